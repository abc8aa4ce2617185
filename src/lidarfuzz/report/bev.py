"""Bird's-eye before/after pictures of a finding, rebuilt exactly from what the store recorded.

The left panel is the original frame: its points, its ground truth and what the system
detected on it; the right panel is the mutant — rebuilt from the operator's spec and the
finding's concrete params, so no random number is drawn — with its ground truth and what
the system detected on it. The objects the finding is about are drawn in red: a source
detection or ground-truth object that the follow-up lost (thick, left) and where it was
expected in the mutant (dashed, right; moved by the operator's transform when the operator
has one), and follow-up detections nothing maps to (thick, right).

x (forward) is drawn upwards and y (left) to the left, as a driver sees the road from above.
The view covers x ∈ [-10, 70] m and y ∈ [-40, 40] m, grown to show every box the finding is
about, with at most 30 000 points (a subsample fixed by the finding's id).

Example:
    >>> from lidarfuzz.store import Store
    >>> png = finding_png(Store("workspace"), 6)  # doctest: +SKIP
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray
from sqlalchemy import select

from lidarfuzz.campaign.tasks import ORIGINAL, subtask_label
from lidarfuzz.errors import LidarfuzzError
from lidarfuzz.report.charts import figure_png
from lidarfuzz.scene.boxes import Boxes3D
from lidarfuzz.scene.geometry import box_corners, transform_boxes
from lidarfuzz.scene.scene import Scene
from lidarfuzz.store.contracts import TOOL_ERRORS
from lidarfuzz.store.models import Finding, FrameResult, Subtask, Task
from lidarfuzz.store.store import Store

if TYPE_CHECKING:
    from matplotlib.figure import Figure

X_RANGE: tuple[float, float] = (-10.0, 70.0)  # forward, metres
Y_RANGE: tuple[float, float] = (-40.0, 40.0)  # left, metres
MAX_POINTS = 30_000

GT_COLOUR = "#1a9850"
DETECTION_COLOUR = "#2b6cb0"
HIGHLIGHT_COLOUR = "#d7191c"


@dataclass(frozen=True)
class FindingPair:
    """Everything one finding's picture shows.

    Attributes:
        finding: id, kind, class, label, frame id, trial and message of the finding.
        source: The original frame (its boxes are the ground truth).
        mutant: The rebuilt mutant; None when the finding is about an original.
        source_detections: The system's output on the original (empty when it failed there).
        source_failed: True when the system failed on the original.
        follow_detections: The system's output on the mutant; None when it failed.
        lost_source: Indices of source detections the follow-up lost.
        lost_gt: Indices of source ground-truth boxes the follow-up lost.
        lost_gt_follow: The same objects' indices in the mutant's ground truth (-1: gone).
        spurious: Indices of follow-up detections nothing maps to.
        transform: The operator's 4×4 source → mutant map, when it has one.
        tool_error: lidarfuzz's own error on the mutant (a relation or the operator raised), never
            the system's: its message; the system's output is still drawn.
    """

    finding: Mapping[str, Any]
    source: Scene
    mutant: Scene | None
    source_detections: Boxes3D
    follow_detections: Boxes3D | None
    lost_source: tuple[int, ...] = ()
    lost_gt: tuple[int, ...] = ()
    lost_gt_follow: tuple[int, ...] = ()
    spurious: tuple[int, ...] = ()
    transform: NDArray[np.float64] | None = None
    source_failed: bool = False
    tool_error: str = ""


def _system_failed(row: FrameResult | None) -> bool:
    """Whether the system under test failed on ``row`` (lidarfuzz's own errors do not count)."""
    return row is None or (row.failure is not None and row.failure.kind not in TOOL_ERRORS)


def _indices(violations: Iterable[Mapping[str, Any]], key: str, size: int, object_level: bool = False) -> tuple[
        int, ...]:
    found = set()
    for violation in violations:
        index = violation.get(key)
        # a frame-level violation (DeepTest's regression) indexes its own rows, not boxes
        if object_level and not violation.get("cls"):
            continue
        if isinstance(index, int) and 0 <= index < size:
            found.add(index)
    return tuple(sorted(found))


def load_pair(store: Store, finding_id: int, *, datasets: dict[str, Any] | None = None) -> FindingPair:
    """Rebuild finding ``finding_id``'s frames and outputs.

    Args:
        store: The campaign store.
        finding_id: The finding.
        datasets: Opened data sets by path, reused across calls (filled in here).

    Raises:
        LidarfuzzError: When the finding does not exist, or its frame cannot be loaded or
            mutated again (e.g. the data set was moved).
    """
    from lidarfuzz.io.open import open_dataset
    from lidarfuzz.io.options import DatasetOptions
    from lidarfuzz.operators.registry import from_spec

    with store.session() as s:
        finding = s.get(Finding, finding_id)
        if finding is None:
            raise LidarfuzzError(f"no finding {finding_id} in the store")
        row = s.get(FrameResult, finding.frame_result_id)
        sub = s.get(Subtask, row.subtask_id) if row is not None else None
        if row is None or sub is None:
            raise LidarfuzzError(f"finding {finding_id}: its frame result is gone from the store")
        original = s.scalar(select(FrameResult).join(Subtask).where(
            Subtask.task_id == finding.task_id, Subtask.name == ORIGINAL, FrameResult.frame_id == row.frame_id,
            FrameResult.trial == 0))
        replay = finding.replay
        task = s.get(Task, finding.task_id)
        options = DatasetOptions.from_stored(task.dataset.options if task is not None else None)
        info = {"id": finding.id, "kind": finding.kind, "class": finding.cls, "message": finding.message,
                "label": subtask_label(sub.name, sub.severity), "frame_id": row.frame_id, "trial": row.trial}
        violations = list(finding.detail.get("violations", []))
        on_original = sub.name == ORIGINAL
        follow_detections = None if _system_failed(row) else row.detections.boxes()
        tool_error = row.failure.message if row.failure is not None and row.failure.kind in TOOL_ERRORS else ""
        source_detections = Boxes3D.empty()
        source_failed = _system_failed(original)
        if original is not None and not source_failed:
            source_detections = original.detections.boxes()

    path = replay.dataset
    datasets = {} if datasets is None else datasets
    key = f"{path}|{options.model_dump_json()}"  # one data set registered twice reads differently
    try:
        if key not in datasets:
            datasets[key] = open_dataset(path, options=options)
        source = datasets[key].load(row.frame_id)
    except Exception as exc:
        raise LidarfuzzError(f"frame {row.frame_id} of {path or 'an unknown data set'} cannot be loaded "
                             f"({type(exc).__name__}: {exc}); was the data set moved?") from exc
    mutant, transform = None, None
    if not on_original and replay.operator is not None:
        try:
            op = from_spec(replay.operator)
            params = op.parse_params(replay.params)
            mutant = op.apply(source, params)
            transform = op.transform(params)
        except Exception as exc:
            raise LidarfuzzError(f"the mutant of frame {row.frame_id} cannot be rebuilt "
                                 f"({type(exc).__name__}: {exc})") from exc

    lost_gt = _indices(violations, "gt_index", len(source.boxes), object_level=True)
    lost_gt_follow: tuple[int, ...] = ()
    if lost_gt and mutant is not None:
        from lidarfuzz.oracles.relations.detection import gt_correspondence

        corr = gt_correspondence(source.boxes, mutant.boxes)
        lost_gt_follow = tuple(int(corr[g]) if corr is not None else -1 for g in lost_gt)
    size = len(follow_detections) if follow_detections is not None else 0
    return FindingPair(info, source, mutant, source_detections, follow_detections,
                       lost_source=_indices(violations, "source_index", len(source_detections)),
                       lost_gt=lost_gt, lost_gt_follow=lost_gt_follow,
                       spurious=_indices(violations, "follow_index", size), transform=transform,
                       source_failed=source_failed, tool_error=tool_error)


# -- drawing ------------------------------------------------------------------------------
def _ids(indices: Sequence[int]) -> NDArray[np.int64]:
    return np.asarray(indices, dtype=np.int64)


def _outlines(boxes: NDArray[np.float64]) -> list[NDArray[np.float64]]:
    """Closed bird's-eye footprints with a heading tick, in plot coordinates (-y, x)."""
    if len(boxes) == 0:
        return []
    corners = box_corners(boxes)[:, :4, :2]
    lines = []
    for footprint, centre in zip(corners, boxes[:, :2], strict=True):
        front = (footprint[0] + footprint[1]) / 2
        ring = np.vstack([footprint, footprint[:1], front[None], centre[None]])
        lines.append(np.column_stack([-ring[:, 1], ring[:, 0]]))
    return lines


def _draw_boxes(ax: Any, boxes: Boxes3D | NDArray[np.float64], colour: str, width: float,
                style: str = "solid") -> None:
    from matplotlib.collections import LineCollection

    array = boxes.as_array() if isinstance(boxes, Boxes3D) else np.asarray(boxes, dtype=np.float64).reshape(-1, 7)
    array = array[np.all(np.isfinite(array), axis=1)]
    lines = _outlines(array)
    if lines:
        ax.add_collection(LineCollection(lines, colors=colour, linewidths=width, linestyles=style))


Limits = tuple[tuple[float, float], tuple[float, float]]


def _limits(boxes: Sequence[NDArray[np.float64]], margin: float = 6.0) -> Limits:
    """The default crop, grown to show every box the finding is about (e.g. one behind the car)."""
    (x0, x1), (y0, y1) = X_RANGE, Y_RANGE
    for array in boxes:
        centres = array[np.all(np.isfinite(array), axis=1), :2]
        if len(centres):
            x0, x1 = min(x0, centres[:, 0].min() - margin), max(x1, centres[:, 0].max() + margin)
            y0, y1 = min(y0, centres[:, 1].min() - margin), max(y1, centres[:, 1].max() + margin)
    return (x0, x1), (y0, y1)


def _draw_points(ax: Any, scene: Scene, max_points: int, seed: int, limits: Limits) -> None:
    (x0, x1), (y0, y1) = limits
    xyz = np.asarray(scene.points.xyz, dtype=np.float64)
    inside = (xyz[:, 0] >= x0) & (xyz[:, 0] <= x1) & (xyz[:, 1] >= y0) & (xyz[:, 1] <= y1)
    xyz = xyz[inside]
    if len(xyz) > max_points:
        # a fixed generator: the same finding always gives the same picture
        xyz = xyz[np.random.default_rng(seed).choice(len(xyz), max_points, replace=False)]
    if len(xyz):
        # darker with height, so objects stand out from the road
        z = np.clip(xyz[:, 2], -2.5, 1.5)
        ax.scatter(-xyz[:, 1], xyz[:, 0], c=z, s=0.8, cmap="Greys", vmin=-3.0, vmax=1.5, linewidths=0,
                   rasterized=True)


def _frame_axes(ax: Any, title: str, limits: Limits) -> None:
    from matplotlib.ticker import FuncFormatter

    (x0, x1), (y0, y1) = limits
    ax.set_xlim(-y1, -y0)
    ax.set_ylim(x0, x1)
    ax.set_aspect("equal")
    ax.xaxis.set_major_formatter(FuncFormatter(lambda value, _: f"{0.0 - value:g}"))  # y grows to the left
    ax.set_title(title, fontsize=10)
    ax.set_xlabel("y (m, left ←)", fontsize=8)
    ax.set_ylabel("x (m, forward)", fontsize=8)
    ax.tick_params(labelsize=8)
    ax.plot([0], [0], marker="^", color="black", markersize=5)


def _note(ax: Any, text: str) -> None:
    ax.text(0.5, 0.97, text, transform=ax.transAxes, ha="center", va="top", fontsize=8, color=HIGHLIGHT_COLOUR,
            bbox={"facecolor": "white", "edgecolor": HIGHLIGHT_COLOUR, "boxstyle": "round,pad=0.3"})


def _highlights(pair: FindingPair) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64],
                                            list[NDArray[np.float64]]]:
    """The boxes a finding is about: the source detections and ground truth the follow-up lost
    (original frame), the follow-up's unexplained detections, and where the lost objects were
    expected in the mutant."""
    source, shown, follow = pair.source, pair.mutant if pair.mutant is not None else pair.source, pair.follow_detections
    lost_source = pair.source_detections.select(_ids(pair.lost_source)).as_array()
    lost_gt = source.boxes.select(_ids(pair.lost_gt)).as_array()
    spurious = follow.select(_ids(pair.spurious)).as_array() if follow is not None else np.zeros((0, 7))
    expected = []  # where the lost objects should be in the mutant
    if len(lost_source):
        expected.append(lost_source if pair.transform is None else transform_boxes(lost_source, pair.transform))
    if pair.lost_gt:
        gone = [g for g, f in zip(pair.lost_gt, pair.lost_gt_follow, strict=True) if f < 0]
        kept = [f for f in pair.lost_gt_follow if f >= 0]
        if kept:
            expected.append(shown.boxes.select(_ids(kept)).as_array())
        if gone:
            boxes = source.boxes.select(_ids(gone)).as_array()
            expected.append(boxes if pair.transform is None else transform_boxes(boxes, pair.transform))
    return lost_source, lost_gt, spurious, expected


