"""The tables ``lidarfuzz run --kind structural`` prints when its task ends (the report has them all)."""

from __future__ import annotations

from typing import Any

from lidarfuzz.cli.common import console


def _pct(value: float | None) -> str:
    return "–" if value is None else f"{100 * value:.1f}"


def print_structural(store: Any, task_id: int) -> None:
    """Per chosen function and criterion, the paper's table (rows: field-test logs; FT log, each
    heuristic's base and its aggregated logs), then the reductions and the relation counts."""
    from rich.table import Table

    from lidarfuzz.campaign.structural import summary_of
    from lidarfuzz.campaign.tasks import get_task

    summary = summary_of(store, get_task(store, task_id))
    for entry in summary.tables:
        if not entry.function and len(summary.functions) == 1:
            continue  # the one function's table says it already
        what = entry.function or "every target"
        name = "all-nodes" if entry.criterion == "node" else "all-edges"
        table = Table(title=f"{name} of {what} ({entry.total} requirements), % covered, task {task_id}")
        table.add_column("log", no_wrap=True)
        for column in entry.columns:
            table.add_column(column, justify="right")
        for row in entry.rows:
            table.add_row(row.log, *[_pct(v) for v in row.values])
        table.add_row("average", *[_pct(v) for v in entry.average], end_section=False)
        console.print(table)
    if summary.reduction:
        table = Table(title="base logs: size and coverage (%) against the field-test log")
        for column in ("log", "heuristic", "segments", "frames", "nodes", "edges"):
            table.add_column(column, justify="left" if column in ("log", "heuristic") else "right")
        for r in summary.reduction:
            table.add_row(r.log, r.heuristic, f"{r.segments}/{r.log_segments}", f"{r.frames}/{r.log_frames}",
                          f"{_pct(r.nodes)} of {_pct(r.log_nodes)}", f"{_pct(r.edges)} of {_pct(r.log_edges)}")
        console.print(table)
    checks = ", ".join(f"{name} {c['violated']}/{c['checked']} violated" for name, c in summary.relations.items())
    console.print(f"relations: {checks or 'none checked'}; findings: "
                  + (", ".join(f"{k} {v}" for k, v in summary.findings.items()) or "none"))


__all__ = ["print_structural"]
