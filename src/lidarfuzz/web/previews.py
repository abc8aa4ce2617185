"""Operator previews (one built-in simulator frame before and after an operator, from above, with
the changed points highlighted) and the finding list's thumbnails.

The preview frame is rendered once by the simulator (:func:`lidarfuzz.sim.render_frames`, seed 0),
cut to the points within :data:`RADIUS` of the sensor (what the picture shows, also after a turn of
the scene) and kept in the app's cache as a full-scene ``.npz``. Each picture (operator × severity ×
seed) is rasterised with numpy and OpenCV rather than matplotlib (a tenth of the time: a cold preview
stays under a second) and kept as PNG bytes on disk, so it is drawn once. The look follows the 3D
viewer's ``change`` colouring (:func:`lidarfuzz.web.frames.change_flags`): on its dark background,
points in both clouds grey (lighter with height), points only the mutant has (added or moved) green,
points only the original has (removed or moved) red; ground truth outlined as the viewer draws it.
x (forward) is drawn upwards and y (left) to the left, as in the report's pictures.

Example:
    >>> png = preview_png(Path("cache"), "fog", 3)  # doctest: +SKIP
"""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from lidarfuzz import __version__
from lidarfuzz.scene.scene import Scene

FRAME_SEED = 0
X_RANGE = (-10.0, 50.0)  # forward, metres
Y_RANGE = (-30.0, 30.0)  # left, metres
RADIUS = 60.0  # the preview frame keeps the points this close to the sensor: the view's far corners are at 58.3 m
SCALE = 6.0  # pixels per metre: a 360 × 360 panel
HEADER = 44  # pixels above the panels: their titles and the legend
GAP = 6
PREVIEW_STYLE = 2  # bumped when the picture changes, so cached previews of an older look are not served
# the 3D viewer's colours (web/frontend/src/viewer/viewer.js: BACKGROUND, KEPT, ADDED, REMOVED, BOX_STYLES.gt)
BACKGROUND = (16, 18, 23)
KEPT = (120, 124, 132)
ADDED = (64, 255, 96)
REMOVED = (255, 64, 64)
GT_COLOUR = (52, 208, 88)
TEXT = (225, 228, 235)
_frame_lock = threading.Lock()
_draw_lock = threading.Lock()


def preview_frame(cache: Path) -> Scene:
    """The preview frame: rendered by the simulator on first use (and cut to :data:`RADIUS`), read
    from the cache after."""
    from lidarfuzz.io.frames import read_frame, write_frame

    path = cache / f"preview-frame-seed{FRAME_SEED}-r{RADIUS:g}-v{__version__}.npz"
    with _frame_lock:
        if not path.is_file():
            from lidarfuzz.sim import GenerationConfig, render_frames

            scene = next(iter(render_frames(GenerationConfig(frames=1, seed=FRAME_SEED))))
            xy = np.asarray(scene.points.xyz[:, :2], dtype=np.float64)
            near = np.flatnonzero(np.hypot(xy[:, 0], xy[:, 1]) <= RADIUS)
            cache.mkdir(parents=True, exist_ok=True)
            write_frame(path, scene.with_points(scene.points.select(near)), overwrite=True)
        return read_frame(path)


def _pixels(xy: NDArray[np.floating[Any]]) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.bool_]]:
    """Rows and columns of the panel for x, y in metres (forward up, left to the left), and which fall inside."""
    rows = np.floor((X_RANGE[1] - xy[:, 0]) * SCALE).astype(np.int64)
    cols = np.floor((Y_RANGE[1] - xy[:, 1]) * SCALE).astype(np.int64)
    size = _panel_size()
    inside = (rows >= 0) & (rows < size[0]) & (cols >= 0) & (cols < size[1])
    return rows, cols, inside


def _panel_size() -> tuple[int, int]:
    return round((X_RANGE[1] - X_RANGE[0]) * SCALE), round((Y_RANGE[1] - Y_RANGE[0]) * SCALE)