def _thumbnail_limits(boxes: Sequence[NDArray[np.float64]], aspect: float, margin: float = 10.0) -> Limits:
    """A crop around the boxes a finding is about (``aspect``: width over height of the picture), or
    the default view's near half when there is none (a failure)."""
    centres = np.concatenate([b[np.all(np.isfinite(b), axis=1), :2] for b in boxes] or [np.zeros((0, 2))])
    if len(centres) == 0:
        (x0, _), (y0, y1) = X_RANGE, Y_RANGE
        height = (y1 - y0) / 2 / aspect
        return (x0, x0 + height), (y0 / 2, y1 / 2)
    (x0, y0), (x1, y1) = centres.min(axis=0) - margin, centres.max(axis=0) + margin
    width, height = max(y1 - y0, (x1 - x0) * aspect), max(x1 - x0, (y1 - y0) / aspect)
    cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
    return (cx - height / 2, cx + height / 2), (cy - width / 2, cy + width / 2)


def draw_thumbnail(pair: FindingPair, *, width: int = 160, height: int = 120, max_points: int = 8_000) -> Figure:
    """A small picture of ``pair``'s mutant (``width`` × ``height`` pixels), cropped to the boxes the
    finding is about, drawn as :func:`draw_pair`'s right panel without axes or text: a finding
    list's thumbnail. A failure (no output) is framed in red."""
    from matplotlib.figure import Figure

    dpi = 80
    fig = Figure(figsize=(width / dpi, height / dpi), dpi=dpi)
    ax = fig.add_axes((0.0, 0.0, 1.0, 1.0))
    shown = pair.mutant if pair.mutant is not None else pair.source
    follow = pair.follow_detections
    lost_source, lost_gt, spurious, expected = _highlights(pair)
    limits = _thumbnail_limits([spurious, *expected] if spurious.size or expected else [lost_source, lost_gt],
                               width / height)
    _draw_points(ax, shown, max_points, int(pair.finding.get("id", 0)), limits)
    _draw_boxes(ax, shown.boxes, GT_COLOUR, 0.8)
    if follow is not None:
        _draw_boxes(ax, follow, DETECTION_COLOUR, 0.8)
        _draw_boxes(ax, spurious, HIGHLIGHT_COLOUR, 1.6)
    for boxes in expected:
        _draw_boxes(ax, boxes, HIGHLIGHT_COLOUR, 1.2, style="dashed")
    (x0, x1), (y0, y1) = limits
    ax.set_xlim(-y1, -y0)
    ax.set_ylim(x0, x1)
    ax.set_axis_off()
    if follow is None:  # the system failed here: nothing to draw of its own
        for side in ax.spines.values():
            side.set_visible(True)
            side.set_edgecolor(HIGHLIGHT_COLOUR)
            side.set_linewidth(3)
        ax.set_axis_on()
        ax.set_xticks([])
        ax.set_yticks([])
    return fig


