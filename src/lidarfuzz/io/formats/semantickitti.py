"""SemanticKITTI point labels: ``sequences/NN/labels/NNNNNN.label`` beside ``velodyne/NNNNNN.bin``.

Each ``.label`` file holds one little-endian uint32 per point of the scan: the low 16 bits are
the semantic class (SemanticKITTI's ids, ``semantic-kitti.yaml``), the high 16 bits the
instance id (0: none), consistent over a sequence.

Reading gives three channels: ``label`` (the class mapped onto lidarfuzz's
:data:`~lidarfuzz.scene.semantics.SEMANTIC_CLASSES` where they correspond; 0 "unlabelled" where
lidarfuzz has no such class: bicycle, bus, motorcycle, on-rails, other-vehicle, motorcyclist,
other-structure, other-object, outlier), ``instance`` (−1 for none, as lidarfuzz numbers
background) and ``semantickitti_label`` (the raw class id, so nothing is lost).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from lidarfuzz.errors import DataFormatError
from lidarfuzz.io.atomic import atomic_path
from lidarfuzz.scene.points import PointCloud
from lidarfuzz.scene.semantics import SEMANTIC_ID

RAW_CHANNEL = "semantickitti_label"

#: SemanticKITTI class id → lidarfuzz semantic class, where the two correspond. Moving objects
#: (252–259) are their static classes in motion. Parking is ground that is neither road nor
#: sidewalk (lidarfuzz's other-ground); SemanticKITTI's fence ("fences, small walls, crash
#: barriers") is lidarfuzz's wall (the simulator's walls and fences).
TO_LIDARFUZZ: dict[int, str] = {
    10: "car", 252: "car", 18: "truck", 258: "truck", 30: "pedestrian", 254: "pedestrian",
    31: "cyclist", 253: "cyclist", 40: "road", 44: "other-ground", 48: "sidewalk", 49: "other-ground",
    60: "lane-marking", 72: "terrain", 50: "building", 51: "wall", 70: "vegetation", 71: "trunk",
    80: "pole", 81: "traffic-sign",
}
#: lidarfuzz semantic class → SemanticKITTI id, for writing clouds that carry no raw id
#: (SemanticKITTI's car includes vans "with continuous body shape").
FROM_LIDARFUZZ: dict[str, int] = {
    "unlabelled": 0, "road": 40, "lane-marking": 60, "sidewalk": 48, "terrain": 72, "building": 50,
    "wall": 51, "vegetation": 70, "trunk": 71, "pole": 80, "traffic-sign": 81, "car": 10, "van": 10,
    "truck": 18, "pedestrian": 30, "cyclist": 31, "other-ground": 49,
}

_LOOKUP = np.zeros(1 << 16, dtype=np.float32)
for _raw, _name in TO_LIDARFUZZ.items():
    _LOOKUP[_raw] = SEMANTIC_ID[_name]
_INVERSE = np.zeros(max(SEMANTIC_ID.values()) + 1, dtype=np.uint32)
for _name, _raw in FROM_LIDARFUZZ.items():
    _INVERSE[SEMANTIC_ID[_name]] = _raw


def label_path(scan: Path) -> Path:
    """``…/velodyne/000042.bin`` → ``…/labels/000042.label``."""
    return scan.parent.parent / "labels" / f"{scan.stem}.label"


def read_labels(path: Path, points: int) -> dict[str, NDArray[np.float32]] | None:
    """The label channels for a scan of ``points`` points, or ``None`` when the file is absent
    (SemanticKITTI's test sequences have none).

    Raises:
        DataFormatError: The file does not hold one uint32 per point.
    """
    if not path.is_file():
        return None
    size = path.stat().st_size
    if size != 4 * points:
        raise DataFormatError(path, f"holds {size} bytes; the scan has {points} points, so {4 * points} were "
                              "expected (one uint32 per point)")
    raw = np.fromfile(path, dtype="<u4")
    semantic = (raw & 0xFFFF).astype(np.int64)
    instance = (raw >> 16).astype(np.float32)
    instance[instance == 0] = -1.0
    return {"label": _LOOKUP[semantic], "instance": instance, RAW_CHANNEL: semantic.astype(np.float32)}


def write_labels(path: Path, cloud: PointCloud, *, overwrite: bool = False, durable: bool = True) -> Path | None:
    """Write the cloud's labels as a ``.label`` file (raw ids from ``semantickitti_label`` when the
    cloud has them, else mapped back from ``label``); ``None`` when it has neither."""
    if cloud.has(RAW_CHANNEL):
        semantic = cloud.channel(RAW_CHANNEL).astype(np.uint32)
    elif cloud.has("label"):
        ids = np.clip(cloud.channel("label").astype(np.int64), 0, len(_INVERSE) - 1)
        semantic = _INVERSE[ids]
    else:
        return None
    instance = cloud.channel("instance") if cloud.has("instance") else np.full(len(cloud), -1.0, np.float32)
    high = np.where(instance < 0, 0, instance).astype(np.uint32)
    with atomic_path(path, overwrite=overwrite, durable=durable) as tmp:
        ((high << 16) | (semantic & 0xFFFF)).astype("<u4").tofile(tmp)
    return path
