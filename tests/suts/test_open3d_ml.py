"""Open3D-ML PointPillars through lidarfuzz (extra ``open3d``; skipped when it is not installed)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from lidarfuzz.errors import DataFormatError
from lidarfuzz.scene.scene import Scene
from lidarfuzz.suts.base import validate_detections
from lidarfuzz.suts.guard import run_guarded
from lidarfuzz.suts.registry import create

pytestmark = pytest.mark.open3d


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Weights of a freshly initialised model (seeded): the plumbing, not the accuracy, is under test."""
    pytest.importorskip("torch")
    try:
        import open3d.ml.torch as ml3d
        from open3d._ml3d.utils import Config
    except (ImportError, OSError) as exc:
        pytest.skip(f"Open3D-ML not available: {exc}")
    import torch

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