def draw_pair(pair: FindingPair, *, max_points: int = MAX_POINTS) -> Figure:
    """The before/after figure of ``pair`` (a matplotlib figure, no pyplot state)."""
    from matplotlib.figure import Figure
    from matplotlib.lines import Line2D

    fig = Figure(figsize=(12.0, 6.4), dpi=90, layout="constrained")
    left, right = fig.subplots(1, 2)
    seed = int(pair.finding.get("id", 0))
    source, mutant = pair.source, pair.mutant

    shown = mutant if mutant is not None else source
    follow = pair.follow_detections
    lost_source, lost_gt, spurious, expected = _highlights(pair)
    limits = _limits([lost_source, lost_gt, spurious, *expected])

    _draw_points(left, source, max_points, seed, limits)
    _draw_boxes(left, source.boxes, GT_COLOUR, 0.8)
    _draw_boxes(left, pair.source_detections, DETECTION_COLOUR, 1.0)
    _draw_boxes(left, lost_gt, HIGHLIGHT_COLOUR, 2.4)
    _draw_boxes(left, lost_source, HIGHLIGHT_COLOUR, 2.4)
    found = "no output" if pair.source_failed else f"{len(pair.source_detections)} detections"
    _frame_axes(left, f"original {pair.finding.get('frame_id', '')}: {len(source.boxes)} objects, {found}", limits)
    if pair.source_failed and mutant is not None:
        _note(left, "the system failed on the original too: no detections")

    _draw_points(right, shown, max_points, seed + 1, limits)
    _draw_boxes(right, shown.boxes, GT_COLOUR, 0.8)
    if follow is not None:
        _draw_boxes(right, follow, DETECTION_COLOUR, 1.0)
        _draw_boxes(right, spurious, HIGHLIGHT_COLOUR, 2.4)
    for boxes in expected:
        _draw_boxes(right, boxes, HIGHLIGHT_COLOUR, 1.8, style="dashed")
    count = "no output" if follow is None else f"{len(follow)} detections"
    _frame_axes(right, f"{pair.finding.get('label', 'mutant')}: {len(shown.boxes)} objects, {count}", limits)
    if follow is None:
        _note(right, f"the system failed here ({pair.finding.get('kind')}): no detections")
    elif pair.tool_error:
        _note(right, f"lidarfuzz's own error here, not the system's: {pair.tool_error}")

    handles = [Line2D([], [], color=GT_COLOUR, lw=1.2, label="ground truth"),
               Line2D([], [], color=DETECTION_COLOUR, lw=1.2, label="detection"),
               Line2D([], [], color=HIGHLIGHT_COLOUR, lw=2.4, label="lost / unexplained"),
               Line2D([], [], color=HIGHLIGHT_COLOUR, lw=1.8, ls="dashed", label="where it was expected")]
    fig.legend(handles=handles, loc="outside lower center", ncol=4, fontsize=9, frameon=False)
    return fig


def finding_png(store: Store, finding_id: int, *, max_points: int = MAX_POINTS,
                datasets: dict[str, Any] | None = None) -> bytes:
    """The before/after picture of finding ``finding_id`` as PNG bytes.

    Raises:
        LidarfuzzError: When the frame cannot be rebuilt (see :func:`load_pair`).
    """
    return figure_png(draw_pair(load_pair(store, finding_id, datasets=datasets), max_points=max_points))


def finding_images(store: Store, finding_ids: Sequence[int], *, limit: int = 12,
                   max_points: int = MAX_POINTS) -> dict[int, bytes | str]:
    """Pictures of the first ``limit`` findings: PNG bytes, or a note saying why there is none."""
    datasets: dict[str, Any] = {}
    images: dict[int, bytes | str] = {}
    for finding_id in list(finding_ids)[: max(0, limit)]:
        try:
            images[finding_id] = finding_png(store, finding_id, max_points=max_points, datasets=datasets)
        except LidarfuzzError as exc:
            images[finding_id] = f"No picture: {exc}"
    return images


__all__ = ["FindingPair", "draw_pair", "draw_thumbnail", "finding_images", "finding_png", "load_pair"]
