"""The SUT contract over every adapter: determinism, identity, conventions, failures as results."""

from __future__ import annotations

import shutil
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from lidarfuzz.scene.boxes import Boxes3D
from lidarfuzz.scene.scene import Scene
from lidarfuzz.suts.base import FailureKind, SystemUnderTest, validate_detections
from lidarfuzz.suts.guard import IsolatedSut, run_guarded
from lidarfuzz.suts.python import PythonSut
from lidarfuzz.suts.registry import SutSpecError, available, create

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "examples" / "suts" / "grid_detector.py"
PY = sys.executable


@pytest.fixture(scope="session")
def c_worker(tmp_path_factory: pytest.TempPathFactory) -> Path:
    compiler = shutil.which("cc") or shutil.which("gcc")
    if compiler is None:
        pytest.skip("no C compiler to build examples/suts/c_worker")
    out = tmp_path_factory.mktemp("cworker") / "detector"
    subprocess.run([compiler, "-O2", "-o", str(out), str(ROOT / "examples/suts/c_worker/detector.c")], check=True)
    return out


@pytest.fixture(scope="session")
def onnx_model(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A real ONNX graph (no weights): one box spanning the points' extent, score 0.9, class 0."""
    onnx = pytest.importorskip("onnx")
    pytest.importorskip("onnxruntime")
    from onnx import TensorProto, helper

    nodes = [
        helper.make_node("Slice", ["points", "s0", "s3", "ax1"], ["xyz"]),
        helper.make_node("ReduceMin", ["xyz", "ax0"], ["lo"], keepdims=1),
        helper.make_node("ReduceMax", ["xyz", "ax0"], ["hi"], keepdims=1),
        helper.make_node("Add", ["lo", "hi"], ["sum"]),
        helper.make_node("Mul", ["sum", "half"], ["centre"]),
        helper.make_node("Sub", ["hi", "lo"], ["size"]),
        helper.make_node("Concat", ["centre", "size", "zero"], ["boxes"], axis=1),
    ]
    consts = [
        helper.make_tensor("s0", TensorProto.INT64, [1], [0]),
        helper.make_tensor("s3", TensorProto.INT64, [1], [3]),
        helper.make_tensor("ax1", TensorProto.INT64, [1], [1]),
        helper.make_tensor("ax0", TensorProto.INT64, [1], [0]),
        helper.make_tensor("half", TensorProto.FLOAT, [1], [0.5]),
        helper.make_tensor("zero", TensorProto.FLOAT, [1, 1], [0.0]),
    ]
    nodes += [
        helper.make_node("Constant", [], ["scores"], value=helper.make_tensor("v", TensorProto.FLOAT, [1], [0.9])),
        helper.make_node("Constant", [], ["labels"], value=helper.make_tensor("w", TensorProto.INT64, [1], [0])),
    ]
    graph = helper.make_graph(
        nodes, "extent", [helper.make_tensor_value_info("points", TensorProto.FLOAT, ["N", 4])],
        [
            helper.make_tensor_value_info("boxes", TensorProto.FLOAT, [1, 7]),
            helper.make_tensor_value_info("scores", TensorProto.FLOAT, [1]),
            helper.make_tensor_value_info("labels", TensorProto.INT64, [1]),
        ],
        initializer=consts,
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)])
    model.ir_version = 9  # what ONNX Runtime releases of the last years all read
    helper.set_model_props(model, {"class_names": '["Car"]'})
    onnx.checker.check_model(model)
    path = tmp_path_factory.mktemp("onnx") / "extent.onnx"
    onnx.save(model, str(path))
    return path


def adapters(c_worker: Path | None = None, onnx_model: Path | None = None) -> dict[str, Callable[[], SystemUnderTest]]:
    out: dict[str, Callable[[], SystemUnderTest]] = {
        "python": lambda: create("tests.suts.detectors:centroid_detector?input=points&convention=openpcdet"),
        "subprocess": lambda: create(f"subprocess:{PY} {EXAMPLE} {{points}} {{output}} {{frame_id}}"),
        "worker": lambda: create(f"worker:{PY} {EXAMPLE} --worker"),
        "classic-isolated": lambda: IsolatedSut("classic?cluster=euclidean", timeout=60),
    }
    if c_worker is not None:
        out["c-worker"] = lambda: create(f"worker:{c_worker}")
    if onnx_model is not None:
        out["onnx"] = lambda: create(f"onnx:{onnx_model}")
    return out


ADAPTERS = ["python", "subprocess", "worker", "c-worker", "onnx", "isolated", "classic-isolated"]
# every registered SUT (the classic pipeline and the bug zoo) passes the same contract
ADAPTERS += sorted(f"registered:{name}" for name in available())


@pytest.fixture(params=ADAPTERS)
def sut(request: pytest.FixtureRequest) -> SystemUnderTest:
    kind = request.param
    if kind.startswith("registered:"):
        made: SystemUnderTest = create(kind.removeprefix("registered:"))
    elif kind == "isolated":
        made = IsolatedSut("tests.suts.detectors:centroid_detector?input=points", timeout=30)
    elif kind == "c-worker":
        made = adapters(c_worker=request.getfixturevalue("c_worker"))[kind]()
    elif kind == "onnx":
        made = adapters(onnx_model=request.getfixturevalue("onnx_model"))[kind]()
    else:
        made = adapters()[kind]()
    made.load()
    yield made
    made.close()


