"""Open3D-ML PointPillars through lidarfuzz (extra ``open3d``, which the ``test`` extra installs:
skipped when it is not installed, failing under CI), and its refusal of a mismatched PyTorch."""

from __future__ import annotations

import sys
import textwrap
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from lidarfuzz.errors import DataFormatError, MissingDependencyError
from lidarfuzz.scene.scene import Scene
from lidarfuzz.suts.base import validate_detections
from lidarfuzz.suts.guard import run_guarded
from lidarfuzz.suts.registry import create
from tests.requirements import missing

pytestmark = pytest.mark.open3d


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Weights of a freshly initialised model (seeded): the plumbing, not the accuracy, is under test."""
    try:
        import open3d.ml.torch as ml3d
        import torch
        from open3d._ml3d.utils import Config
    except (ImportError, OSError, RuntimeError) as exc:
        missing(f"Open3D-ML not available ({exc})", "the open3d extra (pip install -e '.[test]')")

    from lidarfuzz.suts.open3d_ml import bundled_config

    torch.manual_seed(0)
    cfg = Config.load_from_file(str(bundled_config("pointpillars_kitti")))
    model = ml3d.models.PointPillars(device="cpu", **cfg.model)
    path = tmp_path_factory.mktemp("o3d") / "pointpillars.pth"
    torch.save({"model_state_dict": model.state_dict()}, path)
    return path


def test_pointpillars_runs_on_cpu_and_answers_valid_boxes(checkpoint: Path, sample_scenes: list[Scene]) -> None:
    sut = create(f"open3d:{checkpoint}")
    with sut:
        result = run_guarded(sut, sample_scenes[0])
        assert result.ok, result.failure
        assert validate_detections(result.output, sut.classes) is None
        again = sut.detect(sample_scenes[0])
        assert np.allclose(result.output.as_array(), again.as_array())
        assert set(sut.classes) == {"Car", "Pedestrian", "Cyclist"}
    assert len(sut.fingerprint()) == 16


def test_unsafe_or_wrong_checkpoints_are_refused(tmp_path: Path, checkpoint: Path) -> None:
    import pickle

    evil = tmp_path / "evil.pth"
    evil.write_bytes(pickle.dumps({"model_state_dict": object()}))
    with pytest.raises(DataFormatError, match="weights-only"):
        create(f"open3d:{evil}").load()
    with pytest.raises(DataFormatError, match="not found"):
        create(f"open3d:{tmp_path / 'missing.pth'}")


@pytest.fixture
def open3d_for_another_torch(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    """An ``open3d`` package whose ``open3d.ml.torch`` refuses the installed PyTorch, as the real one
    does (same check, same message) when its build and torch's major.minor differ."""
    pytest.importorskip("torch")
    package = tmp_path / "open3d"
    (package / "ml" / "torch").mkdir(parents=True)
    (package / "__init__.py").write_text('__version__ = "0.19.0"\n_build_config = {"Pytorch_VERSION": "2.5.1"}\n')
    (package / "ml" / "__init__.py").write_text("")
    (package / "ml" / "torch" / "__init__.py").write_text(textwrap.dedent("""\
        import torch
        raise RuntimeError("Version mismatch: Open3D needs PyTorch version 2.5.*, but version "
                           f"{torch.__version__} is installed!")
        """))
    for name in [n for n in sys.modules if n == "open3d" or n.startswith("open3d.")]:
        monkeypatch.delitem(sys.modules, name)
    monkeypatch.syspath_prepend(str(tmp_path))
    yield
    for name in [n for n in sys.modules if n == "open3d" or n.startswith("open3d.")]:
        del sys.modules[name]  # the stand-in's modules; monkeypatch then puts back any real ones


def test_a_torch_version_mismatch_is_one_clear_error(open3d_for_another_torch: None, tmp_path: Path) -> None:
    from lidarfuzz.suts.open3d_ml import bundled_config

    with pytest.raises(MissingDependencyError) as caught:
        bundled_config("pointpillars_kitti")
    message = str(caught.value)
    assert "\n" not in message
    assert "open3d 0.19.0" in message and "PyTorch version 2.5.*" in message and "torch 2.5.1" in message
    assert "pip install 'lidarfuzz[open3d]'" in message
    weights = tmp_path / "pointpillars.pth"
    weights.write_bytes(b"")
    with pytest.raises(MissingDependencyError, match="Version mismatch"):
        create(f"open3d:{weights}").load()
