"""The camera of the built-in world: an RGB image and a z-depth map of the world the LiDAR sees.

:class:`CameraRenderer` renders KITTI's colour camera 2 over the same compiled world as a
:class:`~lidarfuzz.sim.render.Renderer` (its Embree scene of the static world, its road users),
from the calibration's camera pose (``Tr_velo_to_cam``, ``R0_rect``, ``P2``) at the frame's
reference instant (the instant the LiDAR head faces forward; a global shutter: every road
user is posed at that instant):

1. **primary rays**, one through every pixel centre, traced by Embree against the static scene
   and the moving road users (posed at the instant);
2. **shading**: each surface's visible-light albedo (:data:`VISIBLE_ALBEDO`, beside the 905 nm
   reflectivities of :mod:`lidarfuzz.sim.materials`; a vehicle's paint a colour drawn from its
   own paint draw, :func:`paint_colour`), cheap procedural texture from hashed world
   coordinates (asphalt grain and patches, grass, paving joints, brick courses, lighter kerb
   faces), Lambert under the sun plus a sky ambient term; **hard shadows** from shadow rays
   towards the sun (Embree occlusion queries) on every other row and column, and wherever
   those disagree (a pixel between four that agree, on its own material, takes their answer);
   glass mirrors the sky; a tyre's outer face, coplanar with its vehicle's side, wins over the
   paint inside the wheel's disc;
3. **sky**: a gradient from a pale, hazy horizon to a blue zenith, a glow around the sun; far
   surfaces fade into the horizon haze (aerial perspective);
4. a film-like exposure curve and sRGB's encoding into 8 bits.

The sun's direction is drawn from the scene's seed (:func:`lighting_of`), so a sequence keeps
its light and every render is deterministic.

**Image sizes and intrinsics.** The calibration describes KITTI's 1242×375 camera. Another
size keeps KITTI's principal-ray geometry: the image is KITTI's scaled by ``s = W / 1242``
(the same horizontal field of view, the focal length and principal point scaled by ``s``) and
padded (or cropped) equally above and below to ``H`` rows, i.e. ``P2' = S·P2`` with
``S = [[s, 0, 0], [0, s, (H − 375·s)/2], [0, 0, 1]]`` (:func:`camera_calibration`). At 640×480
that is ``f = 371.8`` px, 81.3° horizontally and 65.7° vertically, the principal point at
(314.1, 232.5): KITTI's view with more road below and more sky above. The written ``calib/``
file holds the scaled matrices, so LiDAR points projected with its ``P2`` land on the pixels
that show them.

Example:
    >>> from lidarfuzz.sim.generate import generate_scene
    >>> from lidarfuzz.sim.render import Renderer
    >>> from lidarfuzz.sim.world import compile_world
    >>> camera = CameraRenderer(Renderer(compile_world(generate_scene(3))), (64, 48))
    >>> sample = camera.render(0.0)
    >>> sample.image.shape, sample.depth.dtype.name
    ((48, 64, 3), 'float32')
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from functools import cache, lru_cache
from typing import Any

import numpy as np
from embreex import rtcore_scene
from numpy.typing import NDArray

from lidarfuzz.scene.calib import KittiCalibration
from lidarfuzz.scene.image import ImageSample
from lidarfuzz.sim.actors import actor_mesh
from lidarfuzz.sim.materials import MATERIAL_ID, MATERIALS, PAINT_COLOURS, PAINT_MATERIAL
from lidarfuzz.sim.meshes import Mesh
from lidarfuzz.sim.render import Renderer, _thread_pool, add_triangles
from lidarfuzz.sim.terrain import frame_from_slopes
from lidarfuzz.sim.world import TILTING_CLASSES

#: Image sizes (width, height) the data set generator offers by name.
IMAGE_SIZES: dict[str, tuple[int, int]] = {"640x480": (640, 480), "1242x375": (1242, 375)}
DEFAULT_IMAGE_SIZE = IMAGE_SIZES["640x480"]
#: Rays reach this far (metres); nothing hit within it is sky.
FAR = 2000.0

#: Visible-light diffuse albedo (linear RGB, 0–1) of every material; the vehicles' paint is per
#: vehicle (:func:`paint_colour`), clothes and skin per person (:func:`clothing_colours`).
#: Rounded from typical values: fresh asphalt 0.05–0.10, road paint 0.6–0.8, dry grass and
#: foliage 0.1–0.25 with a green cast, brick red-brown, glass dark (it mirrors instead).
VISIBLE_ALBEDO: dict[str, tuple[float, float, float]] = {
    "asphalt": (0.085, 0.085, 0.09),
    "road-paint": (0.72, 0.72, 0.70),
    "paving": (0.32, 0.30, 0.28),
    "kerb": (0.50, 0.50, 0.48),
    "grass": (0.10, 0.19, 0.05),
    "pavement": (0.26, 0.25, 0.23),
    "soil": (0.22, 0.16, 0.10),
    "plaster": (0.62, 0.56, 0.46),
    "brick": (0.36, 0.14, 0.09),
    "window": (0.03, 0.04, 0.05),
    "concrete": (0.42, 0.42, 0.40),
    "fence": (0.30, 0.22, 0.14),
    "foliage": (0.06, 0.15, 0.04),
    "hedge": (0.05, 0.13, 0.04),
    "bark": (0.13, 0.09, 0.06),
    "metal": (0.36, 0.37, 0.39),
    "sign": (0.08, 0.20, 0.62),
    "tyre": (0.03, 0.03, 0.03),
    "car-glass": (0.02, 0.025, 0.03),
    "plate": (0.75, 0.75, 0.70),
    "light": (0.70, 0.30, 0.15),
    "cloth": (0.20, 0.20, 0.25),
    "skin": (0.55, 0.38, 0.28),
    "bike-frame": (0.50, 0.06, 0.05),
}
#: Share of the sky a surface mirrors (glass; paint's clear coat a little).
MIRROR: dict[str, float] = {"window": 0.35, "car-glass": 0.30}
PAINT_MIRROR = 0.06

#: Visible paint per colour group of :data:`~lidarfuzz.sim.materials.PAINT_COLOURS` (same order):
#: the darkest and the lightest of the group, mixed by the vehicle's own draw within its group.
_PAINT_GROUPS: tuple[tuple[tuple[float, float, float], tuple[float, float, float]], ...] = (
    ((0.60, 0.60, 0.58), (0.82, 0.82, 0.80)),  # white
    ((0.015, 0.015, 0.018), (0.035, 0.035, 0.04)),  # black
    ((0.08, 0.085, 0.09), (0.20, 0.20, 0.21)),  # grey
    ((0.35, 0.36, 0.38), (0.55, 0.56, 0.58)),  # silver
)
#: The other colours: red, dark blue, blue, green, yellow, orange, brown.
_PAINT_HUES = ((0.45, 0.03, 0.03), (0.03, 0.05, 0.20), (0.08, 0.18, 0.50), (0.05, 0.20, 0.08),
               (0.60, 0.45, 0.04), (0.60, 0.20, 0.03), (0.20, 0.11, 0.06))
_CLOTHES = ((0.03, 0.03, 0.04), (0.05, 0.07, 0.16), (0.25, 0.25, 0.27), (0.45, 0.06, 0.05), (0.50, 0.48, 0.42),
            (0.08, 0.16, 0.10), (0.35, 0.25, 0.12), (0.60, 0.58, 0.55))
_SKIN = ((0.60, 0.44, 0.34), (0.45, 0.30, 0.21), (0.26, 0.16, 0.10), (0.55, 0.40, 0.28))

#: Texture per material: fine grain (5 cm cells), coarse patches (value noise, 1.6 m), and how
#: much the patches shift the hue towards yellow-brown (grass, foliage).
_GRAIN = {"asphalt": 0.35, "road-paint": 0.12, "paving": 0.15, "kerb": 0.10, "grass": 0.45, "pavement": 0.20,
          "soil": 0.35, "plaster": 0.06, "brick": 0.12, "concrete": 0.12, "fence": 0.15, "foliage": 0.50,
          "hedge": 0.45, "bark": 0.30}
_PATCHES = {"asphalt": 0.30, "road-paint": 0.10, "paving": 0.12, "grass": 0.50, "pavement": 0.20, "soil": 0.40,
            "plaster": 0.08, "brick": 0.10, "concrete": 0.15, "foliage": 0.45, "hedge": 0.35}
_WITHER = {"grass": 0.6, "foliage": 0.35, "hedge": 0.3}


# --------------------------------------------------------------------------- light
@dataclass(frozen=True)
class Lighting:
    """The sun and the sky (linear RGB radiance units; an exposure maps them to pixels).

    Attributes:
        sun: Unit vector towards the sun (world frame, z up).
        sun_irradiance: Light from the sun on a surface facing it.
        sky_irradiance: Light from the sky on an upward surface (half of it on a wall).
        horizon: Sky radiance at the horizon (and the haze far surfaces fade into).
        zenith: Sky radiance straight up.
        haze_distance: Metres over which a surface's contrast falls to 1/e.
    """

    sun: tuple[float, float, float]
    sun_irradiance: tuple[float, float, float] = (2.6, 2.45, 2.2)
    sky_irradiance: tuple[float, float, float] = (0.55, 0.62, 0.78)
    horizon: tuple[float, float, float] = (0.80, 0.85, 0.92)
    zenith: tuple[float, float, float] = (0.22, 0.38, 0.78)
    haze_distance: float = 450.0


def lighting_of(seed: int) -> Lighting:
    """The light of a scene: the sun 25°–65° high, from any direction, drawn from ``seed``."""
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0xCA3]))
    elevation, azimuth = np.deg2rad(rng.uniform(25.0, 65.0)), rng.uniform(0.0, 2 * np.pi)
    sun = (np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth), np.sin(elevation))
    return Lighting(tuple(float(v) for v in sun))  # type: ignore[arg-type]


def sky_radiance(directions: NDArray[np.float32], light: Lighting) -> NDArray[np.float32]:
    """Sky radiance (N×3) seen along unit ``directions``: horizon haze to zenith blue, a sun glow."""
    up = np.clip(directions[:, 2], 0.0, 1.0)
    mix = np.sqrt(up / np.float32(0.7)).clip(0.0, 1.0)[:, None]
    horizon, zenith = np.asarray(light.horizon, np.float32), np.asarray(light.zenith, np.float32)
    sky = horizon + (zenith - horizon) * mix
    towards_sun = np.clip(directions @ np.asarray(light.sun, np.float32), 0.0, 1.0)
    glow = towards_sun ** 48 * np.float32(1.5) + towards_sun ** 6 * np.float32(0.15)
    return (sky + glow[:, None] * np.asarray(light.sun_irradiance, np.float32) / np.float32(2.6)).astype(np.float32)


# --------------------------------------------------------------------------- colours
def paint_colour(seed: int, index: int, cls: str) -> tuple[float, float, float]:
    """A road user's visible colour (linear RGB). Vehicles: from the same draws that chose their
    905 nm paint (:func:`~lidarfuzz.sim.materials.sample_paint`, stream ``[seed, index, 0xAC7]``),
    so a black car is black in both; people and bicycles: a colour for their clothes."""
    pick, within = np.random.default_rng([seed, index, 0xAC7]).random(2)
    if cls in ("Pedestrian", "Cyclist"):
        return _CLOTHES[int(pick * len(_CLOTHES)) % len(_CLOTHES)]
    shares = np.cumsum([c[0] for c in PAINT_COLOURS])
    group = min(int(np.searchsorted(shares, pick * shares[-1])), len(PAINT_COLOURS) - 1)
    if group < len(_PAINT_GROUPS):
        dark, light = (np.asarray(c) for c in _PAINT_GROUPS[group])
        return tuple(float(v) for v in dark + (light - dark) * within)  # type: ignore[return-value]
    return _PAINT_HUES[int(within * len(_PAINT_HUES)) % len(_PAINT_HUES)]


def clothing_colours(seed: int, index: int) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    """A person's clothes and skin (linear RGB), drawn from ``[seed, index, 0xC10]``."""
    top, skin = np.random.default_rng([seed, index, 0xC10]).random(2)
    return _CLOTHES[int(top * len(_CLOTHES)) % len(_CLOTHES)], _SKIN[int(skin * len(_SKIN)) % len(_SKIN)]


