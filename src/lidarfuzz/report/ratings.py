"""The rating experiment in pictures and tables (thesis, Table 6-7; :mod:`lidarfuzz.campaign.ratings`).

* :func:`pair_png`: what a rater sees — the original and the mutant side by side from above, points
  only. Blinded as the thesis's raters were: no operator, severity or parameter in the picture, no
  boxes (ground truth or detections would point at the objects the rater is asked to find). Both
  panels show the same window with every point in it (each marks its 12.5 cm cell, darker with
  height), so a mutant with fewer or more points looks sparser or denser, as it is — a subsample of a
  fixed size per panel would hide that. Drawn with Pillow from a raster of the points (not with
  matplotlib, whose layout alone takes seconds), a picture takes a few tens of milliseconds.
* :func:`rating_rows` / :func:`write_ratings_csv`: Table 6-7 as ``ratings.csv``, one row per
  operator × severity and the total row::

      operator, alias, severity, label, same, similar, different, total, same_share, similar_share,
      different_share, same_or_similar_share, pairs, raters, kappa

  (shares in [0, 1]; ``""`` for a share without verdicts or an undefined kappa).
* :func:`ratings_view`: the report's section (shown when there are verdicts).

Example:
    >>> png = pair_png(store, 1, 42)  # doctest: +SKIP
"""

from __future__ import annotations

import io
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from lidarfuzz.campaign.ratings import VERDICTS, RatingTally, TallyRow, pair_of
from lidarfuzz.errors import LidarfuzzError
from lidarfuzz.store.store import Store

if TYPE_CHECKING:
    from lidarfuzz.scene.scene import Scene

X_RANGE: tuple[float, float] = (-10.0, 70.0)  # forward, metres (the findings' pictures' window)
Y_RANGE: tuple[float, float] = (-40.0, 40.0)  # left, metres
CELL = 0.125  # metres per raster cell (about one screen pixel of a panel)
RATING_COLUMNS = ("operator", "alias", "severity", "label", "same", "similar", "different", "total", "same_share",
                  "similar_share", "different_share", "same_or_similar_share", "pairs", "raters", "kappa")


def load_scenes(store: Store, task_id: int, pair_id: int,
                datasets: dict[str, Any] | None = None) -> tuple[Scene, Scene, str]:
    """The original frame and its mutant (rebuilt from the stored operator spec and concrete params:
    no random number drawn) of pair ``pair_id``, and the frame id.

    Raises:
        NotFoundError: The task has no such pair.
        LidarfuzzError: The frame cannot be loaded or mutated again (the data set moved).
    """
    from lidarfuzz.operators.registry import from_spec
    from lidarfuzz.store.inventory import open_registered
    from lidarfuzz.store.models import FrameResult, Subtask, Task

    pair = pair_of(store, task_id, pair_id)
    with store.session() as s:
        result = s.get(FrameResult, pair_id)
        sub = s.get(Subtask, pair.subtask_id)
        task = s.get(Task, task_id)
        assert result is not None and sub is not None and task is not None  # pair_of found them
        params, spec, row = dict(result.params or {}), dict(sub.operator), task.dataset
        key = f"{row.path}|{row.options}"
    datasets = {} if datasets is None else datasets
    try:
        if key not in datasets:
            datasets[key] = open_registered(row)
        source = datasets[key].load(pair.frame_id)
    except Exception as exc:
        raise LidarfuzzError(f"frame {pair.frame_id} of data set {row.name!r} cannot be loaded "
                             f"({type(exc).__name__}); was the data set moved?") from exc
    try:
        op = from_spec(spec)
        mutant = op.apply(source, op.parse_params(params))
    except Exception as exc:
        raise LidarfuzzError(f"the mutant of frame {pair.frame_id} cannot be rebuilt ({type(exc).__name__}: {exc})") \
            from exc
    return source, mutant, pair.frame_id


