"""KITTI calibration and exact, vectorised conversions LiDAR ↔ rectified camera ↔ image.

Frames (as in the KITTI devkit):

* LiDAR (velodyne): x forward, y left, z up.
* Rectified camera: x right, y down, z forward; ``rect = R0_rect · Tr_velo_to_cam · lidar``.
* Image: pixel ``(u, v) = P2 · rect`` after division by depth.

KITTI labels store the *bottom* centre of a box in the rectified camera frame,
dimensions as ``h, w, l`` and ``rotation_y`` about the camera's y axis. The heading
conversion is ``rotation_y = -yaw - π/2`` (the convention of the devkit's tooling,
which treats the camera's y axis as vertical); it is its own exact inverse, so
LiDAR → label → LiDAR round trips are exact up to float rounding.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from functools import cached_property
from os import PathLike
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from lidarfuzz.errors import DataFormatError
from lidarfuzz.scene.boxes import wrap_angle
from lidarfuzz.scene.points import frozen

#: (key, rows, cols) in the order the KITTI object calib files list them.
CALIB_KEYS: tuple[tuple[str, int, int], ...] = (
    ("P0", 3, 4),
    ("P1", 3, 4),
    ("P2", 3, 4),
    ("P3", 3, 4),
    ("R0_rect", 3, 3),
    ("Tr_velo_to_cam", 3, 4),
    ("Tr_imu_to_velo", 3, 4),
)
REQUIRED_KEYS = ("P2", "R0_rect", "Tr_velo_to_cam")
# Spellings used by the KITTI tracking and raw data releases.
_ALIASES = {"R_rect": "R0_rect", "Tr_velo_cam": "Tr_velo_to_cam", "Tr_imu_velo": "Tr_imu_to_velo"}
#: Image size (height, width) of KITTI's colour camera, used when no image says otherwise.
KITTI_IMAGE_SHAPE = (375, 1242)


def _homogeneous(m: NDArray[np.float64]) -> NDArray[np.float64]:
    out = np.eye(4)
    out[: m.shape[0], : m.shape[1]] = m
    return out


@dataclass(frozen=True, eq=False)
class KittiCalibration:
    """The matrices of a KITTI ``calib/*.txt`` file (those absent in the file are ``None``).

    Example:
        >>> calib = KittiCalibration.default()
        >>> calib.lidar_to_rect([[10.0, 0.0, 0.0]]).round(3).tolist()
        [[0.0, -0.08, 9.73]]
    """

    P2: NDArray[np.float64]
    R0_rect: NDArray[np.float64]
    Tr_velo_to_cam: NDArray[np.float64]
    P0: NDArray[np.float64] | None = None
    P1: NDArray[np.float64] | None = None
    P3: NDArray[np.float64] | None = None
    Tr_imu_to_velo: NDArray[np.float64] | None = None
    image_shape: tuple[int, int] = field(default=KITTI_IMAGE_SHAPE)

    def __post_init__(self) -> None:
        for key, rows, cols in CALIB_KEYS:
            value = getattr(self, key)
            if value is None:
                continue
            array = np.asarray(value, dtype=np.float64)
            if array.shape != (rows, cols):
                raise ValueError(f"{key} must be {rows}×{cols}, got shape {array.shape}")
            object.__setattr__(self, key, frozen(array))

    # -- construction -----------------------------------------------------------------
    @classmethod
    def default(cls) -> KittiCalibration:
        """An idealised KITTI-like rig: KITTI's colour-camera intrinsics, a camera 0.27 m
        ahead of and 0.08 m below the LiDAR, axes exactly aligned, stereo baselines as KITTI."""
        fx, cx, cy = 721.5377, 609.5593, 172.854
        k = np.array([[fx, 0.0, cx], [0.0, fx, cy], [0.0, 0.0, 1.0]])

        def proj(tx: float) -> NDArray[np.float64]:
            return np.concatenate([k, np.array([[fx * tx], [0.0], [0.0]])], axis=1)

        return cls(
            P0=proj(0.0),
            P1=proj(-0.54),
            P2=proj(0.06),
            P3=proj(-0.48),
            R0_rect=np.eye(3),
            Tr_velo_to_cam=np.array([[0.0, -1.0, 0.0, 0.0], [0.0, 0.0, -1.0, -0.08], [1.0, 0.0, 0.0, -0.27]]),
            Tr_imu_to_velo=np.array([[1.0, 0.0, 0.0, -0.81], [0.0, 1.0, 0.0, 0.32], [0.0, 0.0, 1.0, -0.80]]),
        )

    @classmethod
    def from_mapping(
        cls, values: Mapping[str, ArrayLike], image_shape: tuple[int, int] = KITTI_IMAGE_SHAPE
    ) -> KittiCalibration:
        kwargs = {}
        for key, rows, cols in CALIB_KEYS:
            if key in values and values[key] is not None:
                kwargs[key] = np.asarray(values[key], dtype=np.float64).reshape(rows, cols)
        return cls(**kwargs, image_shape=image_shape)  # type: ignore[arg-type]

    @classmethod
    def parse(cls, text: str, path: str | PathLike[str] = "<calib>") -> KittiCalibration:
        """Parse the text of a KITTI calib file; errors name the file, line and key."""
        shapes = {key: (rows, cols) for key, rows, cols in CALIB_KEYS}
        found: dict[str, NDArray[np.float64]] = {}
        lines: dict[str, int] = {}
        for lineno, raw in enumerate(text.splitlines(), start=1):
            line = raw.strip()
            if not line:
                continue
            key, sep, rest = line.partition(":")
            if not sep:
                key, _, rest = line.partition(" ")
            key = _ALIASES.get(key.strip(), key.strip())
            if key not in shapes:
                continue  # other keys (e.g. S_02, D_02 of raw calib) are allowed and ignored
            if key in found:
                raise DataFormatError(path, "key appears twice", line=lineno, field=key)
            rows, cols = shapes[key]
            tokens = rest.split()
            try:
                values = np.array([float(t) for t in tokens], dtype=np.float64)
            except ValueError:
                bad = next(t for t in tokens if not _is_float(t))
                raise DataFormatError(path, f"value {bad!r} is not a number", line=lineno, field=key) from None
            if values.size != rows * cols:
                raise DataFormatError(
                    path, f"expected {rows * cols} numbers ({rows}×{cols}), found {values.size}",
                    line=lineno, field=key,
                )
            if not np.all(np.isfinite(values)):
                raise DataFormatError(path, "values must be finite", line=lineno, field=key)
            found[key] = values.reshape(rows, cols)
            lines[key] = lineno
        missing = [k for k in REQUIRED_KEYS if k not in found]
        if missing:
            raise DataFormatError(
                path, f"missing key{'s' if len(missing) > 1 else ''} {', '.join(missing)}",
                hint=f"a KITTI calib file needs {', '.join(REQUIRED_KEYS)}",
            )
        for key in ("R0_rect", "Tr_velo_to_cam"):
            if not invertible(found[key][:, :3]):
                raise DataFormatError(path, "its 3×3 rotation is not invertible (labels cannot be placed in the "
                                      "LiDAR frame)", line=lines[key], field=key)
        # P2 is left as it is: LiDAR-only data sets write placeholders, and only the camera modality,
        # which needs its inverse, refuses a singular one (lidarfuzz.io.images.kitti)
        return cls.from_mapping(found)

    @classmethod
    def from_file(cls, path: str | PathLike[str]) -> KittiCalibration:
        path = Path(path)
        try:
            text = path.read_text(encoding="utf-8")
        except UnicodeDecodeError:
            raise DataFormatError(path, "not a text file (expected a KITTI calib file)") from None
        return cls.parse(text, path)

    def to_text(self) -> str:
        """The KITTI calib file text; numbers are written so they read back exactly."""
        lines = []
        for key, _, _ in CALIB_KEYS:
            value = getattr(self, key)
            if value is not None:
                lines.append(f"{key}: " + " ".join(repr(float(v)) for v in value.ravel()))
        return "\n".join(lines) + "\n"

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, KittiCalibration):
            return NotImplemented
        for key, _, _ in CALIB_KEYS:
            a, b = getattr(self, key), getattr(other, key)
            if (a is None) != (b is None) or (a is not None and not np.array_equal(a, b)):
                return False
        return tuple(self.image_shape) == tuple(other.image_shape)

    __hash__ = None  # type: ignore[assignment]

    # -- point transforms -------------------------------------------------------------
    @cached_property
    def velo_to_rect(self) -> NDArray[np.float64]:
        """4×4 homogeneous transform LiDAR → rectified camera."""
        return _homogeneous(self.R0_rect) @ _homogeneous(self.Tr_velo_to_cam)

    @cached_property
    def rect_to_velo(self) -> NDArray[np.float64]:
        inverse = np.linalg.inv(self.velo_to_rect).astype(np.float64, copy=False)
        return inverse

    def lidar_to_rect(self, points: ArrayLike) -> NDArray[np.float64]:
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        m = self.velo_to_rect
        return p @ m[:3, :3].T + m[:3, 3]

    def rect_to_lidar(self, points: ArrayLike) -> NDArray[np.float64]:
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        m = self.rect_to_velo
        return p @ m[:3, :3].T + m[:3, 3]

    def rect_to_image(self, points: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Pixel coordinates (N×2) through P2 and the depth (N,) of each rectified point."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        h = p @ self.P2[:, :3].T + self.P2[:, 3]
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = h[:, :2] / h[:, 2:3]
        return uv, p[:, 2]

    def image_to_rect(self, uv: ArrayLike, depth: ArrayLike) -> NDArray[np.float64]:
        """Back-project pixels with their rectified-camera depth (z) to rectified 3D points."""
        pix = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        z = np.asarray(depth, dtype=np.float64).reshape(-1)
        p = self.P2
        # u = (p00 x + p01 y + p02 z + p03) / (z + p23), v likewise; P2 is upper-triangular in KITTI.
        w = z + p[2, 3]
        y = (pix[:, 1] * w - p[1, 2] * z - p[1, 3]) / p[1, 1]
        x = (pix[:, 0] * w - p[0, 1] * y - p[0, 2] * z - p[0, 3]) / p[0, 0]
        return np.stack([x, y, z], axis=1)

    def image_to_lidar(self, uv: ArrayLike, depth: ArrayLike) -> NDArray[np.float64]:
        return self.rect_to_lidar(self.image_to_rect(uv, depth))

    def lidar_to_image(self, points: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        return self.rect_to_image(self.lidar_to_rect(points))

    # -- box conversions --------------------------------------------------------------
    def boxes_to_camera(
        self, boxes: ArrayLike
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """LiDAR boxes (M×7, centre origin) → KITTI label ``location`` (bottom centre),
        ``dimensions`` (h, w, l) and ``rotation_y``."""
        b = np.asarray(boxes, dtype=np.float64).reshape(-1, 7)
        bottom = b[:, :3].copy()
        bottom[:, 2] -= b[:, 5] / 2.0
        location = self.lidar_to_rect(bottom)
        dims_hwl = b[:, [5, 4, 3]]
        rotation_y = wrap_angle(-b[:, 6] - np.pi / 2.0)
        return location, dims_hwl, rotation_y

    def boxes_from_camera(self, location: ArrayLike, dims_hwl: ArrayLike, rotation_y: ArrayLike) -> NDArray[np.float64]:
        """KITTI label geometry → LiDAR boxes M×7 ``[x, y, z, l, w, h, yaw]`` (centre origin)."""
        loc = np.asarray(location, dtype=np.float64).reshape(-1, 3)
        hwl = np.asarray(dims_hwl, dtype=np.float64).reshape(-1, 3)
        ry = np.asarray(rotation_y, dtype=np.float64).reshape(-1)
        centre = self.rect_to_lidar(loc)
        centre[:, 2] += hwl[:, 0] / 2.0
        yaw = wrap_angle(-ry - np.pi / 2.0)
        return np.concatenate([centre, hwl[:, [2, 1, 0]], yaw[:, None]], axis=1)

    @staticmethod
    def camera_box_corners(location: ArrayLike, dims_hwl: ArrayLike, rotation_y: ArrayLike) -> NDArray[np.float64]:
        """M×8×3 corners of KITTI label boxes in the rectified camera frame (upright along camera y)."""
        loc = np.asarray(location, dtype=np.float64).reshape(-1, 3)
        h, w, length = np.asarray(dims_hwl, dtype=np.float64).reshape(-1, 3).T
        ry = np.asarray(rotation_y, dtype=np.float64).reshape(-1)
        x = np.stack([length, length, -length, -length] * 2, axis=1) / 2.0
        y = np.stack([np.zeros_like(h)] * 4 + [-h] * 4, axis=1)
        z = np.stack([w, -w, -w, w, w, -w, -w, w], axis=1) / 2.0
        c, s = np.cos(ry)[:, None], np.sin(ry)[:, None]
        return np.stack([c * x + s * z, y, -s * x + c * z], axis=-1) + loc[:, None, :]

    def boxes_to_image(self, boxes: ArrayLike, clip: bool = True) -> NDArray[np.float64]:
        """2D boxes ``[x1, y1, x2, y2]`` (M×4) as the devkit defines them: the extent of the label
        box's 8 corners (built upright in the camera frame) projected through P2, clipped to the image."""
        b = np.asarray(boxes, dtype=np.float64).reshape(-1, 7)
        if b.shape[0] == 0:
            return np.zeros((0, 4))
        corners = self.camera_box_corners(*self.boxes_to_camera(b)).reshape(-1, 3)
        uv, _ = self.rect_to_image(corners)
        uv = uv.reshape(-1, 8, 2)
        box2d = np.concatenate([uv.min(axis=1), uv.max(axis=1)], axis=1)
        if clip:
            height, width = self.image_shape
            box2d[:, [0, 2]] = np.clip(box2d[:, [0, 2]], 0, width - 1)
            box2d[:, [1, 3]] = np.clip(box2d[:, [1, 3]], 0, height - 1)
        return box2d

    def in_view(self, points: ArrayLike) -> NDArray[np.bool_]:
        """Mask of LiDAR-frame points in front of the camera that project inside the image."""
        uv, depth = self.lidar_to_image(points)
        height, width = self.image_shape
        with np.errstate(invalid="ignore"):
            return (depth > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < width) & (uv[:, 1] >= 0) & (uv[:, 1] < height)

    def alpha(self, boxes: ArrayLike) -> NDArray[np.float64]:
        """Observation angle as the devkit's tooling computes it: ``-arctan2(-y, x) + rotation_y``."""
        b = np.asarray(boxes, dtype=np.float64).reshape(-1, 7)
        rotation_y = -b[:, 6] - np.pi / 2.0
        alpha: NDArray[np.float64] = wrap_angle(-np.arctan2(-b[:, 1], b[:, 0]) + rotation_y)
        return alpha


def invertible(matrix: NDArray[np.float64]) -> bool:
    """Whether a 3×3 matrix has an inverse that float64 arithmetic can use: a rotation's condition
    number is 1; beyond 1e12 the inverse loses all but a few digits (or does not exist)."""
    with np.errstate(all="ignore"):
        condition = float(np.linalg.cond(matrix))
    return bool(np.isfinite(condition) and condition < 1e12)


def _is_float(token: str) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True