# --------------------------------------------------------------------------- geometry
def camera_calibration(calib: KittiCalibration, size: tuple[int, int]) -> KittiCalibration:
    """``calib`` for an image of ``size`` (width, height): every projection matrix scaled by
    ``S = [[s, 0, 0], [0, s, (H − H₀·s)/2], [0, 0, 1]]``, ``s = W / W₀`` (``H₀ × W₀`` the
    calibration's own image): the same horizontal field of view and principal ray, rows
    added (or cut) equally above and below.

    >>> calibration = camera_calibration(KittiCalibration.default(), (640, 480))
    >>> calibration.P2[:, :3].round(2).tolist(), calibration.image_shape
    ([[371.81, 0.0, 314.1], [0.0, 371.81, 232.45], [0.0, 0.0, 1.0]], (480, 640))
    """
    width, height = size
    height0, width0 = calib.image_shape
    scale = width / width0
    shift = np.array([[scale, 0.0, 0.0], [0.0, scale, (height - height0 * scale) / 2], [0.0, 0.0, 1.0]])
    scaled = {key: None if getattr(calib, key) is None else shift @ getattr(calib, key) for key in
              ("P0", "P1", "P2", "P3")}
    return KittiCalibration(R0_rect=calib.R0_rect, Tr_velo_to_cam=calib.Tr_velo_to_cam,
                            Tr_imu_to_velo=calib.Tr_imu_to_velo, image_shape=(height, width),
                            **scaled)  # type: ignore[arg-type]


