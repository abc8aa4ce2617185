"""Regenerate docs/operators.md's operator catalogue and its before/after pictures.

Usage: ``.venv/bin/python docs/scripts/render_operators.py [--only lidar|camera]`` (needs the
``docs`` extra: matplotlib).

The catalogues (everything between the ``<!-- catalogue -->`` markers of docs/operators.md for
the LiDAR operators, between the ``<!-- camera catalogue -->`` markers for the camera ones) are
generated from the operator registry — docstrings, parameters, severity tables, relations and
targets — so the page cannot drift from the code. Each LiDAR operator is shown at severity 3
on one HDL-64E simulator frame: the bird's-eye view before and after, and the points of the
mutant projected into the front camera. Each camera operator is shown at severities 1, 3 and 5
beside the original on a drawn 640×480 road frame with a z-depth map (:func:`road_frame`).
"""

from __future__ import annotations

import argparse
import inspect
import sys
import time
from io import BytesIO
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from PIL import Image

from lidarfuzz.operators import available, generator
from lidarfuzz.operators.catalogue import severity_rows
from lidarfuzz.scene.geometry import bev_corners
from lidarfuzz.scene.image import ImageSample
from lidarfuzz.scene.scene import Scene
from lidarfuzz.sim import GenerationConfig, render_frames

DOCS = Path(__file__).resolve().parents[1]
IMAGES = DOCS / "images" / "operators"
PAGE = DOCS / "operators.md"
BEGIN, END = "<!-- catalogue -->", "<!-- /catalogue -->"
CAMERA_BEGIN, CAMERA_END = "<!-- camera catalogue -->", "<!-- /camera catalogue -->"
SEED = 12
DPI = 60


def _bev(ax: plt.Axes, scene: Scene, title: str) -> None:
    p = scene.points.data
    keep = (np.abs(p[:, 0] - 15) < 45) & (np.abs(p[:, 1]) < 30)
    ax.scatter(p[keep, 0], p[keep, 1], s=0.5, c=p[keep, 2], cmap="viridis", vmin=-2.0, vmax=2.5, linewidths=0)
    boxes = scene.boxes.select(scene.boxes.has_geometry)
    for corners in bev_corners(boxes.as_array()):
        ax.plot(*np.vstack([corners, corners[:1]]).T, color="#ff4d4d", lw=0.8)
    ax.set_xlim(-30, 60)
    ax.set_ylim(-30, 30)
    ax.set_aspect("equal")
    ax.set_facecolor("#101418")
    ax.set_title(title, fontsize=9)
    ax.tick_params(labelsize=7)


def _camera(ax: plt.Axes, scene: Scene) -> None:
    calib = scene.calib
    height, width = calib.image_shape
    uv, depth = calib.lidar_to_image(scene.points.xyz)
    ok = (depth > 0.5) & (uv[:, 0] >= 0) & (uv[:, 0] < width) & (uv[:, 1] >= 0) & (uv[:, 1] < height)
    ax.scatter(uv[ok, 0], uv[ok, 1], s=0.6, c=np.minimum(depth[ok], 60), cmap="turbo_r", linewidths=0)
    for box in scene.boxes.bbox2d[np.isfinite(scene.boxes.bbox2d).all(axis=1)]:
        x1, y1, x2, y2 = box
        ax.plot([x1, x2, x2, x1, x1], [y1, y1, y2, y2, y1], color="#ff4d4d", lw=0.8)
    ax.set_xlim(0, width)
    ax.set_ylim(height, 0)
    ax.set_facecolor("black")
    ax.set_title("mutant in the front camera", fontsize=9)
    ax.tick_params(labelsize=7)


def figure(name: str, before: Scene, after: Scene, path: Path) -> None:
    fig = plt.figure(figsize=(15, 3.6))
    grid = fig.add_gridspec(1, 3, width_ratios=[1, 1, 1.6])
    _bev(fig.add_subplot(grid[0]), before, f"before ({len(before.points):,} points)")
    _bev(fig.add_subplot(grid[1]), after, f"{name}, severity 3 ({len(after.points):,} points)")
    _camera(fig.add_subplot(grid[2]), after)
    fig.tight_layout()
    buffer = BytesIO()
    fig.savefig(buffer, format="png", dpi=DPI, facecolor="white")
    plt.close(fig)
    buffer.seek(0)
    with Image.open(buffer) as image:  # 256 colours: a quarter of a true-colour PNG's size
        image.convert("RGB").quantize(colors=128, method=Image.Quantize.FASTOCTREE, dither=Image.Dither.NONE).save(
            path, optimize=True)


