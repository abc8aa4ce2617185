"""Per-frame domain randomisation for training PillarNet: the gap between the simulator and real scans.

Why these and not others: run on real KITTI frames, the detector trained on plain
simulator frames put 20 false car boxes on one frame's empty road, and every false box
came from the ground alone (they stay when every point more than 0.25 m above the
fitted ground is removed). The simulator's ground is a flat plane 1.73 m under the
sensor and every reading has some intensity; real ground dips and rises by tenths of a
metre over tens of metres, and 65–89 % of real returns beyond 30 m read intensity 0
(none do in the simulator). Pitching a simulator frame's ground up by 1° gave 42 false
cars on 4 frames (0 without), zeroing its far intensities as real ones are added 9 more,
and box heights were pinned to the flat ground's (a real car 0.3 m lower was boxed at
the simulator's height). The card beside the weights has the whole ablation.

So each training frame gets, from one seeded generator:

* **ground and mounting** (``ground_*``): the ground is warped by a height field
  ``dz + tan(pitch)·x + tan(roll)·y + curvature·x²`` about the sensor (a sloped,
  cambered, cresting road, or a sensor mounted higher or tilted); points of an object
  move with the height under its centre, like the object's box, so objects stay upright
  and keep every point;
* **intensity** (``intensity_*``): per-beam gain and offset (uncalibrated beams), a
  global gain and gamma, real dark returns — a share of 8–26 % of readings set to 0,
  chosen more often the farther and darker the return, as on real scans — quantisation
  to 0.01, and now and then intensity that is pure noise or absent, so the network
  cannot lean on intensity alone;
* **drop-out** (``drop_*``): random points, whole beams, every other beam (a sensor with
  half the beams), and background sectors that return nothing (glass, wet or black
  surfaces); objects lose points only with the random and beam drop-outs, so a labelled
  object never loses all its points to a sector;
* **structure beside objects** (``wall_*``): a wall, hedge or fence — a vertical strip of
  returns spaced as a scan spaces them at its range — put along a labelled object's far side,
  a few tenths of a metre to 1.5 m away, hiding what lies behind it. On a real KITTI frame a
  car 1 m beside a 16 m roadside structure was not found, although its own points, moved into
  a simulator scene, are (score 0.36–0.78), and the same structure put beside simulated cars
  took their scores under 0.3: the simulator seldom puts a car that close to a long structure,
  and the network learned that cars stand in the open. A wall never hides a labelled object's
  centre or cuts through one (it is not added where it would), and labelled objects keep every
  point;
* the classic global ones: flip about the x axis, rotation about z, scaling.

Geometric changes move points and boxes together (heading included); the function
returns which input point each output point is, so tests can check that every point
inside a box before is inside it after. Every draw comes from a CPU ``torch.Generator``
in a fixed order, so the same seed gives the same augmentation on the CPU and a GPU.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

#: Beam index assigned to points of frames without a ring channel: elevation bins of this size (degrees),
#: about the mean spacing of an HDL-64E's beams.
ELEVATION_BIN_DEG = 0.4


@dataclass(frozen=True)
class Augmentation:
    """What the per-frame domain randomisation may do (probabilities per frame, ranges uniform).

    Attributes:
        flip: Mirror about the x axis half the time.
        rotation: Largest rotation about z (radians).
        scale_range: Global scaling of points and boxes.
        ground_probability: Share of frames whose ground is warped.
        ground_dz_range: Vertical offset of the whole scene (metres; sensor mounted higher/lower).
        ground_slope_deg: Standard deviation of the pitch and roll of the ground plane (degrees),
            clipped at three of them.
        ground_curvature: Largest ``|c|`` of the ``c·x²`` term (a crest or a dip; 2e-4 is 0.5 m at 50 m).
        ground_max_rise: The warp (without ``dz``) is scaled down so that it stays within this many
            metres over the network's range: objects must stay inside its z range.
        intensity_probability: Share of frames whose intensities are remapped.
        intensity_beam_gain_sigma: Log-normal sigma of each beam's gain.
        intensity_beam_offset: Largest absolute offset per beam.
        intensity_gain_range, intensity_gamma_range: Global ``gain · i ** gamma``.
        intensity_zero_probability: Share of remapped frames given real dark returns.
        intensity_zero_share_range: Share of a frame's readings set to 0 (real KITTI: 8–26 %).
        intensity_quantise_probability: Share of remapped frames quantised to 0.01 (KITTI's step).
        intensity_noise_probability: Share of frames whose intensity is replaced by uniform noise.
        intensity_absent_probability: Share of frames whose intensity is all 0 (a sensor without it).
        drop_point_probability, drop_point_keep_range: Random point drop-out.
        drop_beam_probability, drop_beam_share_range: Whole beams lost.
        drop_half_beams_probability: Every other beam dropped (half the vertical resolution).
        drop_sector_probability, drop_sector_width_deg: A background sector that returns nothing.
        wall_probability: Share of frames given walls beside objects (0: never; the ``walls`` preset).
        wall_per_object: Chance that each labelled object of such a frame gets one.
        wall_gap_range: Gap between the object's side and the wall (metres).
        wall_length_range, wall_height_range: The wall's size (metres).
    """

    flip: bool = True
    rotation: float = math.pi / 8
    scale_range: tuple[float, float] = (0.95, 1.05)
    ground_probability: float = 0.8
    ground_dz_range: tuple[float, float] = (-0.2, 0.2)
    ground_slope_deg: float = 0.8
    ground_curvature: float = 2.5e-4
    ground_max_rise: float = 1.2
    intensity_probability: float = 0.8
    intensity_beam_gain_sigma: float = 0.2
    intensity_beam_offset: float = 0.03
    intensity_gain_range: tuple[float, float] = (0.6, 1.6)
    intensity_gamma_range: tuple[float, float] = (0.6, 1.5)
    intensity_zero_probability: float = 0.7
    intensity_zero_share_range: tuple[float, float] = (0.08, 0.26)
    intensity_quantise_probability: float = 0.7
    intensity_noise_probability: float = 0.05
    intensity_absent_probability: float = 0.03
    drop_point_probability: float = 0.5
    drop_point_keep_range: tuple[float, float] = (0.7, 1.0)
    drop_beam_probability: float = 0.3
    drop_beam_share_range: tuple[float, float] = (0.0, 0.1)
    drop_half_beams_probability: float = 0.1
    drop_sector_probability: float = 0.2
    drop_sector_width_deg: tuple[float, float] = (5.0, 25.0)
    wall_probability: float = 0.0
    wall_per_object: float = 0.5
    wall_gap_range: tuple[float, float] = (0.2, 1.5)
    wall_length_range: tuple[float, float] = (4.0, 18.0)
    wall_height_range: tuple[float, float] = (0.8, 2.2)

    @classmethod
    def preset(cls, name: str) -> Augmentation | None:
        """``default`` (domain randomisation), ``walls`` (that, and structure beside objects),
        ``geometric`` (flip, rotation, scaling only) or ``none``."""
        if name == "default":
            return cls()
        if name == "walls":
            return cls(wall_probability=0.6)
        if name == "geometric":
            return cls(ground_probability=0.0, intensity_probability=0.0, intensity_noise_probability=0.0,
                       intensity_absent_probability=0.0, drop_point_probability=0.0, drop_beam_probability=0.0,
                       drop_half_beams_probability=0.0, drop_sector_probability=0.0)
        if name == "none":
            return None
        raise ValueError(f"unknown augmentation {name!r}; choose default, walls, geometric or none")

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


def beam_index(torch: Any, points: Any) -> Any:
    """Beam of each point: the ring channel (column 4) where known, else an elevation bin.

    Frames without a ring channel carry −1 there (KITTI's ``.bin`` files); their points are
    binned by elevation in steps of :data:`ELEVATION_BIN_DEG`, which on a spinning sensor
    separates the beams well enough for per-beam gains and beam drop-outs.
    """
    ring = points[:, 4]
    if points.shape[0] == 0 or bool((ring >= 0).all()):
        return ring.long().clamp(0, 255)
    elevation = torch.rad2deg(torch.atan2(points[:, 2], torch.hypot(points[:, 0], points[:, 1])))
    binned = torch.floor((elevation + 30.0) / ELEVATION_BIN_DEG).long().clamp(0, 255)
    return torch.where(ring >= 0, ring.long().clamp(0, 255), binned)


def box_index_of_points(torch: Any, xyz: Any, boxes: Any) -> Any:
    """Index of the (first) box each point lies in, −1 for none (boxes ``x y z l w h yaw``, centre origin)."""
    if boxes.shape[0] == 0 or xyz.shape[0] == 0:
        return torch.full((xyz.shape[0],), -1, dtype=torch.long, device=xyz.device)
    d = xyz[:, None, :] - boxes[None, :, :3]
    cos, sin = torch.cos(boxes[:, 6]), torch.sin(boxes[:, 6])
    local_x = d[..., 0] * cos + d[..., 1] * sin
    local_y = -d[..., 0] * sin + d[..., 1] * cos
    inside = (
        (local_x.abs() <= boxes[:, 3] / 2) & (local_y.abs() <= boxes[:, 4] / 2) & (d[..., 2].abs() <= boxes[:, 5] / 2)
    )
    first = inside.to(torch.uint8).argmax(dim=1)
    return torch.where(inside.any(dim=1), first, torch.full_like(first, -1))


def _uniform(torch: Any, generator: Any, n: int, device: Any) -> Any:
    return torch.rand(n, generator=generator).to(device)


#: Angular spacing of a scan's returns (radians): horizontal (HDL-64E at 10 Hz) and vertical.
WALL_STEP_AZIMUTH = math.radians(0.09)
WALL_STEP_ELEVATION = math.radians(0.4)
WALL_MAX_POINTS = 6000


def add_walls(torch: Any, points: Any, boxes: Any, generator: Any, cfg: Augmentation) -> tuple[Any, Any]:
    """Walls along labelled objects' far sides (see the module docstring).

    Each wall is a vertical rectangle parallel to its object's heading, on the side away from the
    sensor, standing on the object's bottom; its returns are spaced as a scan at its range spaces
    them (jittered), and the background returns whose ray crosses it are removed (a labelled
    object keeps every point). A wall that would cut an object's footprint or hide an object's
    centre is not added.

    Returns:
        (points, source: for each output point its index in the input, −1 for a wall's).
    """
    device, dtype = points.device, points.dtype
    n = points.shape[0]
    source = torch.arange(n, device=device)
    m = boxes.shape[0]
    draws = torch.rand(max(m, 1), 6, generator=generator).tolist()
    walls, keep = [], torch.ones(n, dtype=torch.bool, device=device)
    owner = box_index_of_points(torch, points[:, :3], boxes)
    for i in range(m):
        u = draws[i]
        if u[0] >= cfg.wall_per_object:
            continue
        x, y, z, length, width, height, yaw = (float(v) for v in boxes[i].tolist())
        along = (math.cos(yaw), math.sin(yaw))
        normal = (-along[1], along[0])
        if normal[0] * x + normal[1] * y < 0:  # the far side: the normal points away from the sensor
            normal = (-normal[0], -normal[1])
        gap = cfg.wall_gap_range[0] + u[1] * (cfg.wall_gap_range[1] - cfg.wall_gap_range[0])
        span = cfg.wall_length_range[0] + u[2] * (cfg.wall_length_range[1] - cfg.wall_length_range[0])
        rise = cfg.wall_height_range[0] + u[3] * (cfg.wall_height_range[1] - cfg.wall_height_range[0])
        shift = (u[4] - 0.5) * max(span - length, 0.0)  # the object anywhere along the wall
        offset = width / 2 + gap
        cx, cy = x + normal[0] * offset + along[0] * shift, y + normal[1] * offset + along[1] * shift
        bottom = z - height / 2
        # the wall's ends and its plane n·p = d
        ends = [(cx - along[0] * span / 2, cy - along[1] * span / 2),
                (cx + along[0] * span / 2, cy + along[1] * span / 2)]
        d = normal[0] * cx + normal[1] * cy
        if not _wall_is_clear(boxes, i, normal, d, along, (cx, cy), span):
            continue
        walls.append((normal, d, along, (cx, cy), span, bottom, bottom + rise, ends))
    if not walls:
        return points, source
    new = []
    for normal, d, along, centre, span, bottom, top, ends in walls:
        # returns hidden by the wall: their ray from the sensor crosses the rectangle first
        dot = points[:, 0] * normal[0] + points[:, 1] * normal[1]
        t = d / dot.clamp(min=1e-6)
        hit_x, hit_y, hit_z = points[:, 0] * t, points[:, 1] * t, points[:, 2] * t
        along_hit = (hit_x - centre[0]) * along[0] + (hit_y - centre[1]) * along[1]
        hidden = (dot > 1e-6) & (t < 1.0) & (along_hit.abs() <= span / 2) & (hit_z >= bottom) & (hit_z <= top)
        keep &= ~(hidden & (owner < 0))  # a labelled object keeps every point
        # the wall's own returns, at the scan's spacing for its range
        distance = max(math.hypot(*centre), 2.0)
        azimuths = [math.atan2(e[1], e[0]) for e in ends]
        width_angle = abs(math.remainder(azimuths[1] - azimuths[0], 2 * math.pi))
        columns = max(2, min(int(width_angle / WALL_STEP_AZIMUTH), 4000))
        rows = max(2, min(int((top - bottom) / (distance * WALL_STEP_ELEVATION)) + 1, 64))
        count = min(columns * rows, WALL_MAX_POINTS)
        r = torch.rand(count, 4, generator=generator).to(device=device, dtype=dtype)
        position = (r[:, 0] - 0.5) * span
        px = centre[0] + along[0] * position + normal[0] * (r[:, 1] - 0.5) * 0.05
        py = centre[1] + along[1] * position + normal[1] * (r[:, 1] - 0.5) * 0.05
        pz = bottom + r[:, 2] * (top - bottom)
        intensity = r[:, 3] * 0.5
        ring = torch.full_like(px, -1.0)
        new.append(torch.stack([px, py, pz, intensity, ring], dim=1))
    added = torch.cat(new)
    points = torch.cat([points[keep], added])
    source = torch.cat([source[keep], torch.full((added.shape[0],), -1, dtype=source.dtype, device=device)])
    return points, source


def _wall_is_clear(boxes: Any, index: int, normal: tuple[float, float], d: float, along: tuple[float, float],
                   centre: tuple[float, float], span: float) -> bool:
    """The wall cuts no object's footprint and hides no object's centre from the sensor."""
    for j in range(boxes.shape[0]):
        x, y, _, length, width, _, yaw = (float(v) for v in boxes[j].tolist())
        corners = [(x + c * length / 2 * math.cos(yaw) - s * width / 2 * math.sin(yaw),
                    y + c * length / 2 * math.sin(yaw) + s * width / 2 * math.cos(yaw))
                   for c in (-1, 1) for s in (-1, 1)]
        sides = [normal[0] * cx + normal[1] * cy - d for cx, cy in corners]
        along_pos = [(cx - centre[0]) * along[0] + (cy - centre[1]) * along[1] for cx, cy in corners]
        if min(sides) < 0 < max(sides) and min(along_pos) < span / 2 and max(along_pos) > -span / 2:
            return False  # the wall's line runs through this object's footprint
        dot = normal[0] * x + normal[1] * y
        if j != index and dot > 1e-6 and d / dot < 1.0:
            hit = (x * d / dot - centre[0]) * along[0] + (y * d / dot - centre[1]) * along[1]
            if abs(hit) <= span / 2:
                return False  # the object stands behind the wall
    return True


def augment(
    torch: Any,
    points: Any,
    boxes: Any,
    generator: Any,
    cfg: Augmentation,
    *,
    x_max: float = 57.6,
) -> tuple[Any, Any, Any]:
    """One frame's domain randomisation (see the module docstring).

    Args:
        torch: The ``torch`` module (imported lazily by the caller).
        points: N×5 tensor ``x y z intensity ring`` (ring −1 where unknown), on any device.
        boxes: M×7 tensor ``x y z l w h yaw`` of the frame's labelled objects.
        generator: CPU ``torch.Generator``; every draw comes from it, in a fixed order.
        cfg: What may happen and how often.
        x_max: Far edge of the network's range, over which the ground warp is bounded.

    Returns:
        (points N'×5, boxes M×7, source N': index of each output point in the input). Boxes
        are never dropped; the inputs are not modified.
    """
    device = points.device
    n = points.shape[0]
    source = torch.arange(n, device=device)
    points, boxes = points.clone(), boxes.clone()
    # fixed-size draws first, so one frame's randomness does not depend on its point count
    u = torch.rand(24, generator=generator).tolist()
    normal = torch.randn(2, generator=generator).tolist()
    beam_gain = torch.exp(torch.randn(256, generator=generator) * cfg.intensity_beam_gain_sigma).to(device)
    beam_offset = ((torch.rand(256, generator=generator) * 2 - 1) * cfg.intensity_beam_offset).to(device)
    beam_lost = torch.rand(256, generator=generator).to(device)

    # structure beside objects: before anything reads the points, so walls get the same treatment
    # (drawn only when walls are on: the default's random stream stays that of the committed weights)
    if cfg.wall_probability > 0 and boxes.shape[0] and float(torch.rand(1, generator=generator)) < cfg.wall_probability:
        points, source = add_walls(torch, points, boxes, generator, cfg)
        n = points.shape[0]

    owner = box_index_of_points(torch, points[:, :3], boxes)
    beam = beam_index(torch, points)

    # ground and mounting: a height field about the sensor; objects ride on the height under their centre
    if u[0] < cfg.ground_probability:
        dz = cfg.ground_dz_range[0] + u[1] * (cfg.ground_dz_range[1] - cfg.ground_dz_range[0])
        limit = 3 * cfg.ground_slope_deg
        pitch = math.tan(math.radians(max(-limit, min(limit, normal[0] * cfg.ground_slope_deg))))
        roll = math.tan(math.radians(max(-limit, min(limit, normal[1] * cfg.ground_slope_deg))))
        curvature = (2 * u[2] - 1) * cfg.ground_curvature
        # the largest rise over x in [0, x_max], |y| <= x (the camera's view is narrower)
        rise = abs(pitch) * x_max + abs(roll) * x_max + abs(curvature) * x_max**2
        shrink = min(1.0, cfg.ground_max_rise / rise) if rise > 0 else 1.0
        pitch, roll, curvature = pitch * shrink, roll * shrink, curvature * shrink

        def height(x: Any, y: Any) -> Any:
            return dz + pitch * x + roll * y + curvature * x * x

        box_lift = height(boxes[:, 0], boxes[:, 1])
        point_lift = height(points[:, 0], points[:, 1])
        if boxes.shape[0]:
            point_lift = torch.where(owner >= 0, box_lift[owner.clamp(min=0)], point_lift)
        points[:, 2] += point_lift
        boxes[:, 2] += box_lift

    # intensity
    intensity = points[:, 3]
    if u[3] < cfg.intensity_probability and n:
        if u[4] < 0.5:
            intensity = intensity * beam_gain[beam] + beam_offset[beam]
        gain = cfg.intensity_gain_range[0] + u[5] * (cfg.intensity_gain_range[1] - cfg.intensity_gain_range[0])
        gamma = cfg.intensity_gamma_range[0] + u[6] * (cfg.intensity_gamma_range[1] - cfg.intensity_gamma_range[0])
        intensity = (gain * intensity.clamp(0.0, 1.0) ** gamma).clamp(0.0, 1.0)
        if u[7] < cfg.intensity_zero_probability:
            share = cfg.intensity_zero_share_range[0] + u[8] * (
                cfg.intensity_zero_share_range[1] - cfg.intensity_zero_share_range[0]
            )
            k = round(share * n)
            if k:
                # weighted sampling without replacement (Gumbel top-k): far, dark returns read 0 first
                distance = torch.hypot(points[:, 0], points[:, 1]).clamp(min=1.0)
                weight = torch.log((distance / 20.0) ** 3 * (1.05 - intensity))
                gumbel = -torch.log(-torch.log(_uniform(torch, generator, n, device).clamp(1e-12, 1 - 1e-7)))
                intensity = intensity.clone()
                intensity[torch.topk(weight + gumbel, k).indices] = 0.0
        if u[9] < cfg.intensity_quantise_probability:
            intensity = torch.floor(intensity * 100.0 + 1e-4) / 100.0
    if u[10] < cfg.intensity_noise_probability:
        intensity = _uniform(torch, generator, n, device)
    elif u[11] < cfg.intensity_absent_probability:
        intensity = torch.zeros_like(intensity)
    points[:, 3] = intensity

    # drop-out
    keep = torch.ones(n, dtype=torch.bool, device=device)
    if u[12] < cfg.drop_point_probability:
        share = cfg.drop_point_keep_range[0] + u[13] * (cfg.drop_point_keep_range[1] - cfg.drop_point_keep_range[0])
        keep &= _uniform(torch, generator, n, device) < share
    if u[14] < cfg.drop_beam_probability:
        share = cfg.drop_beam_share_range[0] + u[15] * (cfg.drop_beam_share_range[1] - cfg.drop_beam_share_range[0])
        keep &= beam_lost[beam] >= share
    if u[16] < cfg.drop_half_beams_probability:
        keep &= (beam % 2) == (1 if u[17] < 0.5 else 0)
    if u[18] < cfg.drop_sector_probability:
        centre = math.radians(-45.0 + 90.0 * u[19])  # inside the camera's view
        width = math.radians(cfg.drop_sector_width_deg[0] + u[20] * (
            cfg.drop_sector_width_deg[1] - cfg.drop_sector_width_deg[0]))
        azimuth = torch.atan2(points[:, 1], points[:, 0])
        off = torch.remainder(azimuth - centre + math.pi, 2 * math.pi) - math.pi
        keep &= ~((off.abs() < width / 2) & (owner < 0))
    points, source = points[keep], source[keep]

    # global flip, rotation about z, scaling (rigid on everything)
    if cfg.flip and u[21] < 0.5:
        points[:, 1] = -points[:, 1]
        boxes[:, 1] = -boxes[:, 1]
        boxes[:, 6] = -boxes[:, 6]
    angle = (2 * u[22] - 1) * cfg.rotation
    if angle:
        cos, sin = math.cos(angle), math.sin(angle)
        rot = torch.tensor([[cos, -sin], [sin, cos]], dtype=points.dtype, device=device)
        points[:, :2] = points[:, :2] @ rot.T
        boxes[:, :2] = boxes[:, :2] @ rot.T
        boxes[:, 6] = torch.remainder(boxes[:, 6] + angle + math.pi, 2 * math.pi) - math.pi
    scale = cfg.scale_range[0] + u[23] * (cfg.scale_range[1] - cfg.scale_range[0])
    points[:, :3] *= scale
    boxes[:, :6] *= scale
    return points, boxes, source


__all__ = ["ELEVATION_BIN_DEG", "Augmentation", "add_walls", "augment", "beam_index", "box_index_of_points"]
