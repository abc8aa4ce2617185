"""Open3D-ML's PointPillars as a system under test (extra ``open3d``; CPU, ``torch==2.13.0``).

``open3d.ml.torch`` refuses a PyTorch whose major.minor differs from the one Open3D was built
against (``open3d-cpu`` 0.20.0: 2.13); that refusal is reported as one line naming both versions
and the extra that pins a matching pair.

The user supplies the checkpoint (lidarfuzz downloads nothing); the model's configuration is
one of Open3D-ML's bundled YAML files (default ``pointpillars_kitti``) or a path to one.
Checkpoints are read with ``torch.load(weights_only=True)``: plain tensors only, no code.

Open3D-ML's boxes (``BEVBox3D``) hold the centre, ``size = (w, h, l)`` and a yaw that equals
KITTI's ``rotation_y`` (0 along LiDAR −y, growing towards +x); lidarfuzz's heading is
``-yaw - π/2``, the same map as mmdetection3d's pre-1.0 convention.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from lidarfuzz.errors import DataFormatError, MissingDependencyError
from lidarfuzz.scene.boxes import Boxes3D, wrap_angle
from lidarfuzz.scene.scene import Scene
from lidarfuzz.suts.base import SystemUnderTest
from lidarfuzz.suts.code import distribution_version


def _modules() -> tuple[Any, Any, Any]:
    try:
        import open3d
        import torch
    except (ImportError, OSError) as exc:
        raise MissingDependencyError("open3d-cpu", "open3d", f"Open3D-ML PointPillars ({exc})") from None
    try:
        import open3d.ml.torch as ml3d
    except (ImportError, OSError) as exc:
        raise MissingDependencyError("open3d-cpu", "open3d", f"Open3D-ML PointPillars ({exc})") from None
    except RuntimeError as exc:  # open3d.ml.torch's own check: "Version mismatch: Open3D needs PyTorch ..."
        built = getattr(open3d, "_build_config", {}).get("Pytorch_VERSION") or "of Open3D's build"
        why = " ".join(str(exc).split())
        raise MissingDependencyError(f"torch {built}", "open3d",
                                     f"Open3D-ML PointPillars (open3d {open3d.__version__}: {why})") from None
    return open3d, ml3d, torch


def bundled_config(name: str) -> Path:
    """Path of one of Open3D-ML's bundled model configurations (e.g. ``pointpillars_kitti``)."""
    open3d, _, _ = _modules()
    path = Path(open3d.__file__).parent / "_ml3d" / "configs" / f"{name}.yml"
    if not path.exists():
        raise DataFormatError(path, "no such bundled Open3D-ML configuration")
    return path


class Open3DPointPillars(SystemUnderTest[Scene, Boxes3D]):
    """Open3D-ML PointPillars on CPU from a user's checkpoint.

    Args:
        checkpoint: A ``.pth`` file holding the model's ``state_dict`` (or a dict with
            ``model_state_dict``, as Open3D-ML's pipelines save it).
        config: A bundled configuration name or a YAML path.
        threads: torch intra-op threads.
    """

    name = "open3d-pointpillars"
    version = "1"

    def __init__(self, checkpoint: str, *, config: str = "pointpillars_kitti", threads: int = 1) -> None:
        self.checkpoint = Path(checkpoint)
        if not self.checkpoint.is_file():
            raise DataFormatError(self.checkpoint, "checkpoint file not found")
        self.config_name = config
        self.threads = int(threads)
        self._model: Any = None

    def config(self) -> dict[str, Any]:
        return {"config": self.config_name}

    def weight_files(self) -> Sequence[Path]:
        return [self.checkpoint]

    def code(self) -> dict[str, str]:
        """The Python code, with the versions of the installed Open3D and torch (the network's code)."""
        versions = {f"dist:{d}": distribution_version(d) for d in ("open3d", "open3d-cpu", "torch")}
        return {**super().code(), **{k: v for k, v in versions.items() if v is not None}}

    def load(self) -> None:
        if self._model is not None:
            return
        _, ml3d, torch = _modules()
        from open3d._ml3d.utils import Config

        path = Path(self.config_name) if self.config_name.endswith((".yml", ".yaml")) else bundled_config(
            self.config_name
        )
        cfg = Config.load_from_file(str(path))
        torch.set_num_threads(self.threads)
        model = ml3d.models.PointPillars(device="cpu", **cfg.model)
        try:
            state = torch.load(self.checkpoint, map_location="cpu", weights_only=True)
        except Exception as exc:  # torch raises many types for files that are not plain tensors
            raise DataFormatError(self.checkpoint, f"not a loadable weights-only checkpoint: {exc}") from None
        if isinstance(state, dict) and "model_state_dict" in state:
            state = state["model_state_dict"]
        try:
            model.load_state_dict(state)
        except (RuntimeError, TypeError) as exc:
            raise DataFormatError(self.checkpoint, f"weights do not fit {path.name}: {exc}") from None
        model.eval()
        self._model = model
        self.classes = tuple(model.classes)  # type: ignore[misc]

    def close(self) -> None:
        self._model = None

    def detect(self, sample: Scene) -> Boxes3D:
        self.load()
        _, _, torch = _modules()
        from open3d._ml3d.torch.dataloaders import ConcatBatcher

        model = self._model
        points = np.ascontiguousarray(sample.points.data[:, :4], dtype=np.float32)
        data: dict[str, Any] = {"point": points, "full_point": points, "feat": None, "calib": None,
                                "bounding_boxes": []}
        attr = {"split": "test"}
        batch = model.transform(model.preprocess(data, attr), attr)
        inputs = ConcatBatcher("cpu", model="PointPillars").collate_fn([{"data": batch, "attr": attr}])
        inputs = inputs["data"] if isinstance(inputs, dict) else inputs
        with torch.no_grad():
            boxes = model.inference_end(model(inputs), inputs)[0]
        if not boxes:
            return Boxes3D.empty()
        centres = np.array([b.center for b in boxes], dtype=np.float64)
        whl = np.array([b.size for b in boxes], dtype=np.float64)
        yaw = wrap_angle(-np.array([b.yaw for b in boxes], dtype=np.float64) - np.pi / 2.0)
        return Boxes3D.create(
            centres, whl[:, [2, 0, 1]], yaw, [str(b.label_class) for b in boxes],
            scores=[float(b.confidence) for b in boxes],
        )
