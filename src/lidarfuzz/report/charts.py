"""The report's charts, drawn with matplotlib's Agg backend into PNG bytes.

Each function reads the task summary (:func:`lidarfuzz.campaign.results.summarise`) and
returns a PNG, or None when the summary has nothing to draw (no labels, nothing finished).
Figures are built with :class:`matplotlib.figure.Figure` directly, so nothing touches
pyplot's global state, and saved as palette PNGs, which keeps each under about 100 kB.
"""

from __future__ import annotations

import io
import math
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from lidarfuzz.store.contracts import APRecord, TaskSummary

METRIC_NAMES: dict[str, str] = {"bbox": "bbox (2D)", "bev": "BEV", "3d": "3D"}
METRIC_COLOURS: dict[str, str] = {"bbox": "#9ecae1", "bev": "#4292c6", "3d": "#08306b"}
PALETTE = ("#4c72b0", "#dd8452", "#55a868", "#c44e52", "#8172b3", "#937860", "#da8bc3", "#8c8c8c", "#ccb974",
           "#64b5cd")


def figure_png(fig: Figure, colours: int = 128) -> bytes:
    """``fig`` as PNG bytes, quantised to a palette (a scatter plot's PNG shrinks several times)."""
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", facecolor="white")
    try:
        from PIL import Image
    except ImportError:  # matplotlib brings Pillow; without it the PNG is only bigger
        return buffer.getvalue()
    buffer.seek(0)
    # octree keeps rare colours (thin coloured lines) that median cut merges into their neighbours
    image = Image.open(buffer).convert("RGB").quantize(colors=colours, method=Image.Quantize.FASTOCTREE)
    out = io.BytesIO()
    image.save(out, format="PNG", optimize=True)
    return out.getvalue()


def _figure(width: float, height: float) -> Figure:
    from matplotlib.figure import Figure

    return Figure(figsize=(width, height), dpi=80, layout="constrained")


def ap_value(ap: APRecord | None, metric: str, cls: str, difficulty: str, points: str) -> float | None:
    """One AP figure of a subtask's ``ap`` entry (``cls`` may be ``mAP``); None when absent or undefined."""
    if ap is None:
        return None
    try:
        table = ap.map[metric] if cls == "mAP" else ap.ap[metric][cls]
        value = table[difficulty][points]
    except KeyError:
        return None
    return float(value) if math.isfinite(value) else None


def ap_chart(summary: TaskSummary, difficulty: str = "moderate", points: str = "R40") -> bytes | None:
    """AP per subtask for bbox, BEV and 3D: one panel per class and one for mAP (grouped bars)."""
    subtasks = [s for s in summary.subtasks if s.ap is not None]
    if not subtasks:
        return None
    classes = [*summary.classes, "mAP"]
    labels = [s.label for s in subtasks]
    fig = _figure(max(8.0, 2.0 + 0.55 * len(labels) * 2), 6.4)
    axes = fig.subplots(2, 2, sharex=True).ravel()
    width = 0.27
    for ax, cls in zip(axes, classes, strict=False):
        top = 0.0
        for k, metric in enumerate(METRIC_NAMES):
            values = [ap_value(s.ap, metric, cls, difficulty, points) for s in subtasks]
            xs = [i + (k - 1) * width for i in range(len(labels))]
            ax.bar(xs, [v if v is not None else 0.0 for v in values], width, color=METRIC_COLOURS[metric],
                   label=METRIC_NAMES[metric])
            top = max([top, *(v for v in values if v is not None)])
            if values[0] is not None and subtasks[0].label == "original":
                ax.axhline(values[0], color=METRIC_COLOURS[metric], lw=0.8, ls="--")
        ax.set_title(cls if cls != "mAP" else "mean over classes (mAP)", fontsize=10)
        ax.set_xticks(range(len(labels)), labels, rotation=40, ha="right", fontsize=8)
        ax.set_xlim(-0.6, max(len(labels), 4) - 0.4)  # a few subtasks: bars of the usual width, not stretched
        ax.tick_params(axis="y", labelsize=8)
        ax.set_ylim(0, min(100.0, max(10.0, 10.0 * math.ceil(top * 1.15 / 10.0))))
        ax.grid(axis="y", lw=0.4, alpha=0.5)
        ax.set_axisbelow(True)
    for ax in axes[::2]:
        ax.set_ylabel(f"AP|{points} ({difficulty}) %", fontsize=8)
    axes[0].legend(fontsize=8, ncols=3, loc="upper right", frameon=False)
    return figure_png(fig)


