"""KITTI labels for a rendered frame: which road users get a label, and their truncation and occlusion.

Following the KITTI object benchmark, objects are labelled when they appear in the
front camera's image:

* **no label** when the object has no LiDAR point (fully occluded or out of range) or
  lies entirely outside the image;
* **DontCare** (a 2D region only) when it is too far (beyond ``dontcare_range``), has
  fewer than ``min_points`` points, or its 2D box is lower than ``min_height_px``;
* otherwise a full label: class, **truncation** = the share of the object's volume
  (a 5×5×5 grid of samples in its box) that projects outside the image or behind the
  camera; **occlusion** from visibility, the share of the LiDAR rays that would hit
  the object if it were alone that do hit it in the scene (≥ 0.8 → 0 fully visible,
  ≥ 0.4 → 1 partly occluded, otherwise 2 largely occluded); alpha and the 2D box as
  the devkit computes them from the 3D box; the 3D box.

Each box is placed where the sensor saw the object: at the instant the head swept
over it, in the sensor frame of that instant — the frame its points are expressed
in — so labels and points agree even for a moving ego vehicle and moving objects.
On sloping ground the box's bottom is on the ground under the object and its heading
is the object's, seen in the (tilted) sensor frame; as in KITTI, boxes turn about the
vertical only, so a vehicle on a grade that differs from the ego vehicle's by a few
per cent sticks out of its box by a few centimetres at its ends.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
from numpy.typing import NDArray

from lidarfuzz.scene.boxes import Boxes3D
from lidarfuzz.scene.geometry import box_corners
from lidarfuzz.scene.labels import image_boxes as _boxes2d
from lidarfuzz.scene.labels import image_coverage as _image_coverage
from lidarfuzz.scene.labels import occlusion_level
from lidarfuzz.sim.terrain import frame_from_slopes

if TYPE_CHECKING:
    from lidarfuzz.scene.calib import KittiCalibration
    from lidarfuzz.sim.meshes import Mesh
    from lidarfuzz.sim.sensor import LidarSensor
    from lidarfuzz.sim.world import World


class FrameRenderer(Protocol):
    """What labelling needs of the renderer that made the frame
    (:class:`lidarfuzz.sim.render.Renderer` is one; it calls :func:`label_actors`, so this
    module names only the part it uses)."""

    world: World
    sensor: LidarSensor
    calib: KittiCalibration

    def sensor_pose(self, t: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Sensor origins and rotations at times ``t``."""
        ...

    def visible_rays_alone(self, actors: Mesh, owner: NDArray[np.int32], index: int,
                           origins: NDArray[np.float32], directions: NDArray[np.float32],
                           candidates: NDArray[np.intp]) -> int:
        """How many of the ``candidates`` rays would hit actor ``index`` if nothing else were there."""
        ...


@dataclass(frozen=True)
class LabelConfig:
    dontcare_range: float = 80.0
    min_points: int = 5
    min_height_px: float = 12.0