def lidar_from_camera(calib: KittiCalibration) -> NDArray[np.float64]:
    """4×4 transform from camera 2's frame (rectified axes: x right, y down, z forward, origin
    at its centre) to the LiDAR's."""
    rect_from_lidar = np.eye(4)
    rect_from_lidar[:3, :3] = calib.R0_rect @ calib.Tr_velo_to_cam[:, :3]
    rect_from_lidar[:3, 3] = calib.R0_rect @ calib.Tr_velo_to_cam[:, 3]
    intrinsic, column = calib.P2[:, :3], calib.P2[:, 3]
    centre = -np.linalg.solve(intrinsic, column)  # camera 2's centre in the rectified frame
    camera_to_rect = np.eye(4)
    camera_to_rect[:3, 3] = centre
    return np.linalg.inv(rect_from_lidar) @ camera_to_rect  # type: ignore[no-any-return]


# --------------------------------------------------------------------------- texture
GRAIN_CELL = 0.05  #: metres: the fine grain's cells (asphalt chippings, grass blades)
PATCH_SCALE = 1.6  #: metres between the coarse patches' lattice points (wear, dry and lush grass)
_GRAIN_SIZE, _PATCH_SIZE, _PATCH_TEXEL = 512, 1024, 0.1


def _hash(ix: NDArray[np.int64], iy: NDArray[np.int64], seed: int) -> NDArray[np.float32]:
    """A pseudo-random value in [0, 1) per integer lattice point (a 32-bit integer hash)."""
    h = (ix.astype(np.uint32) * np.uint32(0x8DA6B343)) ^ (iy.astype(np.uint32) * np.uint32(0xD8163841))
    h ^= np.uint32(seed & 0xFFFFFFFF)
    h ^= h >> np.uint32(15)
    h *= np.uint32(0x2C1B3C6D)
    h ^= h >> np.uint32(12)
    h *= np.uint32(0x297A2D39)
    h ^= h >> np.uint32(15)
    return (h >> np.uint32(8)).astype(np.float32) * np.float32(1.0 / (1 << 24))


@cache
def _textures() -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """Two tiling noise textures, flattened: grain (one hashed value per :data:`GRAIN_CELL`
    cell, 512² cells) and patches (value noise on a :data:`PATCH_SCALE` lattice, smoothstep-
    interpolated, sampled every 0.1 m, 1024² texels: it repeats every 102.4 m). A frame looks
    them up at its world coordinates shifted by an offset drawn from its seed."""
    i, j = np.meshgrid(np.arange(_GRAIN_SIZE), np.arange(_GRAIN_SIZE), indexing="ij")
    grain = _hash(i, j, 0x9A1)
    period = round(_PATCH_SIZE * _PATCH_TEXEL / PATCH_SCALE)  # lattice points per repeat
    u = np.arange(_PATCH_SIZE) * (period / _PATCH_SIZE)
    cell = np.floor(u).astype(np.int64)
    frac = u - cell
    frac = frac * frac * (3 - 2 * frac)
    lattice = _hash(*np.meshgrid(np.arange(period), np.arange(period), indexing="ij"), 0x9A2)
    nxt = (cell + 1) % period
    rows = lattice[cell] + (lattice[nxt] - lattice[cell]) * frac[:, None]  # along the first axis
    patch = rows[:, cell] + (rows[:, nxt] - rows[:, cell]) * frac[None, :]
    return grain.ravel().astype(np.float32), patch.ravel().astype(np.float32)


def _lookup(texture: NDArray[np.float32], size: int, u: NDArray[np.float32], v: NDArray[np.float32],
            cell: float) -> NDArray[np.float32]:
    """``texture`` (``size``² texels of ``cell`` metres, tiling) at world coordinates (u, v), both
    positive (the frame's texture offset sees to it): truncation is then the floor."""
    iu = (u * np.float32(1 / cell)).astype(np.int32) & np.int32(size - 1)
    iv = (v * np.float32(1 / cell)).astype(np.int32) & np.int32(size - 1)
    return np.take(texture, iu * np.int32(size) + iv)  # take: faster than indexing with int32


def _stripes(coordinate: NDArray[np.float32], period: float, width: float) -> NDArray[np.bool_]:
    """Where ``coordinate`` lies within ``width`` of a multiple of ``period`` (joints, mortar)."""
    return np.mod(coordinate, np.float32(period)) < np.float32(width)  # type: ignore[no-any-return]


