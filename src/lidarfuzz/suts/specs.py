"""Reading a SUT spec string: its query options, and the ``module:attribute`` it may name.

The grammar of specs is described in :mod:`lidarfuzz.suts.registry`, which builds the
system; adapters that resolve a ``module:attribute`` option themselves (ONNX pre- and
post-processing hooks) use :func:`import_target` from here, below the registry.
"""

from __future__ import annotations

import importlib
import json
from typing import Any
from urllib.parse import parse_qsl

from lidarfuzz.errors import LidarfuzzError


class SutSpecError(LidarfuzzError, ValueError):
    """A SUT spec that names nothing usable."""


def _value(text: str) -> Any:
    try:
        return json.loads(text)
    except json.JSONDecodeError:
        return text


def split_spec(spec: str) -> tuple[str, dict[str, Any]]:
    """``name?k=v&k2=v2`` → (``name``, {k: v, k2: v2}) with JSON-parsed values."""
    base, _, query = spec.partition("?")
    return base.strip(), {k: _value(v) for k, v in parse_qsl(query, keep_blank_values=True)}


def import_target(target: str) -> Any:
    """The object ``module.path:attr.path`` names.

    Raises:
        SutSpecError: The module cannot be imported or has no such attribute.
    """
    module_name, _, attr = target.partition(":")
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise SutSpecError(f"SUT spec {target!r}: cannot import module {module_name!r} ({exc})") from None
    obj: Any = module
    for part in attr.split("."):
        if not hasattr(obj, part):
            raise SutSpecError(f"SUT spec {target!r}: module {module_name!r} has no attribute {attr!r}")
        obj = getattr(obj, part)
    return obj