def catalogue(scene: Scene) -> str:
    lines = []
    by_family: dict[str, list[str]] = {}
    for name, cls in available().items():
        if cls.modality == "lidar":
            by_family.setdefault(cls.family, []).append(name)
    lines.append("| operator | aliases | family | relation | changes |")
    lines.append("|---|---|---|---|---|")
    for family in sorted(by_family):
        for name in sorted(by_family[family]):
            cls = available()[name]
            lines.append(f"| [`{name}`](#{name.replace('_', '-')}) | {', '.join(cls.aliases)} | {family} | "
                         f"{cls.relation.value} | {', '.join(sorted(t.value for t in cls.targets))} |")
    lines.append("")
    for family in sorted(by_family):
        lines.append(f"## {family.capitalize()}\n")
        for name in sorted(by_family[family]):
            cls = available()[name]
            aliases = f" ({', '.join(cls.aliases)})" if cls.aliases else ""
            lines.append(f"### {name.replace('_', '-')}\n")
            lines.append(f"**`{name}`**{aliases} — {cls.relation.value}; changes "
                         f"{', '.join(sorted(t.value for t in cls.targets))}.\n")
            lines.append(inspect.getdoc(cls) or "")
            lines.append("")
            lines.append("| parameter | meaning | " + " | ".join(f"severity {s}" for s in (0, *cls.SEVERITIES)) + " |")
            lines.append("|---|---|" + "---:|" * (len(cls.SEVERITIES) + 1))
            for field, description, values in severity_rows(cls):
                lines.append(f"| `{field}` | {description} | " + " | ".join(values) + " |")
            lines.append("")
            image = IMAGES / f"{name}.png"
            op = cls.at_severity(3)
            mutant, _ = op(scene, generator(0, scene.frame_id, 0, 0))
            figure(name, scene, mutant, image)
            lines.append(f"![{name} at severity 3](images/operators/{name}.png)\n")
            print(f"  {name}: {image.stat().st_size / 1024:.0f} KB", flush=True)
    return "\n".join(lines)


def road_frame(width: int = 640, height: int = 480) -> ImageSample:
    """A drawn road scene for the camera pictures: sky, grass, a straight two-lane road with a
    dashed centre line and a dark car 20 m ahead, seen by a level camera 1.65 m above the road
    with a 60° field of view; its z-depth map is exact for that geometry (sky: inf)."""
    f = width / (2 * np.tan(np.radians(30)))
    k = np.array([[f, 0.0, (width - 1) / 2], [0.0, f, (height - 1) / 2], [0.0, 0.0, 1.0]])
    u = np.arange(width, dtype=np.float64)[None, :] - k[0, 2]
    v = np.arange(height, dtype=np.float64)[:, None] - k[1, 2]
    ground = np.broadcast_to(v > 0, (height, width))
    z = np.where(ground, f * 1.65 / np.where(v > 0, v, 1.0), np.inf) * np.ones((1, width))
    x = np.where(ground, u * z / f, 0.0)
    rng = np.random.default_rng(SEED)
    sky = np.array([150.0, 190.0, 235.0]) + (np.array([235.0, 240.0, 245.0]) - [150.0, 190.0, 235.0]) * np.clip(
        (v + k[1, 2]) / k[1, 2], 0, 1)[..., None]
    image = np.broadcast_to(sky, (height, width, 3)).copy()
    grass = np.array([70.0, 120.0, 50.0])
    asphalt = np.array([90.0, 90.0, 95.0])
    road = np.abs(x) < 3.6
    image[ground & ~road] = grass
    image[ground & road] = asphalt
    edge = ground & (np.abs(np.abs(x) - 3.45) < 0.1)
    centre = ground & (np.abs(x) < 0.07) & (np.mod(np.where(ground, z, 0.0), 9.0) < 4.5)
    image[edge | centre] = 235.0
    car_z, car_x, car_w, car_h = 20.0, 1.8, 1.8, 1.5
    cu = (np.array([car_x - car_w / 2, car_x + car_w / 2]) * f / car_z + k[0, 2]).round().astype(int)
    cv = (np.array([1.65 - car_h, 1.65]) * f / car_z + k[1, 2]).round().astype(int)
    image[cv[0]:cv[1], cu[0]:cu[1]] = [150.0, 30.0, 30.0]
    z[cv[0]:cv[1], cu[0]:cu[1]] = car_z
    image += rng.normal(0.0, 6.0, image.shape) * ground[..., None]
    return ImageSample(np.clip(image, 0, 255).astype(np.uint8), frame_id="road", steering=0.0,
                       depth=z.astype(np.float32), intrinsics=k)