def severity_name(severity: int) -> str:
    return str(severity) if severity else "config"


def delta_heatmap(summary: TaskSummary, metric: str = "3d", cls: str = "mAP", difficulty: str = "moderate",
                  ) -> bytes | None:
    """ΔAP (mutant − original, R40) per operator × severity, diverging colours centred at 0."""
    rows = [r for r in summary.delta_ap if r.metric == metric and r.cls == cls and r.difficulty == difficulty]
    if not rows:
        return None
    operators = list(dict.fromkeys(r.operator for r in rows))
    severities = sorted({r.severity for r in rows}, key=lambda s: (s == 0, s))
    import numpy as np

    grid = np.full((len(operators), len(severities)), np.nan)
    for r in rows:
        if math.isfinite(r.delta):
            grid[operators.index(r.operator), severities.index(r.severity)] = r.delta
    finite = grid[np.isfinite(grid)]
    limit = max(1.0, float(np.abs(finite).max())) if finite.size else 1.0
    fig = _figure(max(4.5, 1.6 + 0.9 * len(severities)), max(2.2, 0.9 + 0.42 * len(operators)))
    ax = fig.subplots()
    image = ax.imshow(np.ma.masked_invalid(grid), cmap="RdBu", vmin=-limit, vmax=limit, aspect="auto")
    ax.set_xticks(range(len(severities)), [severity_name(s) for s in severities], fontsize=9)
    ax.set_yticks(range(len(operators)), operators, fontsize=9)
    ax.set_xlabel("severity", fontsize=9)
    ax.set_facecolor("#eeeeee")
    for (i, j), value in np.ndenumerate(grid):
        if math.isfinite(value):
            colour = "white" if abs(value) > 0.6 * limit else "black"
            ax.text(j, i, f"{value:+.1f}", ha="center", va="center", fontsize=9, color=colour)
    bar = fig.colorbar(image, ax=ax, shrink=0.9)
    bar.set_label(f"Δ {METRIC_NAMES.get(metric, metric)} {cls} ({difficulty}, R40)", fontsize=8)
    bar.ax.tick_params(labelsize=8)
    return figure_png(fig)


def violation_chart(summary: TaskSummary) -> bytes | None:
    """Violation rate per operator (groups) and relation (bars), as Zhou & Sun's Figure 3."""
    rate = {(r.operator or "", r.relation or ""): r.rate for r in summary.violations.relation_operator
            if r.rate is not None}
    if not rate:
        return None
    order = [s.operator for s in summary.subtasks]
    operators = sorted(dict.fromkeys(o for o, _ in rate), key=lambda o: order.index(o) if o in order else len(order))
    relations = sorted({r for _, r in rate})
    widest = max(sum((o, r) in rate for r in relations) for o in operators)
    width = 0.8 / widest
    fig = _figure(max(6.0, 1.5 + 0.3 * len(operators) * widest + 0.3 * len(operators)), 3.6)
    ax = fig.subplots()
    placed: dict[str, tuple[list[float], list[float]]] = {r: ([], []) for r in relations}
    for i, operator in enumerate(operators):
        # only the relations checked under this operator, centred on its tick
        present = [r for r in relations if (operator, r) in rate]
        for k, relation in enumerate(present):
            placed[relation][0].append(i + (k - (len(present) - 1) / 2) * width)
            placed[relation][1].append(100.0 * rate[(operator, relation)])
    for k, relation in enumerate(relations):
        ax.bar(*placed[relation], width * 0.95, label=relation, color=PALETTE[k % len(PALETTE)])
    ax.set_xticks(range(len(operators)), operators, rotation=20 if len(operators) > 4 else 0, ha="right"
                  if len(operators) > 4 else "center", fontsize=9)
    ax.set_ylabel("violated frames %", fontsize=9)
    ax.set_ylim(0, 100)
    ax.tick_params(axis="y", labelsize=8)
    ax.grid(axis="y", lw=0.4, alpha=0.5)
    ax.set_axisbelow(True)
    ax.legend(fontsize=8, ncols=min(len(relations), 5), loc="upper left", frameon=False)
    return figure_png(fig)


def charts(summary: TaskSummary) -> dict[str, bytes]:
    """Every chart the summary can fill, by name (``ap``, ``delta``, ``violations``)."""
    drawn = {"ap": ap_chart(summary), "delta": delta_heatmap(summary), "violations": violation_chart(summary)}
    return {name: png for name, png in drawn.items() if png is not None}


__all__ = ["ap_chart", "ap_value", "charts", "delta_heatmap", "figure_png", "violation_chart"]
