"""Naming systems under test: one spec string for the CLI, campaign files and the web.

========================  =====================================================================
spec                      system
========================  =====================================================================
``classic``               a built-in (or plugin) SUT registered under ``lidarfuzz.suts``
``classic?ground=grid``   the same with configuration (query string; values parsed as JSON
                          when they are JSON, else kept as text)
``pkg.module:name``       a :class:`SystemUnderTest` subclass or instance, a factory returning
                          one, or any detector callable (wrapped by :class:`PythonSut`;
                          query options go to it, e.g. ``?input=points&convention=mmdet3d``)
``subprocess:COMMAND``    a program run once per frame (:class:`SubprocessSut`)
``worker:COMMAND``        a long-lived program serving frames (:class:`WorkerSut`)
``onnx:PATH``             an ONNX model run by ONNX Runtime (:class:`OnnxSut`; extra ``onnx``)
``open3d:CHECKPOINT``     Open3D-ML PointPillars from a user's checkpoint (extra ``open3d``;
                          ``?config=pointpillars_kitti`` or a YAML path)
========================  =====================================================================

Options for the command forms come from :func:`create`'s keyword arguments (a campaign
file's ``options``), since a command line may itself contain ``?``.

Systems that consume logs in order (:mod:`lidarfuzz.suts.sequence`) are named the same way by
:func:`create_sequence`: a name registered under ``lidarfuzz.sequence_suts`` (``controller``),
``pkg.module:name`` (a :class:`~lidarfuzz.suts.sequence.SequenceSystem` subclass or instance, or
a class or factory returning an object with ``step``), or ``worker:COMMAND`` (the worker
protocol with resets).
"""

from __future__ import annotations

from typing import Any

from pydantic import ValidationError

from lidarfuzz.plugins import find, load_group, plugin_key
from lidarfuzz.suts.base import SystemUnderTest
from lidarfuzz.suts.external import SubprocessSut, WorkerSut
from lidarfuzz.suts.onnx import OnnxSut
from lidarfuzz.suts.open3d_ml import Open3DPointPillars
from lidarfuzz.suts.python import PythonSut
from lidarfuzz.suts.sequence import PythonSequence, SequenceSystem, WorkerSequence
from lidarfuzz.suts.specs import SutSpecError, import_target, split_spec

__all__ = ["GROUP", "SCHEMES", "SEQUENCE_GROUP", "SutSpecError", "available", "available_sequences", "create",
           "create_sequence", "split_spec", "sut_factory"]

GROUP = "lidarfuzz.suts"
SEQUENCE_GROUP = "lidarfuzz.sequence_suts"
SCHEMES = ("subprocess", "worker", "onnx", "open3d")


def available() -> dict[str, type[SystemUnderTest[Any, Any]]]:
    """Registered SUT classes by name (built-ins first)."""
    return load_group(GROUP, SystemUnderTest)


def _build(spec: str, factory: Any, options: dict[str, Any]) -> Any:
    """Call a SUT constructor; bad options become one line naming the spec and the field."""
    try:
        return factory(**options)
    except ValidationError as exc:
        problems = "; ".join(f"{'.'.join(map(str, e['loc'])) or 'options'}: {e['msg']}" for e in exc.errors())
        raise SutSpecError(f"SUT spec {spec!r}: {problems}") from None
    except TypeError as exc:
        raise SutSpecError(f"SUT spec {spec!r}: {exc}") from None


