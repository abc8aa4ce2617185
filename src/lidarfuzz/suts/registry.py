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

Steering systems of the camera modality (:mod:`lidarfuzz.suts.steering`) are named the same way
by :func:`create_camera`: a name registered under ``lidarfuzz.camera_suts`` (``epoch``, ``dave2``,
``chauffeur``; ``dave2?weights=PATH``), ``onnx:PATH`` (:class:`~lidarfuzz.suts.steering.onnx.OnnxSteering`;
query options: :class:`~lidarfuzz.suts.steering.preprocess.Preprocess` fields, ``layout``, …),
``worker:COMMAND`` (:class:`~lidarfuzz.suts.steering.worker.WorkerSteering`) or ``pkg.module:name``
— a :class:`~lidarfuzz.suts.steering.base.SteeringSystem` subclass or instance, or a
``torch.nn.Module`` (an instance, or a class or factory returning one; wrapped by
:class:`~lidarfuzz.suts.steering.pytorch.TorchSteering`, query options its Preprocess fields and
``steering_range``, ``threads``, …).
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
from lidarfuzz.suts.steering.base import SteeringSystem
from lidarfuzz.suts.steering.onnx import OnnxSteering
from lidarfuzz.suts.steering.preprocess import split_options
from lidarfuzz.suts.steering.pytorch import TorchSteering
from lidarfuzz.suts.steering.worker import WorkerSteering

__all__ = ["CAMERA_GROUP", "GROUP", "SCHEMES", "SEQUENCE_GROUP", "SutSpecError", "available", "available_camera",
           "available_sequences", "create", "create_camera", "create_sequence", "split_spec", "sut_factory",
           "system_type"]

GROUP = "lidarfuzz.suts"
SEQUENCE_GROUP = "lidarfuzz.sequence_suts"
CAMERA_GROUP = "lidarfuzz.camera_suts"
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


def available_camera() -> dict[str, type[SteeringSystem]]:
    """Registered steering systems (the camera modality's) by name, built-ins first."""
    return load_group(CAMERA_GROUP, SteeringSystem)


def _is_module(obj: Any) -> bool:
    """Whether ``obj`` is a ``torch.nn.Module`` instance (without importing torch for a spec that needs none)."""
    return not isinstance(obj, type) and hasattr(obj, "state_dict") and hasattr(obj, "named_modules") and callable(obj)


def _torch_steering(spec: str, module: Any, options: dict[str, Any]) -> TorchSteering:
    preprocess, rest = split_options(options)
    return _build(spec, lambda **o: TorchSteering(module, preprocess=preprocess, **o), rest)  # type: ignore[no-any-return]


def create_camera(spec: str, **options: Any) -> SteeringSystem:
    """Build the steering system a spec names (see the module docstring); ``options`` configure it.

    Raises:
        SutSpecError: for a spec naming nothing usable, with what is available.
    """
    spec = spec.strip()
    scheme, sep, rest = spec.partition(":")
    if sep and scheme in SCHEMES:
        if not rest.strip():
            raise SutSpecError(f"SUT spec {spec!r}: nothing after '{scheme}:'")
        if scheme == "worker":
            return _build(spec, lambda **o: WorkerSteering(rest, **o), options)  # type: ignore[no-any-return]
        if scheme != "onnx":
            raise SutSpecError(f"SUT spec {spec!r}: a steering system is a registered name, onnx:PATH, worker:COMMAND "
                               f"or module:name, not {scheme}:")
        path, query = split_spec(rest)
        preprocess, other = split_options({**query, **options})
        return _build(spec, lambda **o: OnnxSteering(path, preprocess=preprocess, **o), other)  # type: ignore[no-any-return]
    base, query = split_spec(spec)
    options = {**query, **options}
    if ":" not in base:
        if plugin_key(base) in {plugin_key(n) for n in available()}:
            raise SutSpecError(f"SUT spec {spec!r}: {base} is a LiDAR system (it detects objects in point clouds); a "
                               f"camera task needs a steering system: {', '.join(sorted(available_camera()))}")
        cls = find(CAMERA_GROUP, SteeringSystem, base, "steering system", "see lidarfuzz suts")
        return _build(spec, cls, options)  # type: ignore[no-any-return]
    obj = import_target(base)
    if isinstance(obj, SteeringSystem) or _is_module(obj):
        if options and isinstance(obj, SteeringSystem):
            raise SutSpecError(f"SUT spec {spec!r}: {base} is an instance; it takes no options")
        return obj if isinstance(obj, SteeringSystem) else _torch_steering(spec, obj, options)
    if isinstance(obj, type) and issubclass(obj, SteeringSystem):
        return _build(spec, obj, options)  # type: ignore[no-any-return]
    if not callable(obj):
        raise SutSpecError(f"SUT spec {spec!r}: {base} is neither a steering system nor a torch module or factory")
    # a torch.nn.Module class or a factory: built without options, which go to the wrapper
    made = _build(spec, obj, {})
    if isinstance(made, SteeringSystem):
        return made
    if _is_module(made):
        return _torch_steering(spec, made, options)
    raise SutSpecError(f"SUT spec {spec!r}: {base} gave {type(made).__name__}, which is neither a SteeringSystem "
                       "nor a torch.nn.Module")