def test_contract_deterministic_valid_and_identified(sut: SystemUnderTest, sample_scenes: list[Scene]) -> None:
    for scene in sample_scenes[:2]:
        first = sut.detect(scene)
        again = sut.detect(scene)
        assert isinstance(first, Boxes3D)
        assert validate_detections(first, sut.classes) is None
        assert first.allclose(again, atol=1e-4) and np.array_equal(first.labels, again.labels)
        assert run_guarded(sut, scene).ok
    assert sut.detect_batch(sample_scenes[:2])[0].allclose(sut.detect(sample_scenes[0]), atol=1e-4)
    fp = sut.fingerprint()
    assert len(fp) == 16 and fp == sut.fingerprint()
    assert isinstance(sut.name, str) and sut.name


def test_the_adapters_agree_on_the_same_algorithm(sample_scenes: list[Scene], c_worker: Path) -> None:
    """The in-process detector and the C worker compute the same box: conventions survive each edge."""
    scene = sample_scenes[0]
    python = adapters()["python"]()
    with adapters(c_worker=c_worker)["c-worker"]() as worker:
        a, b = python.detect(scene), worker.detect(scene)
    assert len(a) == len(b) == 1
    np.testing.assert_allclose(a.as_array(), b.as_array(), atol=2e-3)


def test_fingerprint_follows_configuration() -> None:
    a = create("tests.suts.detectors:centroid_detector?input=points")
    b = create("tests.suts.detectors:centroid_detector?input=points")
    c = create("tests.suts.detectors:centroid_detector?input=points&convention=mmdet3d")
    assert a.fingerprint() == b.fingerprint() != c.fingerprint()


# -- failures are results -------------------------------------------------------------------------
def with_id(scene: Scene, frame_id: str) -> Scene:
    return scene.replace(frame_id=frame_id)


def test_in_process_failures_become_results(sample_scenes: list[Scene]) -> None:
    sut = PythonSut(__import__("tests.suts.detectors", fromlist=["flaky"]).flaky)
    crash = run_guarded(sut, with_id(sample_scenes[0], "000001"))
    assert crash.failure is not None and crash.failure.kind is FailureKind.CRASH
    assert "segmentation of the cloud failed" in crash.failure.message and "Traceback" in crash.failure.detail
    garbage = run_guarded(sut, with_id(sample_scenes[0], "000004"))
    assert garbage.failure is not None and garbage.failure.kind is FailureKind.INVALID_OUTPUT
    assert "NaN" in garbage.failure.message
    assert run_guarded(sut, with_id(sample_scenes[0], "000000")).ok


def test_isolated_sut_survives_hangs_and_deaths(sample_scenes: list[Scene]) -> None:
    sut = IsolatedSut("tests.suts.detectors:flaky", timeout=2.0)
    with sut:
        hang = run_guarded(sut, with_id(sample_scenes[0], "000002"))
        assert hang.failure is not None and hang.failure.kind is FailureKind.TIMEOUT
        assert run_guarded(sut, with_id(sample_scenes[0], "000000")).ok  # restarted
        dead = run_guarded(sut, with_id(sample_scenes[0], "000003"))
        assert dead.failure is not None and dead.failure.kind is FailureKind.CRASH
        assert "exit code 9" in dead.failure.message
        crash = run_guarded(sut, with_id(sample_scenes[0], "000001"))
        assert crash.failure is not None and "segmentation" in crash.failure.message
        assert run_guarded(sut, with_id(sample_scenes[0], "000005")).ok
        assert sut.restarts == 2


@pytest.mark.parametrize("mode,kind", [("crash", FailureKind.CRASH), ("hang", FailureKind.TIMEOUT),
                                        ("garbage", FailureKind.INVALID_OUTPUT)])
def test_external_failures_become_results(sample_scenes: list[Scene], mode: str, kind: FailureKind) -> None:
    scene = with_id(sample_scenes[0], "000007")
    fail = f"--fail-on 000007:{mode}"
    for sut in (
        create(f"subprocess:{PY} {EXAMPLE} {fail} {{points}} {{output}} {{frame_id}}", timeout=3.0),
        create(f"worker:{PY} {EXAMPLE} {fail} --worker", timeout=3.0),
    ):
        with sut:
            result = run_guarded(sut, scene)
            assert result.failure is not None and result.failure.kind is kind, (sut, result.failure)
            assert run_guarded(sut, with_id(scene, "000008")).ok  # the run goes on


def test_bad_specs_say_what_is_wrong() -> None:
    with pytest.raises(SutSpecError, match="cannot import module"):
        create("no_such_module:detect")
    with pytest.raises(SutSpecError, match="has no attribute"):
        create("tests.suts.detectors:nothing")
    with pytest.raises(ValueError, match="placeholders"):
        create("subprocess:echo hello")
    with pytest.raises(Exception, match="unknown system under test 'nope'"):
        create("nope")
    with pytest.raises(SutSpecError, match=r"'classic\?ground=magic': ground: Input should be 'ransac' or 'grid'"):
        create("classic?ground=magic")
    with pytest.raises(SutSpecError, match="typo"):
        create("classic?typo=1")