def create(spec: str, **options: Any) -> SystemUnderTest[Any, Any]:
    """Build the SUT a spec names (see the module docstring); ``options`` configure it.

    Raises:
        SutSpecError: for a spec naming nothing, with what is available.
    """
    spec = spec.strip()
    scheme, sep, rest = spec.partition(":")
    if sep and scheme in SCHEMES:
        if not rest.strip():
            raise SutSpecError(f"SUT spec {spec!r}: nothing after '{scheme}:'")
        if scheme == "subprocess":
            return _build(spec, lambda **o: SubprocessSut(rest, **o), options)
        if scheme == "worker":
            return _build(spec, lambda **o: WorkerSut(rest, **o), options)
        path, query = split_spec(rest)
        if scheme == "open3d":
            return _build(spec, lambda **o: Open3DPointPillars(path, **o), {**query, **options})
        return _build(spec, lambda **o: OnnxSut(path, **o), {**query, **options})
    base, query = split_spec(spec)
    options = {**query, **options}
    if ":" in base:
        obj = import_target(base)
        if isinstance(obj, type) and issubclass(obj, SystemUnderTest):
            return _build(spec, obj, options)
        if isinstance(obj, SystemUnderTest):
            if options:
                raise SutSpecError(f"SUT spec {spec!r}: {base} is an instance; it takes no options")
            return obj
        if not callable(obj):
            raise SutSpecError(f"SUT spec {spec!r}: {base} is neither a SUT nor callable")
        made = obj() if getattr(obj, "__lidarfuzz_factory__", False) else None
        if isinstance(made, SystemUnderTest):
            return made
        return _build(spec, lambda **o: PythonSut(obj, **o), options)
    if plugin_key(base) in {plugin_key(n) for n in available_sequences()}:
        raise SutSpecError(f"SUT spec {spec!r}: {base} consumes logs in order (a sequence system); it makes "
                           "decisions, not detections, and is replayed on logs, not run frame by frame")
    cls = find(GROUP, SystemUnderTest, base, "system under test", "see lidarfuzz suts")
    return _build(spec, cls, options)


def available_sequences() -> dict[str, type[SequenceSystem]]:
    """Registered sequence systems (systems that consume logs in order) by name, built-ins first."""
    return load_group(SEQUENCE_GROUP, SequenceSystem)


def create_sequence(spec: str, **options: Any) -> SequenceSystem:
    """Build the sequence system a spec names (see the module docstring); ``options`` configure it.

    Raises:
        SutSpecError: for a spec naming nothing usable, with what is available.
    """
    spec = spec.strip()
    scheme, sep, rest = spec.partition(":")
    if sep and scheme in SCHEMES:
        if scheme != "worker":
            raise SutSpecError(f"SUT spec {spec!r}: a system that consumes logs is a registered name, "
                               f"module:callable or worker:COMMAND, not {scheme}:")
        if not rest.strip():
            raise SutSpecError(f"SUT spec {spec!r}: nothing after 'worker:'")
        return _build(spec, lambda **o: WorkerSequence(rest, **o), options)  # type: ignore[no-any-return]
    base, query = split_spec(spec)
    options = {**query, **options}
    if ":" not in base:
        cls = find(SEQUENCE_GROUP, SequenceSystem, base, "sequence system", "see lidarfuzz suts")
        return _build(spec, cls, options)  # type: ignore[no-any-return]
    obj = import_target(base)
    if isinstance(obj, SequenceSystem):
        if options:
            raise SutSpecError(f"SUT spec {spec!r}: {base} is an instance; it takes no options")
        return obj
    if isinstance(obj, type) and issubclass(obj, SequenceSystem):
        return _build(spec, obj, options)  # type: ignore[no-any-return]
    if not callable(obj) and not hasattr(obj, "step"):
        raise SutSpecError(f"SUT spec {spec!r}: {base} is neither a sequence system nor a class or factory")
    if hasattr(obj, "step") and not isinstance(obj, type):  # an object, ready to step
        if options:
            raise SutSpecError(f"SUT spec {spec!r}: {base} is an instance; it takes no options")
        made = obj
    else:
        made = _build(spec, obj, options)
    if isinstance(made, SequenceSystem):
        return made
    if not callable(getattr(made, "step", None)):
        raise SutSpecError(f"SUT spec {spec!r}: {base} gave {type(made).__name__}, which has no step(frame) method")
    return PythonSequence(made, name=base.rpartition(":")[2])


def sut_factory(fn: Any) -> Any:
    """Mark a zero-argument function as a factory returning a SUT (for ``module:function`` specs)."""
    fn.__lidarfuzz_factory__ = True
    return fn