#: Radiance steps of the encoding table (:func:`_encoding_table`): 16384 up to radiance 8.
_ENCODE_STEPS, _ENCODE_TOP = 16384, 8.0


@cache
def _encoding_table(exposure: float) -> NDArray[np.uint8]:
    """8-bit sRGB of ``1 − exp(−exposure · L)`` for :data:`_ENCODE_STEPS` radiances ``L`` evenly
    spaced in [0, :data:`_ENCODE_TOP`] (encoding by lookup; a step is under 1.5 levels even
    in the darkest shadows)."""
    radiance = np.linspace(0.0, _ENCODE_TOP, _ENCODE_STEPS)
    x = 1.0 - np.exp(-exposure * radiance)
    srgb = np.where(x <= 0.0031308, x * 12.92, 1.055 * x ** (1 / 2.4) - 0.055)
    return np.round(srgb * 255.0).astype(np.uint8)  # type: ignore[no-any-return]


@lru_cache(maxsize=4)
def _pixel_rays(intrinsic: bytes, size: tuple[int, int]) -> tuple[NDArray[np.float32], ...]:
    """Every pixel centre's unit ray in the camera frame (x, y, z components, row-major), and the
    z-depth per metre along it (frames of one data set share them)."""
    width, height = size
    matrix = np.frombuffer(intrinsic, np.float64).reshape(3, 3)
    u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
    rays = np.linalg.solve(matrix, np.stack([u.ravel(), v.ravel(), np.ones(u.size)]))  # third row: (0, 0, 1)
    length = np.linalg.norm(rays, axis=0)
    return (*(np.ascontiguousarray(c / length, np.float32) for c in rays), (1.0 / length).astype(np.float32))


_MAX_WHEELS = 8


@lru_cache(maxsize=1024)
def _wheel_discs(cls: str, size: tuple[float, float, float]) -> NDArray[np.float64]:
    """The outer faces of a vehicle's wheels in its own frame: rows (x, z, radius, |y|) of the
    tyres of :func:`~lidarfuzz.sim.actors.actor_mesh` (zero rows pad to :data:`_MAX_WHEELS`)."""
    mesh = actor_mesh(cls, size)
    faces = mesh.faces[mesh.material == MATERIAL_ID["tyre"]]
    # Each wheel is its own cylinder: a run of vertices no other wheel shares.
    faces = faces[np.argsort(faces.min(axis=1), kind="stable")]
    reach = np.maximum.accumulate(faces.max(axis=1))
    starts = np.flatnonzero(faces.min(axis=1)[1:] > reach[:-1]) + 1
    out = np.zeros((_MAX_WHEELS, 4))
    for row, wheel in enumerate(np.split(faces, starts)[:_MAX_WHEELS]):
        v = mesh.vertices[np.unique(wheel)]
        out[row] = ((v[:, 0].min() + v[:, 0].max()) / 2, (v[:, 2].min() + v[:, 2].max()) / 2,
                    (v[:, 2].max() - v[:, 2].min()) / 2, np.abs(v[:, 1]).max())
    return out


def _unit_face_normals(mesh: Mesh) -> NDArray[np.float32]:
    if not len(mesh):
        return np.zeros((0, 3), np.float32)
    corners = mesh.vertices[mesh.faces]
    normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    return (normal / np.maximum(np.linalg.norm(normal, axis=1), 1e-12)[:, None]).astype(np.float32)


def _table(values: dict[str, float], paint: float = 0.0) -> NDArray[np.float32]:
    """A per-material table of 256 entries (materials, paint, zeros up to the sky's 255)."""
    out = np.zeros(256, np.float32)
    out[: len(MATERIALS)] = [values.get(name, 0.0) for name in MATERIALS]
    out[PAINT_MATERIAL] = paint
    return out


_ALBEDO = [_table({n: c[k] for n, c in VISIBLE_ALBEDO.items()}, 0.5) for k in range(3)]
_MIRROR = _table(MIRROR, PAINT_MIRROR)
_GRAIN_AMP = _table(_GRAIN)
_PATCH_AMP = _table(_PATCHES)
_WITHER_AMP = _table(_WITHER)
_WITHERED = (0.16, 0.13, 0.05)  # the colour dry grass and leaves tend to
SKY = 255  #: the material index of pixels that see the sky


# --------------------------------------------------------------------------- renderer
@dataclass(frozen=True)
class CameraLayers:
    """One render before encoding: linear radiance and what each pixel shows (for tests and tools).

    ``material`` indexes :data:`~lidarfuzz.sim.materials.MATERIAL_ID` (``PAINT_MATERIAL`` for
    paint, :data:`SKY` for sky); ``owner`` is the road user's index or −1; ``sunlit`` the share
    of the sun's light that reaches the surface (0 in shadow or facing away, else the cosine)."""

    radiance: NDArray[np.float32]  # H×W×3
    image: NDArray[np.uint8]  # H×W×3, encoded
    depth: NDArray[np.float32]  # H×W, inf for sky
    material: NDArray[np.uint8]
    owner: NDArray[np.int64]
    sunlit: NDArray[np.float32]
    normal: NDArray[np.float32]  # H×W×3, unit, facing the camera (zeros for sky)


@dataclass(frozen=True)
class _Instant:
    """What every band of a frame shares: the camera, the moving road users' scene and faces."""

    origin: NDArray[np.float32]
    rotation: NDArray[np.float32]
    moving: rtcore_scene.EmbreeScene | None
    material: NDArray[np.uint8]  # per face: the static faces, the sky row, the moving faces
    owner: NDArray[np.int64]
    normal: tuple[NDArray[np.float32], NDArray[np.float32], NDArray[np.float32]]
    moving_pixels: NDArray[np.bool_]  # pixels whose rays may meet a moving road user
    actor_origin: NDArray[np.float64]  # every road user's place (its bottom centre) and rotation
    actor_rotation: NDArray[np.float64]


