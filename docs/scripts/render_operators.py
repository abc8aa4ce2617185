"""Regenerate docs/operators.md's operator catalogue and its before/after pictures.

Usage: ``.venv/bin/python docs/scripts/render_operators.py`` (needs the ``docs`` extra: matplotlib).

The catalogue (everything between the ``<!-- catalogue -->`` markers of
docs/operators.md) is generated from the operator registry — docstrings, parameters,
severity tables, relations and targets — so the page cannot drift from the code. Each
operator is shown at severity 3 on one HDL-64E simulator frame: the bird's-eye view
before and after, and the points of the mutant projected into the front camera.
"""

from __future__ import annotations

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
from lidarfuzz.scene.scene import Scene
from lidarfuzz.sim import GenerationConfig, render_frames

DOCS = Path(__file__).resolve().parents[1]
IMAGES = DOCS / "images" / "operators"
PAGE = DOCS / "operators.md"
BEGIN, END = "<!-- catalogue -->", "<!-- /catalogue -->"
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


def main() -> int:
    started = time.perf_counter()
    IMAGES.mkdir(parents=True, exist_ok=True)
    scene = next(render_frames(GenerationConfig(frames=1, seed=SEED)))
    text = PAGE.read_text(encoding="utf-8")
    if BEGIN not in text or END not in text:
        raise SystemExit(f"{PAGE}: missing the {BEGIN} … {END} markers")
    head, rest = text.split(BEGIN, 1)
    _, tail = rest.split(END, 1)
    PAGE.write_text(f"{head}{BEGIN}\n{catalogue(scene)}\n{END}{tail}", encoding="utf-8")
    print(f"done in {time.perf_counter() - started:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