def system_type(system: SystemUnderTest[Any, Any] | SequenceSystem) -> tuple[str, str]:
    """What kind of system a built one is, as ``(code, label)`` — the model list's *type* column:
    ``classic`` (the classic pipeline), ``bugzoo`` (a bug-zoo variant of it), ``pillars``
    (lidarfuzz's learned PointPillars), ``open3d``, ``onnx``, ``subprocess``, ``worker``, ``python``
    (a detector callable), ``steering`` (a built-in steering network), ``onnx-steering``,
    ``torch-steering``, ``worker-steering``, ``sequence`` (a system consuming logs in order: the
    controller, its bug-zoo variants, ...), or ``plugin`` (any other class, named in the label).

    Read from the class :func:`create`, :func:`create_camera` or :func:`create_sequence` built, so
    it is what will run, not a guess from the spec's text.

    >>> system_type(create("classic-bug-roi-cache"))
    ('bugzoo', 'bug-zoo variant of the classic pipeline')
    """
    from lidarfuzz.suts.bugzoo import BuggyPipeline
    from lidarfuzz.suts.classic import ClassicPipeline
    from lidarfuzz.suts.learned.sut import PillarsDetector
    from lidarfuzz.suts.steering.builtin import BuiltinSteering

    known: tuple[tuple[type, str, str], ...] = (  # subclasses before their bases
        (BuggyPipeline, "bugzoo", "bug-zoo variant of the classic pipeline"),
        (ClassicPipeline, "classic", "classic pipeline"),
        (PillarsDetector, "pillars", "learned PointPillars"),
        (Open3DPointPillars, "open3d", "Open3D-ML PointPillars"),
        (OnnxSut, "onnx", "ONNX model"),
        (SubprocessSut, "subprocess", "program run once per frame"),
        (WorkerSut, "worker", "worker process"),
        (PythonSut, "python", "Python detector callable"),
        (BuiltinSteering, "steering", "built-in steering network"),
        (OnnxSteering, "onnx-steering", "ONNX steering network"),
        (TorchSteering, "torch-steering", "torch steering network"),
        (WorkerSteering, "worker-steering", "steering worker process"),
    )
    for cls, code, label in known:
        if isinstance(system, cls):
            return code, label
    if isinstance(system, SequenceSystem):
        return "sequence", f"system consuming logs in order ({system.name})"
    kind = "steering system" if isinstance(system, SteeringSystem) else "system"
    return "plugin", f"plugin {kind} ({type(system).__name__})"


def sut_factory(fn: Any) -> Any:
    """Mark a zero-argument function as a factory returning a SUT (for ``module:function`` specs)."""
    fn.__lidarfuzz_factory__ = True
    return fn