def label_actors(
    renderer: FrameRenderer,
    *,
    t_ref: float,
    times: NDArray[np.float64],
    actor_poses: NDArray[np.float64],
    actors: Mesh,
    owner: NDArray[np.int32],
    origins: NDArray[np.float32],
    directions: NDArray[np.float32],
    geometric_owner: NDArray[np.int64],
    points_owner: NDArray[np.int64],
    config: LabelConfig,
) -> tuple[Boxes3D, dict[str, Any]]:
    """Boxes (labelled objects, then DontCare regions) and per-box extras for the frame's metadata."""
    world, calib = renderer.world, renderer.calib
    n = len(world.actors)
    if n == 0:
        return Boxes3D.empty(), {"objects": {"num_points": [], "visibility": []}}

    # Each actor's box in the sensor frame of the instant it was seen: its centre half its
    # height above the ground along its own up (vehicles tilt with the ground), its heading
    # projected onto the sensor's horizontal plane (KITTI boxes turn about the vertical only).
    origin, rotation = renderer.sensor_pose(times)
    sizes = np.array([a.size for a in world.actors], dtype=np.float64)
    body = frame_from_slopes(actor_poses[:, 3], actor_poses[:, 4], actor_poses[:, 5])
    centre = actor_poses[:, :3] + body[:, :, 2] * (sizes[:, 2:3] / 2)
    local_centre = np.einsum("nji,nj->ni", rotation, centre - origin)
    local_forward = np.einsum("nji,nj->ni", rotation, body[:, :, 0])
    boxes = np.column_stack([local_centre, sizes, np.arctan2(local_forward[:, 1], local_forward[:, 0])])
    num_points = np.bincount(points_owner[points_owner >= 0], minlength=n)[:n]
    geometric_hits = np.bincount(geometric_owner[geometric_owner >= 0], minlength=n)[:n]

    inside, in_front_uv = _image_coverage(calib, boxes)
    truncation = 1.0 - inside
    distance = np.hypot(boxes[:, 0], boxes[:, 1])
    box2d = _boxes2d(calib, boxes, in_front_uv)
    height_px = np.where(np.isfinite(box2d).all(axis=1), box2d[:, 3] - box2d[:, 1], 0.0)

    seen = (num_points > 0) & (truncation < 0.99)
    dontcare = seen & ((distance > config.dontcare_range) | (num_points < config.min_points)
                       | (height_px < config.min_height_px))
    labelled = seen & ~dontcare

    visibility = np.full(n, np.nan)
    for i in np.flatnonzero(labelled):
        candidates = _rays_towards(renderer, boxes[i])
        # Rays that hit the object in the scene would hit it alone too: cast only the others.
        hidden = candidates[geometric_owner[candidates] != i]
        alone = geometric_hits[i] + renderer.visible_rays_alone(actors, owner, int(i), origins, directions, hidden)
        visibility[i] = min(1.0, geometric_hits[i] / alone) if alone else 1.0

    track_ids = np.array([a.track_id for a in world.actors], np.int64)
    classes = np.array([a.cls for a in world.actors])
    keep = np.flatnonzero(labelled)
    order = keep[np.argsort(distance[keep], kind="stable")]
    labelled_boxes = Boxes3D.from_array(
        boxes[order], classes[order], track_ids=track_ids[order],
        truncation=np.round(np.clip(truncation[order], 0.0, 1.0), 2),
        occlusion=occlusion_level(visibility[order]),
        alpha=calib.alpha(boxes[order]), bbox2d=box2d[order],
    )
    regions = np.flatnonzero(dontcare)
    regions = regions[np.argsort(distance[regions], kind="stable")]
    dontcare_boxes = Boxes3D.create(
        np.full((len(regions), 3), np.nan), np.full((len(regions), 3), np.nan), np.full(len(regions), np.nan),
        ["DontCare"] * len(regions), track_ids=track_ids[regions], truncation=np.full(len(regions), np.nan),
        occlusion=np.full(len(regions), -1), alpha=np.full(len(regions), np.nan), bbox2d=box2d[regions],
    )
    result = Boxes3D.concat([labelled_boxes, dontcare_boxes])
    extras = {
        "objects": {
            "num_points": [int(num_points[i]) for i in order] + [int(num_points[i]) for i in regions],
            "visibility": [round(float(visibility[i]), 3) for i in order] + [None] * len(regions),
        },
    }
    return result, extras


def _rays_towards(renderer: FrameRenderer, box: NDArray[np.float64]) -> NDArray[np.intp]:
    """Indices of the rays fired into the box's angular extent (its columns, and the beams whose
    elevation reaches it, each widened by a margin)."""
    sensor = renderer.sensor
    corners = box_corners(box[None])[0]
    centre_azimuth = np.arctan2(box[1], box[0])
    spread = np.angle(np.exp(1j * (np.arctan2(corners[:, 1], corners[:, 0]) - centre_azimuth)))
    margin = 2.0 * 2.0 * np.pi / sensor.columns
    lo = float(spread.min()) - margin
    hi = float(spread.max()) + margin
    if np.hypot(box[0], box[1]) < np.hypot(box[3], box[4]) / 2 + 0.5:  # the sensor is (almost) inside the box
        lo, hi = -np.pi, np.pi
    count = int(np.ceil((hi - lo) / (2 * np.pi) * sensor.columns)) + 1
    first = int(np.floor(sensor.column_of_azimuth(centre_azimuth + hi)))  # clockwise: larger azimuth fires first
    columns = np.unique((first + np.arange(count)) % sensor.columns)
    beams = np.arange(sensor.beams)
    if lo > -np.pi:
        # Nearest and farthest ground distance of the box, and its bottom and top heights.
        near = max(float(np.hypot(corners[:, 0], corners[:, 1]).min()) - 0.3, 0.1)
        far = float(np.hypot(corners[:, 0], corners[:, 1]).max()) + 0.3
        bottom, top = float(corners[:, 2].min()) - 0.2, float(corners[:, 2].max()) + 0.2
        elevations = np.array([np.arctan2(bottom, far), np.arctan2(bottom, near), np.arctan2(top, far),
                               np.arctan2(top, near)])
        low, high = float(elevations.min()), float(elevations.max())
        keep = (sensor.ring_elevations >= low - np.deg2rad(1.0)) & (sensor.ring_elevations <= high + np.deg2rad(1.0))
        beams = beams[keep]
    return (columns[:, None] * sensor.beams + beams[None, :]).ravel()