def bev_raster(xyz: NDArray[np.float64]) -> NDArray[np.float64]:
    """The points of the window as an image seen from above: one cell per :data:`CELL` metres, row 0
    the farthest forward, column 0 the farthest left; 0 for an empty cell, else the darkness of its
    highest point, from 0.3 (2.5 m or more below the sensor) to 1 (1.5 m or more above it)."""
    (x0, x1), (y0, y1) = X_RANGE, Y_RANGE
    rows, cols = round((x1 - x0) / CELL), round((y1 - y0) / CELL)
    image = np.zeros((rows, cols), dtype=np.float64)
    xyz = xyz[(xyz[:, 0] >= x0) & (xyz[:, 0] < x1) & (xyz[:, 1] > y0) & (xyz[:, 1] <= y1)]
    if len(xyz):
        row = np.minimum(((x1 - xyz[:, 0]) / CELL).astype(np.int64), rows - 1)
        col = np.minimum(((y1 - xyz[:, 1]) / CELL).astype(np.int64), cols - 1)
        shade = 0.3 + 0.7 * (np.clip(xyz[:, 2], -2.5, 1.5) + 2.5) / 4.0
        np.maximum.at(image, (row, col), shade)
    return image


GRID_M = 10.0  # a faint line every 10 m, for scale
MARGIN = 16  # pixels around and between the panels
TITLE_H = 30  # pixels above the panels
FOOT_H = 26  # pixels below them


def _panel(xyz: NDArray[np.float64]) -> NDArray[np.uint8]:
    """One panel as grey pixels: white ground, a light 10 m grid, the points (:func:`bev_raster`)."""
    raster = bev_raster(xyz)
    grey = np.full(raster.shape, 255, dtype=np.uint8)
    step = round(GRID_M / CELL)
    grey[round(X_RANGE[1] / CELL) % step::step, :] = 232  # rows at whole tens of metres forward
    grey[:, round(Y_RANGE[1] / CELL) % step::step] = 232  # columns at whole tens of metres left/right
    hit = raster > 0
    grey[hit] = np.round(255 * (1.0 - raster[hit])).astype(np.uint8)
    return grey


def _font(size: int) -> Any:
    from PIL import ImageFont

    try:
        return ImageFont.load_default(size=size)
    except TypeError:  # Pillow < 10.1 has only its small bitmap font
        return ImageFont.load_default()


def rating_picture(source: Scene, mutant: Scene, frame_id: str) -> Any:
    """The blinded side-by-side picture (see the module docstring) as a Pillow RGB image: the original
    left, the mutant right, x (forward) up and y (left) to the left as a driver sees the road from
    above, the sensor as a red triangle."""
    from PIL import Image, ImageDraw

    panels = [_panel(np.asarray(scene.points.xyz, dtype=np.float64)) for scene in (source, mutant)]
    rows, cols = panels[0].shape
    width, height = 3 * MARGIN + 2 * cols, TITLE_H + rows + FOOT_H
    picture = Image.new("RGB", (width, height), "white")
    draw = ImageDraw.Draw(picture)
    title, small = _font(16), _font(12)
    sensor_row, sensor_col = round(X_RANGE[1] / CELL), round(Y_RANGE[1] / CELL)
    for index, (panel, caption) in enumerate(zip(panels, (f"original - frame {frame_id}", "mutant"), strict=True)):
        left = MARGIN + index * (cols + MARGIN)
        picture.paste(Image.fromarray(panel, "L").convert("RGB"), (left, TITLE_H))
        draw.rectangle((left - 1, TITLE_H - 1, left + cols, TITLE_H + rows), outline="#9aa3b2")
        draw.text((left + cols / 2, TITLE_H / 2), caption, fill="black", font=title, anchor="mm")
        x, y = left + sensor_col, TITLE_H + sensor_row
        draw.polygon([(x, y - 7), (x - 6, y + 5), (x + 6, y + 5)], fill="#d7191c")
    draw.text((MARGIN, TITLE_H + rows + FOOT_H / 2), f"seen from above: forward is up, left is left; grid "
              f"{GRID_M:g} m; {X_RANGE[1] - X_RANGE[0]:g} m x {Y_RANGE[1] - Y_RANGE[0]:g} m around the sensor "
              "(red); darker points are higher", fill="#555", font=small, anchor="lm")
    return picture