class CameraRenderer:
    """Renders camera 2 of a :class:`~lidarfuzz.sim.render.Renderer`'s world.

    The image is cut into horizontal bands, one per tracing thread of the renderer; each band
    is traced and shaded on its own (Embree and numpy release the GIL), so a frame uses the
    cores as the LiDAR renderer does; the result does not depend on the split.

    Args:
        renderer: The LiDAR renderer whose world (and Embree scene) the camera sees.
        size: (width, height) of the image.
        lighting: The light (default: :func:`lighting_of` the scene's seed).
        exposure: Multiplies the radiance before encoding.
    """

    def __init__(self, renderer: Renderer, size: tuple[int, int] = DEFAULT_IMAGE_SIZE, *,
                 lighting: Lighting | None = None, exposure: float = 0.8) -> None:
        width, height = size
        if width < 8 or height < 8 or width > 8192 or height > 8192:
            raise ValueError(f"image size: {width}x{height} is outside 8x8 … 8192x8192")
        self.renderer = renderer
        self.size = (int(width), int(height))
        self.calib = camera_calibration(renderer.calib, self.size)
        world = renderer.world
        self.seed = int(world.spec.seed)
        self.lighting = lighting or lighting_of(self.seed)
        self.exposure = float(exposure)
        self._camera_to_lidar = lidar_from_camera(self.calib)
        *rays, self._depth_per_metre = _pixel_rays(self.calib.P2[:, :3].tobytes(), self.size)
        self._rays = (rays[0], rays[1], rays[2])
        # Per-face material, owner and unit normal of the static scene (the world, then the
        # still road users), then a row for the sky; a frame appends its moving road users'.
        still = renderer._still_mesh
        self._static_material = np.concatenate([world.static.material, still.material, [SKY]]).astype(np.uint8)
        self._static_owner = np.concatenate([np.full(len(world.static), -1, np.int64),
                                             renderer._still_owner.astype(np.int64), [-1]])
        static_normal = np.concatenate([_unit_face_normals(world.static), _unit_face_normals(still),
                                        np.zeros((1, 3), np.float32)])
        self._static_normal = (np.ascontiguousarray(static_normal[:, 0]), np.ascontiguousarray(static_normal[:, 1]),
                               np.ascontiguousarray(static_normal[:, 2]))
        self._world_faces = len(world.static)
        tops = [float(m.vertices[:, 2].max()) for m in (world.static, still) if len(m)]
        tallest = max((a.size[2] for a in world.actors), default=0.0)
        self._top = max(tops, default=0.0) + tallest + 2.0  # moving road users stand on the ground below it
        self._sky_row = len(self._static_material) - 1
        colours = np.zeros((len(world.actors) + 1, 3), np.float32)
        skins = np.zeros((len(world.actors) + 1, 3), np.float32)
        for actor in world.actors:
            clothes, skin = clothing_colours(self.seed, actor.index)
            colours[actor.index] = clothes if actor.cls in ("Pedestrian", "Cyclist") else \
                paint_colour(self.seed, actor.index, actor.cls)
            skins[actor.index] = skin
        self._actor_colour, self._actor_skin = colours, skins
        self._wheels = np.zeros((len(world.actors) + 1, _MAX_WHEELS, 4))
        for actor in world.actors:
            if actor.cls in TILTING_CLASSES:
                self._wheels[actor.index] = _wheel_discs(actor.cls, actor.size)
        self._still_actor_poses = np.zeros((len(world.actors) + 1, 6))
        for index, still_pose in renderer._still_poses.items():
            self._still_actor_poses[index] = still_pose
        # Texture coordinates are world coordinates shifted by 20–30 km: positive in any world.
        offset = np.random.default_rng(np.random.SeedSequence([self.seed, 0x7E7])).uniform(2.0e4, 3.0e4, 2)
        self._texture_offset = offset.astype(np.float32)

    @property
    def intrinsics(self) -> NDArray[np.float64]:
        """3×3 K of the image (``P2``'s left block)."""
        return np.array(self.calib.P2[:, :3])

    def pose(self, t_ref: float) -> NDArray[np.float64]:
        """4×4 camera → world transform at ``t_ref`` (camera axes: x right, y down, z forward)."""
        return self.renderer.pose_matrix(t_ref) @ self._camera_to_lidar  # type: ignore[no-any-return]

    def render(self, t_ref: float = 0.0, *, frame_id: str = "", steering: float | None = None,
               timestamp: float | None = None, metadata: dict[str, Any] | None = None) -> ImageSample:
        """The camera frame at ``t_ref`` seconds after the scene's start."""
        layers = self._render(t_ref, keep_layers=False)
        info = {"generator": "lidarfuzz.sim.camera", "scene": self.renderer.world.spec.name, "seed": self.seed,
                "scene_time": t_ref, "sun": list(self.lighting.sun), **(metadata or {})}
        return ImageSample(layers.image, frame_id=frame_id, steering=steering, depth=layers.depth,
                           intrinsics=self.intrinsics, timestamp=timestamp, pose=self.pose(t_ref), metadata=info)

    def layers(self, t_ref: float = 0.0) -> CameraLayers:
        """The frame at ``t_ref`` with its linear radiance and what every pixel shows."""
        return self._render(t_ref, keep_layers=True)

    def encode(self, radiance: NDArray[np.float32]) -> NDArray[np.uint8]:
        """Linear radiance → 8-bit sRGB: a film-like exposure curve ``1 − exp(−exposure · L)``
        (linear in the shadows, a soft shoulder: sunlit white paint and the sky do not clip),
        then sRGB's curve (by a 4096-entry table)."""
        scale = np.float32((_ENCODE_STEPS - 1) / _ENCODE_TOP)
        index = np.clip(radiance * scale + np.float32(0.5), 0.0, np.float32(_ENCODE_STEPS - 1)).astype(np.int32)
        return _encoding_table(self.exposure)[index]

    # ------------------------------------------------------------------ a frame
    def _render(self, t_ref: float, *, keep_layers: bool) -> CameraLayers:
        width, height = self.size
        instant = self._instant(t_ref)
        n = width * height
        threads = self.renderer.threads if n >= 40_000 else 1
        rows = np.linspace(0, height, threads + 1).astype(int) // 2 * 2  # bands start on even rows (shadows)
        rows[-1] = height
        bands = [slice(a * width, b * width) for a, b in itertools.pairwise(rows)]
        if threads == 1:
            parts = [self._band(instant, band, keep_layers) for band in bands]
        else:
            parts = list(_thread_pool(threads).map(lambda band: self._band(instant, band, keep_layers), bands))
        out = {key: np.concatenate([p[key] for p in parts]) for key in parts[0]}
        image = out["image"].reshape(height, width, 3)
        depth = out["depth"].reshape(height, width)
        if not keep_layers:
            empty = np.zeros((0, 0), np.float32)
            return CameraLayers(empty, image, depth, empty.astype(np.uint8), empty.astype(np.int64), empty, empty)
        return CameraLayers(out["radiance"].reshape(height, width, 3), image, depth,
                            out["material"].reshape(height, width), out["owner"].reshape(height, width),
                            out["sunlit"].reshape(height, width), out["normal"].reshape(height, width, 3))

    def _instant(self, t_ref: float) -> _Instant:
        """The camera's pose and the moving road users posed at ``t_ref``."""
        renderer = self.renderer
        pose = self.pose(t_ref)
        material, owner, normal = self._static_material, self._static_owner, self._static_normal
        moving_scene = None
        moving_pixels = np.zeros(self.size[0] * self.size[1], bool)
        actor_poses = self._still_actor_poses
        if renderer._moving:
            mesh, mesh_owner, moving_poses = renderer._moving_mesh(np.full(len(renderer.world.actors), t_ref))
            actor_poses = actor_poses.copy()
            moving = [a.index for a in renderer._moving]
            actor_poses[moving] = moving_poses[moving]
            if len(mesh):
                moving_scene = rtcore_scene.EmbreeScene(renderer._device)
                add_triangles(moving_scene, mesh.vertices, mesh.faces)
                material = np.concatenate([material, mesh.material])
                owner = np.concatenate([owner, mesh_owner.astype(np.int64)])
                faces = _unit_face_normals(mesh)
                normal = (np.concatenate([normal[0], faces[:, 0]]), np.concatenate([normal[1], faces[:, 1]]),
                          np.concatenate([normal[2], faces[:, 2]]))
                moving_pixels = self._pixels_towards(mesh, mesh_owner, pose)
        rotation = frame_from_slopes(actor_poses[:, 3], actor_poses[:, 4], actor_poses[:, 5])
        return _Instant(pose[:3, 3].astype(np.float32), pose[:3, :3].astype(np.float32), moving_scene, material,
                        owner, normal, moving_pixels, actor_poses[:, :3], rotation)

    def _pixels_towards(self, mesh: Mesh, owner: NDArray[np.int32], pose: NDArray[np.float64]) -> NDArray[np.bool_]:
        """Pixels inside the image rectangle of each road user of ``mesh`` (2 pixels wider): its
        bounding box in the camera frame, cut by the plane 0.5 m ahead of the camera, projected."""
        width, height = self.size
        camera = (mesh.vertices - pose[:3, 3]) @ pose[:3, :3]  # world → camera axes
        intrinsic = self.calib.P2[:, :3]
        covered = np.zeros((height, width), bool)
        near = 0.5  # nothing but the ego itself comes within 0.5 m ahead of the camera inside its view
        index_of_vertex = np.full(len(camera), -1, np.int64)  # vertices no face uses belong to no one
        index_of_vertex[mesh.faces.ravel()] = np.repeat(owner, 3)
        for index in np.unique(owner):
            vertices = camera[index_of_vertex == index]
            lo, hi = vertices.min(axis=0), vertices.max(axis=0)
            if hi[2] <= near:
                continue  # wholly behind the camera
            corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
            if lo[2] < near:  # straddles the near plane: keep its part ahead (a box: corners with z cut)
                corners = np.concatenate([corners[corners[:, 2] >= near],
                                          np.concatenate([corners[:, :2], np.full((8, 1), near)], axis=1)])
            projected = corners @ intrinsic.T
            u, v = projected[:, 0] / projected[:, 2], projected[:, 1] / projected[:, 2]
            u0, u1 = int(max(np.floor(u.min()) - 2, 0)), int(min(np.ceil(u.max()) + 3, width))
            v0, v1 = int(max(np.floor(v.min()) - 2, 0)), int(min(np.ceil(v.max()) + 3, height))
            if u0 < u1 and v0 < v1:
                covered[v0:v1, u0:u1] = True
        return covered.ravel()

    # ------------------------------------------------------------------ a band of rows
    def _band(self, instant: _Instant, band: slice, keep_layers: bool) -> dict[str, NDArray[Any]]:
        """Trace and shade the pixels ``band`` (a range of the row-major pixel order)."""
        light = self.lighting
        cx, cy, cz = (c[band] for c in self._rays)
        r = instant.rotation
        dx = r[0, 0] * cx + r[0, 1] * cy + r[0, 2] * cz
        dy = r[1, 0] * cx + r[1, 1] * cy + r[1, 2] * cz
        dz = r[2, 0] * cx + r[2, 1] * cy + r[2, 2] * cz
        n = len(dx)
        directions = np.stack([dx, dy, dz], axis=1)
        origins = np.empty((n, 3), np.float32)
        origins[:] = instant.origin

        # Nearest surface: the static scene, then the moving road users where they may be.
        row = np.full(n, self._sky_row, np.int64)
        distance = np.zeros(n, np.float32)
        static = self.renderer._static()
        if static is not None:
            found = static.run(origins, directions, dists=np.full(n, FAR, np.float32), output=1)
            geometry, face = found["geomID"], found["primID"].astype(np.int64)
            row = np.where(geometry == 0, face, np.where(geometry == 1, face + self._world_faces, row))
            distance = np.where(geometry >= 0, found["tfar"], np.float32(0.0))
        if instant.moving is not None:
            near = np.flatnonzero(instant.moving_pixels[band])
            if len(near):
                reach = np.where(row[near] != self._sky_row, np.nextafter(distance[near], np.float32(np.inf)),
                                 np.float32(FAR)).astype(np.float32)
                found = instant.moving.run(np.take(origins, near, axis=0), np.take(directions, near, axis=0),
                                           dists=reach, output=1)
                nearer = found["geomID"] >= 0
                row[near[nearer]] = self._sky_row + 1 + found["primID"][nearer]
                distance[near[nearer]] = found["tfar"][nearer]
        hit = row != self._sky_row
        # np.take: several times faster than fancy indexing for these 1-D gathers.
        material, owner = np.take(instant.material, row), np.take(instant.owner, row)
        nx, ny, nz = (np.take(c, row) for c in instant.normal)
        flip = np.where(nx * dx + ny * dy + nz * dz > 0, np.float32(-1.0), np.float32(1.0))  # face the camera
        nx, ny, nz = nx * flip, ny * flip, nz * flip
        px, py, pz = (instant.origin[0] + dx * distance, instant.origin[1] + dy * distance,
                      instant.origin[2] + dz * distance)

        # Sunlight: the cosine, and a shadow ray towards the sun from every surface facing it.
        sx, sy, sz = (np.float32(c) for c in light.sun)
        sunlit = np.maximum(nx * sx + ny * sy + nz * sz, np.float32(0.0))
        lit = sunlit > 0
        if lit.any():
            points, normals = (px, py, pz), (nx, ny, nz)
            # Every other row and column first; a pixel between four of them that agree (and show
            # the same material as it) takes their answer, the others (shadow edges) are traced.
            width = self.size[0]
            rows = n // width
            coarse = np.zeros((rows, width), bool)
            coarse[::2, ::2] = True
            coarse = coarse.ravel() & lit
            blocked = np.zeros(n, bool)
            first = np.flatnonzero(coarse)
            blocked[first] = self._occluded(instant, points, normals, first)
            state = np.where(coarse, blocked.astype(np.int8), np.int8(-1)).reshape(rows, width)[::2, ::2]
            kind = material.reshape(rows, width)[::2, ::2]
            # Pixel (r, c)'s coarse neighbours are (r//2, c//2) … ((r+1)//2, (c+1)//2): the coarse
            # grid doubled (padded with "unknown" at the far edges) and shifted by one pixel.
            state = np.pad(state, ((0, 1), (0, 1)), constant_values=-1).repeat(2, axis=0).repeat(2, axis=1)
            kind = np.pad(kind, ((0, 1), (0, 1))).repeat(2, axis=0).repeat(2, axis=1)
            here = material.reshape(rows, width)
            first_state = state[:rows, :width]
            agree = first_state >= 0
            for dr, dc in ((0, 0), (0, 1), (1, 0), (1, 1)):
                agree &= kind[dr:dr + rows, dc:dc + width] == here
                if dr or dc:
                    agree &= state[dr:dr + rows, dc:dc + width] == first_state
            agree = agree.ravel()
            between = lit & ~coarse
            inherit = between & agree
            blocked[inherit] = first_state.reshape(-1)[inherit] == 1
            rest = np.flatnonzero(between & ~agree)
            blocked[rest] = self._occluded(instant, points, normals, rest)
            sunlit[blocked] = 0.0

        self._wheel_faces(instant, material, owner, px, py, pz)
        albedo = self._albedo(material, owner, px, py, pz, nx, ny, nz, distance)
        ambient = np.float32(0.75) + np.float32(0.25) * nz
        channels = []
        for k in range(3):
            c = albedo[k] * (sunlit * np.float32(light.sun_irradiance[k]) + ambient * np.float32(
                light.sky_irradiance[k]))
            channels.append(c)
        shiny = np.flatnonzero(np.take(_MIRROR, material) > 0)
        if len(shiny):
            # The sky in the mirror direction (its height above the horizon is all the gradient needs).
            along = dx[shiny] * nx[shiny] + dy[shiny] * ny[shiny] + dz[shiny] * nz[shiny]
            up = np.clip(dz[shiny] - 2 * along * nz[shiny], 0.0, 1.0)
            mix = np.sqrt(np.minimum(up * np.float32(1 / 0.7), np.float32(1.0)))
            share = np.take(_MIRROR, material[shiny])
            for k in range(3):
                sky = np.float32(light.horizon[k]) + np.float32(light.zenith[k] - light.horizon[k]) * mix
                channels[k][shiny] += share * sky
        haze = np.float32(1.0) - np.exp(-distance * np.float32(1.0 / light.haze_distance))
        for k in range(3):
            channels[k] += (np.float32(light.horizon[k]) - channels[k]) * haze
        missed = np.flatnonzero(~hit)
        if len(missed):
            sky = sky_radiance(np.take(directions, missed, axis=0), light)
            for k in range(3):
                channels[k][missed] = sky[:, k]
        image = np.empty((n, 3), np.uint8)
        for k in range(3):
            image[:, k] = self.encode(channels[k])
        out: dict[str, NDArray[Any]] = {
            "image": image,
            "depth": np.where(hit, distance * self._depth_per_metre[band], np.float32(np.inf)).astype(np.float32),
        }
        if keep_layers:
            out.update(radiance=np.stack(channels, axis=1), material=material, owner=owner, sunlit=sunlit,
                       normal=np.stack([nx, ny, nz], axis=1) * hit[:, None])
        return out

    def _occluded(self, instant: _Instant, points: tuple[NDArray[np.float32], ...],
                  normals: tuple[NDArray[np.float32], ...], which: NDArray[np.intp]) -> NDArray[np.bool_]:
        """Whether the way to the sun from the surface points ``which`` is blocked (Embree occlusion
        queries against the static scene, then the moving road users)."""
        sun = self.lighting.sun
        lift = np.float32(0.02)  # off the surface, so it does not shade itself
        start = np.stack([points[k][which] + normals[k][which] * lift for k in range(3)], axis=1)
        towards = np.empty_like(start)
        towards[:] = sun
        # Nothing stands higher than the top of the world: a shadow ray can stop there.
        reach = np.maximum((np.float32(self._top) - start[:, 2]) / np.float32(sun[2]), np.float32(0.05))
        blocked = np.zeros(len(which), bool)
        for scene in (self.renderer._static(), instant.moving):
            todo = np.flatnonzero(~blocked)
            if scene is None or not len(todo):
                continue
            if len(todo) == len(which):
                occluded = scene.run(start, towards, dists=reach, query="OCCLUDED")
            else:
                occluded = scene.run(np.take(start, todo, axis=0), np.take(towards, todo, axis=0),
                                     dists=reach[todo], query="OCCLUDED")
            blocked[todo[occluded >= 0]] = True
        return blocked

    def _wheel_faces(self, instant: _Instant, material: NDArray[np.uint8], owner: NDArray[np.int64],
                     px: NDArray[np.float32], py: NDArray[np.float32], pz: NDArray[np.float32]) -> None:
        """Paint hits inside a wheel's disc become tyre (in place). A tyre's outer face lies in the
        plane of its vehicle's side, so Embree returns either at random (speckled wheels); the
        meshes stay as they are: the LiDAR's points must not change."""
        painted = np.flatnonzero(material == PAINT_MATERIAL)
        painted = painted[self._wheels[owner[painted], 0, 2] > 0]  # vehicles with wheels
        if not len(painted):
            return
        who = owner[painted]
        offset = np.stack([px[painted], py[painted], pz[painted]], axis=1) - instant.actor_origin[who]
        local = np.einsum("nij,ni->nj", instant.actor_rotation[who], offset)  # world → the vehicle's frame
        discs = self._wheels[who]  # n × wheels × (x, z, radius, outer |y|)
        inside = ((local[:, None, 0] - discs[:, :, 0]) ** 2 + (local[:, None, 2] - discs[:, :, 1]) ** 2
                  < discs[:, :, 2] ** 2) & (np.abs(local[:, None, 1]) > discs[:, :, 3] - 0.01)
        material[painted[inside.any(axis=1)]] = MATERIAL_ID["tyre"]

    def _albedo(self, material: NDArray[np.uint8], owner: NDArray[np.int64], px: NDArray[np.float32],
                py: NDArray[np.float32], pz: NDArray[np.float32], nx: NDArray[np.float32], ny: NDArray[np.float32],
                nz: NDArray[np.float32], distance: NDArray[np.float32]) -> list[NDArray[np.float32]]:
        """Visible albedo (three channels) of each pixel's surface with its procedural texture."""
        albedo = [np.take(table, material) for table in _ALBEDO]
        actor = np.flatnonzero(owner >= 0)
        if len(actor):
            kind = material[actor]
            for mask, colours in ((kind == PAINT_MATERIAL, self._actor_colour),
                                  (kind == MATERIAL_ID["cloth"], self._actor_colour),
                                  (kind == MATERIAL_ID["skin"], self._actor_skin)):
                chosen = actor[mask]
                for k in range(3):
                    albedo[k][chosen] = colours[owner[chosen], k]
        # Texture coordinates: the ground plane for flat faces, (along the wall, height) for walls.
        flat = np.abs(nz) > 0.7
        horizontal = np.maximum(np.sqrt(nx * nx + ny * ny), np.float32(1e-6))
        u = np.where(flat, px, (py * nx - px * ny) / horizontal) + self._texture_offset[0]
        v = np.where(flat, py, pz) + self._texture_offset[1]
        grain_texture, patch_texture = _textures()
        grain = _lookup(grain_texture, _GRAIN_SIZE, u, v, GRAIN_CELL) - np.float32(0.5)
        patch = _lookup(patch_texture, _PATCH_SIZE, u, v, _PATCH_TEXEL) - np.float32(0.5)
        # A pixel covers distance / f metres: grain finer than a pixel fades to a quarter (no shimmer).
        footprint = distance * np.float32(1.0 / self.calib.P2[0, 0])
        fade = np.clip(np.float32(1.5) - footprint * np.float32(1 / GRAIN_CELL), np.float32(0.25), np.float32(1.0))
        gain = (np.float32(1.0) + np.take(_GRAIN_AMP, material) * fade * grain) * (
            np.float32(1.0) + np.float32(2.0) * np.take(_PATCH_AMP, material) * patch)
        for k in range(3):
            albedo[k] *= gain
        green = np.flatnonzero(np.take(_WITHER_AMP, material) > 0)  # vegetation: patches dry towards yellow-brown
        if len(green):
            wither = np.take(_WITHER_AMP, material[green]) * (patch[green] + np.float32(0.5)) * np.float32(0.6)
            for k in range(3):
                albedo[k][green] += wither * (np.float32(_WITHERED[k]) - albedo[k][green])
        self._joints(albedo, material, u, v, footprint)
        return albedo

    @staticmethod
    def _joints(albedo: list[NDArray[np.float32]], material: NDArray[np.uint8], u: NDArray[np.float32],
                v: NDArray[np.float32], footprint: NDArray[np.float32]) -> None:
        """Regular patterns where a pixel resolves them (in place): paving joints, brick courses and mortar."""
        fine = footprint < 0.04
        paving = np.flatnonzero(((material == MATERIAL_ID["paving"]) | (material == MATERIAL_ID["pavement"])) & fine)
        if len(paving):
            joint = paving[_stripes(u[paving], 0.5, 0.025) | _stripes(v[paving], 0.5, 0.025)]
            for k in range(3):
                albedo[k][joint] *= np.float32(0.6)
        brick = np.flatnonzero((material == MATERIAL_ID["brick"]) & fine)
        if len(brick):
            course = np.floor(v[brick] / np.float32(0.15))
            offset = np.where(np.mod(course, 2) == 0, np.float32(0.0), np.float32(0.2))
            mortar = brick[_stripes(v[brick], 0.15, 0.02) | _stripes(u[brick] + offset, 0.4, 0.02)]
            for k, value in enumerate((0.45, 0.43, 0.40)):
                albedo[k][mortar] = value


__all__ = ["DEFAULT_IMAGE_SIZE", "IMAGE_SIZES", "MIRROR", "SKY", "VISIBLE_ALBEDO", "CameraLayers", "CameraRenderer",
           "Lighting", "camera_calibration", "clothing_colours", "lidar_from_camera", "lighting_of", "paint_colour",
           "sky_radiance"]
