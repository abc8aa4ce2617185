"""Fuzzing targets for point-cloud frame files: every format :func:`lidarfuzz.io.frames.read_frame` reads.

Seeds are written by lidarfuzz's own writers from small deterministic clouds (a few hundred
points, so that a case costs milliseconds): KITTI ``.bin``, PCD in its three encodings, LAS,
LAZ, NumPy ``.npy`` and the full-scene ``.npz`` archive, PLY (ascii and binary), Argoverse 2
``.feather`` and SemanticKITTI ``.label`` files beside their scan.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from lidarfuzz.io.formats import semantickitti
from lidarfuzz.io.frames import read_frame, write_frame
from lidarfuzz.scene.points import PointCloud
from lidarfuzz.scene.scene import Scene
from tests.fuzz.harness import Target

#: Points in the largest seed cloud: small enough that a case reads in milliseconds.
SEED_POINTS = 300
#: Points of the scan written beside a fuzzed SemanticKITTI label file.
LABEL_SCAN_POINTS = 200


def clouds(channels: tuple[str, ...] = ("x", "y", "z", "intensity")) -> list[PointCloud]:
    """Seed clouds: a scan-like ring of points, a tiny one, an empty one (fixed seed)."""
    rng = np.random.default_rng(23)
    out = []
    for n in (SEED_POINTS, 7, 0):
        angle = rng.uniform(-np.pi, np.pi, n)
        distance = rng.uniform(2.0, 60.0, n)
        columns = {"x": distance * np.cos(angle), "y": distance * np.sin(angle), "z": rng.uniform(-2.0, 3.0, n),
                   "intensity": rng.uniform(0.0, 1.0, n), "ring": rng.integers(0, 64, n),
                   "time": np.sort(rng.uniform(0.0, 0.1, n)), "label": rng.integers(0, 12, n)}
        data = np.stack([columns[c] for c in channels], axis=1) if n else np.zeros((0, len(channels)))
        out.append(PointCloud(data.astype(np.float32), channels))
    return out


def frame_seeds(filename: str, *, channel_sets: tuple[tuple[str, ...], ...] = (("x", "y", "z", "intensity"),),
                **options: object) -> Callable[[Path], list[bytes]]:
    """Seeds for one frame format: every seed cloud of every channel set, written by write_frame."""

    def seeds(scratch: Path) -> list[bytes]:
        scratch.mkdir(parents=True, exist_ok=True)
        out = []
        for k, channels in enumerate(channel_sets):
            for i, cloud in enumerate(clouds(channels)):
                path = scratch / f"s{k}_{i}_{filename}"
                write_frame(path, Scene(cloud, frame_id="000000"), overwrite=True, **options)
                out.append(path.read_bytes())
        return out

    return seeds


RICH = (("x", "y", "z", "intensity"), ("x", "y", "z", "intensity", "ring", "time", "label"))


def read_frame_file(path: Path) -> object:
    """What ``lidarfuzz info``/``run`` do with a frame file: read it as a scene."""
    return read_frame(path)


def label_seeds(scratch: Path) -> list[bytes]:
    """SemanticKITTI label files of a scan of :data:`LABEL_SCAN_POINTS` points."""
    scratch.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(5)
    out = []
    for raw_ids in ([10, 40, 48, 70], [252, 30, 0, 1 << 15]):
        n = LABEL_SCAN_POINTS
        data = np.zeros((n, 6), np.float32)
        data[:, :3] = rng.uniform(-20, 20, (n, 3))
        data[:, 4] = rng.choice(raw_ids, n)
        data[:, 5] = rng.integers(-1, 40, n)
        cloud = PointCloud(data, ("x", "y", "z", "intensity", semantickitti.RAW_CHANNEL, "instance"))
        path = scratch / f"{len(out)}.label"
        semantickitti.write_labels(path, cloud, overwrite=True, durable=False)
        out.append(path.read_bytes())
    return out


def read_label_file(path: Path) -> object:
    """Read the scan ``sequences/00/velodyne/<id>.bin`` beside the fuzzed ``labels/<id>.label`` (which reads the
    labels: the folders make it a SemanticKITTI sequence)."""
    scan = path.parent.parent / "velodyne" / f"{path.stem}.bin"
    if not scan.exists():
        scan.parent.mkdir(parents=True, exist_ok=True)
        rng = np.random.default_rng(7)
        points = np.zeros((LABEL_SCAN_POINTS, 4), np.float32)
        points[:, :3] = rng.uniform(-20, 20, (LABEL_SCAN_POINTS, 3))
        points.astype("<f4").tofile(scan)
    return read_frame(scan)


INFO = ("info", "{path}")

TARGETS: list[Target] = [
    Target("bin", "000000.bin", frame_seeds("000000.bin"), read_frame_file, INFO),
    Target("pcd-ascii", "frame.pcd", frame_seeds("frame.pcd", channel_sets=RICH, encoding="ascii"),
           read_frame_file, INFO),
    Target("pcd-binary", "frame.pcd", frame_seeds("frame.pcd", channel_sets=RICH, encoding="binary"),
           read_frame_file, INFO),
    Target("pcd-binary_compressed", "frame.pcd",
           frame_seeds("frame.pcd", channel_sets=RICH, encoding="binary_compressed"), read_frame_file, INFO),
    Target("las", "frame.las", frame_seeds("frame.las", channel_sets=RICH), read_frame_file, INFO),
    Target("laz", "frame.laz", frame_seeds("frame.laz", channel_sets=RICH), read_frame_file, INFO),
    Target("npy", "frame.npy", frame_seeds("frame.npy", channel_sets=RICH), read_frame_file, INFO),
    Target("npz", "frame.npz", frame_seeds("frame.npz", channel_sets=RICH), read_frame_file, INFO),
    Target("ply-ascii", "frame.ply", frame_seeds("frame.ply", channel_sets=RICH, text=True), read_frame_file, INFO),
    Target("ply-binary", "frame.ply", frame_seeds("frame.ply", channel_sets=RICH), read_frame_file, INFO),
    Target("feather", "frame.feather", frame_seeds("frame.feather"), read_frame_file, INFO),
    Target("semantickitti-label", "sequences/00/labels/000000.label", label_seeds, read_label_file, None),
]