def pair_png(store: Store, task_id: int, pair_id: int, *, datasets: dict[str, Any] | None = None) -> bytes:
    """Pair ``pair_id``'s blinded picture as PNG bytes (the same pair always gives the same picture)."""
    source, mutant, frame_id = load_scenes(store, task_id, pair_id, datasets)
    buffer = io.BytesIO()
    rating_picture(source, mutant, frame_id).save(buffer, format="PNG")
    return buffer.getvalue()


def camera_image(store: Store, task_id: int, pair_id: int) -> tuple[bytes, str] | None:
    """The camera image of the pair's frame (KITTI's ``image_2/<frame>.png``) and its media type, as
    the thesis's raters had it; None when the data set has no images."""
    from lidarfuzz.campaign.lifecycle import get_task
    from lidarfuzz.io.images.kitti import IMAGE_SUFFIXES, find_image_root

    pair = pair_of(store, task_id, pair_id)
    root = find_image_root(get_task(store, task_id).dataset.path)
    if root is None:
        return None
    for suffix in IMAGE_SUFFIXES:
        path = root / "image_2" / f"{pair.frame_id}{suffix}"
        if path.is_file():
            return path.read_bytes(), "image/png" if suffix == ".png" else "image/jpeg"
    return None


# -- Table 6-7 ------------------------------------------------------------------------------------
def _cell(value: float | None) -> Any:
    return "" if value is None else round(value, 6)


def rating_rows(result: RatingTally) -> list[dict[str, Any]]:
    """Table 6-7's rows (see the module docstring), the total row last (``label`` ``all``)."""
    def row(r: TallyRow) -> dict[str, Any]:
        out: dict[str, Any] = {"operator": r.operator, "alias": r.alias, "severity": r.severity, "label": r.label,
                               "same": r.same, "similar": r.similar, "different": r.different, "total": r.total,
                               "same_or_similar_share": _cell(r.same_or_similar_share), "pairs": r.pairs,
                               "raters": r.raters, "kappa": _cell(r.kappa)}
        out.update({f"{v}_share": _cell(r.share(v)) for v in VERDICTS})
        return out

    return [row(r) for r in result.rows] + ([row(result.total)] if not result.empty else [])


def write_ratings_csv(result: RatingTally, path: str | Path) -> Path:
    """``ratings.csv`` (only the header when nobody has rated yet)."""
    from lidarfuzz.report.exports import write_csv

    return write_csv(rating_rows(result), RATING_COLUMNS, path)


def _pct(value: float | None) -> str:
    return "—" if value is None else f"{100 * value:.1f}%"


def ratings_view(result: RatingTally | None) -> dict[str, Any] | None:
    """The report's Table 6-7 section (None when nobody has rated a pair of the task)."""
    if result is None or result.empty:
        return None

    def row(r: TallyRow) -> Mapping[str, Any]:
        name = r.label if not r.alias else f"{r.label} ({r.alias})"
        return {"name": name, "counts": [getattr(r, v) for v in VERDICTS],
                "shares": [_pct(r.share(v)) for v in VERDICTS], "same_or_similar": _pct(r.same_or_similar_share),
                "pairs": r.pairs, "raters": r.raters, "kappa": "—" if r.kappa is None else f"{r.kappa:.3f}"}

    return {"rows": [row(r) for r in result.rows], "total": row(result.total), "raters": list(result.raters),
            "verdicts": list(VERDICTS)}


__all__ = ["RATING_COLUMNS", "bev_raster", "camera_image", "load_scenes", "pair_png", "rating_picture", "rating_rows",
           "ratings_view", "write_ratings_csv"]