def camera_figure(name: str, frame: ImageSample, path: Path) -> None:
    """Original and severities 1, 3, 5 side by side, each 320×240."""
    cls = available()[name]
    cells = [frame.image]
    for severity in (1, 3, 5):
        mutant, _ = cls.at_severity(severity)(frame, generator(0, frame.frame_id, 0, severity))
        cells.append(mutant.image)
    small = [np.asarray(Image.fromarray(c).resize((320, 240), Image.Resampling.BOX)) for c in cells]
    gap = np.full((240, 4, 3), 255, np.uint8)
    strip = np.concatenate([part for cell in small for part in (cell, gap)][:-1], axis=1)
    Image.fromarray(strip).quantize(colors=128, method=Image.Quantize.FASTOCTREE, dither=Image.Dither.NONE).save(
        path, optimize=True)


def camera_catalogue(frame: ImageSample) -> str:
    names = sorted((cls.family, name) for name, cls in available().items() if cls.modality == "camera")
    lines = ["| operator | aliases | family | relation | harmless up to | changes |", "|---|---|---|---|---:|---|"]
    for family, name in names:
        cls = available()[name]
        targets = ", ".join(sorted(t.value for t in cls.targets))
        lines.append(f"| [`{name}`](#{name.replace('_', '-')}) | {', '.join(cls.aliases)} | {family} | "
                     f"{cls.relation.value} | {cls.harmless_up_to} | {targets} |")
    lines.append("")
    for family, name in names:
        cls = available()[name]
        aliases = f" ({', '.join(cls.aliases)})" if cls.aliases else ""
        lines.append(f"### {name.replace('_', '-')}\n")
        lines.append(f"**`{name}`**{aliases} — {family}, {cls.relation.value} up to severity {cls.harmless_up_to} "
                     f"({cls.harmless_because}); changes {', '.join(sorted(t.value for t in cls.targets))}.\n")
        lines.append(inspect.getdoc(cls) or "")
        lines.append("")
        lines.append("| parameter | meaning | " + " | ".join(f"severity {s}" for s in (0, *cls.SEVERITIES)) + " |")
        lines.append("|---|---|" + "---:|" * (len(cls.SEVERITIES) + 1))
        for field, description, values in severity_rows(cls):
            lines.append(f"| `{field}` | {description} | " + " | ".join(values) + " |")
        lines.append("")
        image = IMAGES / f"{name}.png"
        camera_figure(name, frame, image)
        lines.append(f"![{name}: original, severities 1, 3 and 5](images/operators/{name}.png)\n")
        print(f"  {name}: {image.stat().st_size / 1024:.0f} KB", flush=True)
    return "\n".join(lines)


def _replace(text: str, begin: str, end: str, body: str) -> str:
    if begin not in text or end not in text:
        raise SystemExit(f"{PAGE}: missing the {begin} … {end} markers")
    head, rest = text.split(begin, 1)
    _, tail = rest.split(end, 1)
    return f"{head}{begin}\n{body}\n{end}{tail}"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", choices=["lidar", "camera"], help="regenerate one catalogue (default: both)")
    args = parser.parse_args()
    started = time.perf_counter()
    IMAGES.mkdir(parents=True, exist_ok=True)
    text = PAGE.read_text(encoding="utf-8")
    if args.only in (None, "lidar"):
        scene = next(render_frames(GenerationConfig(frames=1, seed=SEED)))
        text = _replace(text, BEGIN, END, catalogue(scene))
    if args.only in (None, "camera"):
        text = _replace(text, CAMERA_BEGIN, CAMERA_END, camera_catalogue(road_frame()))
    PAGE.write_text(text, encoding="utf-8")
    print(f"done in {time.perf_counter() - started:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
