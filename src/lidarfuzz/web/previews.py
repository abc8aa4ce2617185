"""Operator previews: one built-in simulator frame before and after an operator, from above.

The frame is rendered once by the simulator (:func:`lidarfuzz.sim.render_frames`, seed 0)
and kept in the app's cache as a full-scene ``.npz``; each picture (operator × severity ×
seed) is drawn with matplotlib as the report's bird's-eye pictures are
(:mod:`lidarfuzz.report.bev`: x forward upwards, y left to the left, darker with height,
ground truth in green) and kept as PNG bytes on disk, so it is drawn once.
"""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Any

import numpy as np

from lidarfuzz import __version__
from lidarfuzz.scene.scene import Scene

FRAME_SEED = 0
X_RANGE = (-10.0, 50.0)
Y_RANGE = (-30.0, 30.0)
MAX_POINTS = 20_000
GT_COLOUR = "#1a9850"
_frame_lock = threading.Lock()


def preview_frame(cache: Path) -> Scene:
    """The preview frame: rendered by the simulator on first use, read from the cache after."""
    from lidarfuzz.io.frames import read_frame, write_frame

    path = cache / f"preview-frame-seed{FRAME_SEED}-v{__version__}.npz"
    with _frame_lock:
        if not path.is_file():
            from lidarfuzz.sim import GenerationConfig, render_frames

            scene = next(iter(render_frames(GenerationConfig(frames=1, seed=FRAME_SEED))))
            cache.mkdir(parents=True, exist_ok=True)
            write_frame(path, scene, overwrite=True)
        return read_frame(path)


def _panel(ax: Any, scene: Scene, title: str, seed: int) -> None:
    from matplotlib.collections import LineCollection

    from lidarfuzz.scene.geometry import box_corners

    xyz = np.asarray(scene.points.xyz, dtype=np.float64)
    inside = ((xyz[:, 0] >= X_RANGE[0]) & (xyz[:, 0] <= X_RANGE[1]) & (xyz[:, 1] >= Y_RANGE[0])
              & (xyz[:, 1] <= Y_RANGE[1]))
    xyz = xyz[inside]
    if len(xyz) > MAX_POINTS:
        xyz = xyz[np.random.default_rng(seed).choice(len(xyz), MAX_POINTS, replace=False)]
    if len(xyz):
        ax.scatter(-xyz[:, 1], xyz[:, 0], c=np.clip(xyz[:, 2], -2.5, 1.5), s=0.6, cmap="Greys", vmin=-3.0, vmax=1.5,
                   linewidths=0, rasterized=True)
    boxes = scene.boxes.as_array()
    boxes = boxes[np.all(np.isfinite(boxes), axis=1)]
    if len(boxes):
        footprints = box_corners(boxes)[:, :4, :2]
        lines = [np.column_stack([-np.r_[f[:, 1], f[:1, 1]], np.r_[f[:, 0], f[:1, 0]]]) for f in footprints]
        ax.add_collection(LineCollection(lines, colors=GT_COLOUR, linewidths=0.9))
    ax.set_xlim(-Y_RANGE[1], -Y_RANGE[0])
    ax.set_ylim(*X_RANGE)
    ax.set_aspect("equal")
    ax.set_title(f"{title}: {len(scene.points):,} points, {len(boxes)} objects", fontsize=9)
    ax.tick_params(labelsize=7)
    ax.plot([0], [0], marker="^", color="black", markersize=4)


def render_preview(frame: Scene, name: str, severity: int, seed: int) -> bytes:
    """PNG bytes: ``frame`` and its mutant under operator ``name`` at ``severity``."""
    from matplotlib.figure import Figure

    from lidarfuzz.operators import generator, get
    from lidarfuzz.report.charts import figure_png

    op = get(name).at_severity(severity)
    mutant, _ = op(frame, generator(seed, frame.frame_id, 0, 0))
    fig = Figure(figsize=(8.0, 4.4), dpi=80, layout="constrained")
    left, right = fig.subplots(1, 2)
    _panel(left, frame, "original", seed)
    _panel(right, mutant, f"{op.name}@{severity}", seed + 1)
    return figure_png(fig, colours=64)


def preview_png(cache: Path, name: str, severity: int, seed: int = 0, lock: threading.Lock | None = None) -> bytes:
    """The cached preview of operator ``name`` (its registry name) at ``severity``, drawn on first use."""
    path = cache / "previews" / f"{name}-s{severity}-seed{seed}-v{__version__}.png"
    if path.is_file():
        return path.read_bytes()
    with lock or threading.Lock():
        if path.is_file():
            return path.read_bytes()
        png = render_preview(preview_frame(cache), name, severity, seed)
        path.parent.mkdir(parents=True, exist_ok=True)
        temporary = path.with_suffix(f".{threading.get_ident()}.tmp")
        temporary.write_bytes(png)
        temporary.replace(path)
        return png


__all__ = ["preview_frame", "preview_png", "render_preview"]