def _draw_points(panel: NDArray[np.uint8], xyz: NDArray[np.float32], changed: NDArray[np.bool_],
                 colour: tuple[int, int, int]) -> None:
    """Unchanged points grey, lighter with height (low ones first, so a tall object shows over the
    road); the changed ones over them in ``colour``, two pixels wide so a few stand out."""
    rows, cols, inside = _pixels(xyz)
    same = inside & ~changed
    order = np.argsort(xyz[same, 2], kind="stable")
    light = 0.45 + 0.55 * np.clip((xyz[same, 2][order] + 2.0) / 3.5, 0.0, 1.0)
    panel[rows[same][order], cols[same][order]] = (np.asarray(KEPT, np.float32) * light[:, None] * 1.25).clip(
        0, 255).astype(np.uint8)
    moved = inside & changed
    r, c = rows[moved], cols[moved]
    height, width = panel.shape[:2]
    for dr, dc in ((0, 0), (0, 1), (1, 0), (1, 1)):
        panel[np.minimum(r + dr, height - 1), np.minimum(c + dc, width - 1)] = colour


def _draw_boxes(panel: NDArray[np.uint8], scene: Scene) -> None:
    """Ground-truth footprints with a tick from the centre to the front face."""
    import cv2

    from lidarfuzz.scene.geometry import box_corners

    boxes = scene.boxes.as_array()
    boxes = boxes[np.all(np.isfinite(boxes), axis=1)]
    if not len(boxes):
        return
    for footprint, centre in zip(box_corners(boxes)[:, :4, :2], boxes[:, :2], strict=True):
        ring = np.vstack([footprint, (footprint[0] + footprint[1])[None] / 2, centre[None]])
        points = np.column_stack([(Y_RANGE[1] - ring[:, 1]) * SCALE, (X_RANGE[1] - ring[:, 0]) * SCALE])
        points = np.round(points).astype(np.int32)
        cv2.polylines(panel, [points[:4]], True, GT_COLOUR, 1, cv2.LINE_AA)
        cv2.line(panel, tuple(points[4]), tuple(points[5]), GT_COLOUR, 1, cv2.LINE_AA)


def _panel(scene: Scene, changed: NDArray[np.bool_], colour: tuple[int, int, int]) -> NDArray[np.uint8]:
    import cv2

    panel = np.empty((*_panel_size(), 3), np.uint8)
    panel[:] = BACKGROUND
    _draw_points(panel, np.asarray(scene.points.xyz, dtype=np.float32), changed, colour)
    _draw_boxes(panel, scene)
    row, col = round(X_RANGE[1] * SCALE), round(Y_RANGE[1] * SCALE)  # the sensor
    cv2.fillPoly(panel, [np.array([[col, row - 6], [col - 4, row + 4], [col + 4, row + 4]], np.int32)], TEXT)
    return panel


def _text(image: NDArray[np.uint8], text: str, x: int, y: int, colour: tuple[int, int, int] = TEXT) -> None:
    import cv2

    cv2.putText(image, text, (x, y), cv2.FONT_HERSHEY_SIMPLEX, 0.42, colour, 1, cv2.LINE_AA)


def _legend(image: NDArray[np.uint8], y: int) -> None:
    import cv2

    x = 8
    for colour, words in ((KEPT, "in both"), (ADDED, "only the mutant's (added or moved)"),
                          (REMOVED, "only the original's (removed or moved)"), (GT_COLOUR, "ground truth")):
        cv2.rectangle(image, (x, y - 8), (x + 8, y), colour, -1)
        _text(image, words, x + 12, y)
        x += 20 + 7 * len(words)


def preview_picture(frame: Scene, mutant: Scene, title: str) -> NDArray[np.uint8]:
    """Original | mutant from above (RGB): the original's points the mutant lacks in red, the
    mutant's points the original lacks in green (:func:`lidarfuzz.web.frames.change_flags`)."""
    from lidarfuzz.web.frames import change_flags

    before, after = change_flags(np.asarray(frame.points.data), np.asarray(mutant.points.data))
    removed, added = before != 0, after != 0
    left, right = _panel(frame, removed, REMOVED), _panel(mutant, added, ADDED)
    height, width = left.shape[:2]
    image = np.empty((HEADER + height, 2 * width + GAP, 3), np.uint8)
    image[:] = BACKGROUND
    image[HEADER:, :width], image[HEADER:, width + GAP:] = left, right
    _text(image, f"original: {len(frame.points):,} points, {removed.sum():,} not in the mutant", 8, 16)
    _text(image, f"{title}: {len(mutant.points):,} points, {added.sum():,} new or moved", width + GAP + 8, 16)
    _legend(image, 36)
    return image


