"""What a test does when a system package or optional dependency it needs is missing.

Outside CI it skips, with the reason. Under CI (the environment variable ``CI`` set, as ``.ci/run``
does) it fails, naming the package, so that a run which could not install it is never green by
skipping the tests that need it.
"""

from __future__ import annotations

import os
from typing import NoReturn

import pytest


def in_ci() -> bool:
    """Whether the tests run under CI (``CI`` set to anything but empty, ``0`` or ``false``)."""
    return os.environ.get("CI", "").strip().lower() not in ("", "0", "false")


def missing(reason: str, package: str, *, module: bool = False) -> NoReturn:
    """Skip (outside CI) or fail (under CI) because ``package`` is not installed.

    Args:
        reason: What is missing, e.g. ``"PostgreSQL server binaries (initdb) not found"``.
        package: What to install, e.g. ``"the Debian package postgresql"``.
        module: Called at a test module's top level (skips, or fails the collection of, the module).
    """
    if in_ci():
        pytest.fail(f"CI needs {package}: {reason}", pytrace=False)
    pytest.skip(f"{reason} (install {package})", allow_module_level=module)