def render_preview(frame: Scene, name: str, severity: int, seed: int) -> bytes:
    """PNG bytes: ``frame`` and its mutant under operator ``name`` at ``severity``."""
    from lidarfuzz.operators import generator, get
    from lidarfuzz.report.camera import png_bytes

    op = get(name).at_severity(severity)
    mutant, _ = op(frame, generator(seed, frame.frame_id, 0, 0))
    return png_bytes(preview_picture(frame, mutant, f"{op.name}@{severity}"))


def preview_png(cache: Path, name: str, severity: int, seed: int = 0, lock: threading.Lock | None = None) -> bytes:
    """The cached preview of operator ``name`` (its registry name) at ``severity``, drawn on first use."""
    path = cache / "previews" / f"{name}-s{severity}-seed{seed}-r{PREVIEW_STYLE}-v{__version__}.png"
    if path.is_file():
        return path.read_bytes()
    with lock or threading.Lock():
        if path.is_file():
            return path.read_bytes()
        png = render_preview(preview_frame(cache), name, severity, seed)
        _write(path, png)
        return png


# -- finding thumbnails ---------------------------------------------------------------------------
THUMB_SIZE = (160, 120)
THUMB_STYLE = 1  # bumped when the picture changes, so cached thumbnails of an older look are not served


def thumb_key(finding: Any, created: Any, modality: str) -> str:
    """What names a finding's thumbnail on disk: its id and a digest of what it shows (ids of a deleted
    task's findings may be given again to a new task's, so the id alone could serve a stale picture)."""
    import hashlib
    import json

    text = json.dumps([finding.id, finding.task_id, finding.frame_result_id, finding.kind, finding.cls,
                       finding.replay.dump(), str(created), modality, THUMB_STYLE, __version__],
                      sort_keys=True, default=str)
    return f"{finding.id}-{hashlib.sha1(text.encode()).hexdigest()[:16]}"


def render_thumbnail(store: Any, finding_id: int, modality: str, datasets: dict[str, Any]) -> bytes:
    """PNG bytes of a finding's thumbnail: a LiDAR finding's mutant from above, cropped to its objects
    (:func:`lidarfuzz.report.bev.draw_thumbnail`); a camera finding's transformed image."""
    width, height = THUMB_SIZE
    if modality == "camera":
        from lidarfuzz.campaign.camera import finding_pair
        from lidarfuzz.report.camera import frame_picture, png_bytes

        pair = finding_pair(store, finding_id, datasets)
        return png_bytes(frame_picture(pair["transformed"].image, label=None, width=width))
    from lidarfuzz.report.bev import draw_thumbnail, load_pair
    from lidarfuzz.report.charts import figure_png

    lidar_pair = load_pair(store, finding_id, datasets=datasets)
    with _draw_lock:  # matplotlib's shared state is not made for threads; the drawing is short
        return figure_png(draw_thumbnail(lidar_pair, width=width, height=height), colours=64)


def thumbnail_png(cache: Path, key: str, draw: Any, lock: threading.Lock | None = None) -> bytes:
    """The cached thumbnail named ``key`` (:func:`thumb_key`), drawn by ``draw()`` on first use."""
    path = cache / "thumbs" / f"{key}.png"
    if path.is_file():
        return path.read_bytes()
    with lock or threading.Lock():
        if path.is_file():
            return path.read_bytes()
        png: bytes = draw()
        _write(path, png)
        return png


def _write(path: Path, data: bytes) -> None:
    """``data`` to ``path`` through a temporary file, so a reader never sees half a picture."""
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_suffix(f".{threading.get_ident()}.tmp")
    temporary.write_bytes(data)
    temporary.replace(path)


__all__ = ["preview_frame", "preview_picture", "preview_png", "render_preview", "render_thumbnail", "thumb_key",
           "thumbnail_png"]
