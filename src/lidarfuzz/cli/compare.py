"""``lidarfuzz compare A B``: two finished tasks on the same frames and mutants, side by side
(:mod:`lidarfuzz.campaign.compare`): violation rates with a significance test, the units where
they disagree, and recall and AP by range band, class, size and occlusion."""

from typing import TYPE_CHECKING, Annotated, Any

import typer
from rich.markup import escape

from lidarfuzz.cli.common import WORKSPACE, JsonOption, WorkspaceOption, console, open_store, print_table

if TYPE_CHECKING:
    from lidarfuzz.campaign.compare import TaskComparison

#: Disagreeing units the text output lists (``--json`` has every one the comparison keeps).
SHOWN_DISAGREEMENTS = 20


def _pct(value: float) -> str:
    return "–" if value != value else f"{100 * value:.0f}%"


def _ap(value: float) -> str:
    return "–" if value != value else f"{value:.1f}"


def _p(value: float) -> str:
    if value != value:
        return "–"
    return f"{value:.2g}" if value < 0.01 else f"{value:.3f}"


def print_comparison(result: "TaskComparison", *, show_all: bool = False) -> None:
    """The comparison's tables: rates and tests, disagreements, breakdowns."""
    from rich.table import Table

    a, b = result.a, result.b
    console.print(f"A = task {a.task} ({escape(a.model)}), B = task {b.task} ({escape(b.model)}): "
                  f"{escape(result.dataset)}, {result.frames} frame(s), {result.trials} trial(s), seed {result.seed}")
    rows = result.rows if show_all else [r for r in result.rows if r.violated_a or r.violated_b]
    table = Table(title=f"violating / checked frames (objects_lost: objects lost / found on the original); "
                        f"{result.test}, {result.correction}, α = {result.alpha:g}")
    for header in ("subtask", "relation", "class"):
        table.add_column(header, no_wrap=True)
    for header in ("A", "B", "A − B", "p", "p (corr.)", "A > B"):
        table.add_column(header, justify="right")
    for r in rows:
        diff = "–" if r.difference != r.difference else f"{100 * r.difference:+.0f} pt"
        table.add_row(r.label, r.relation, r.cls or "any", f"{r.violated_a}/{r.checked_a} ({_pct(r.rate_a)})",
                      f"{r.violated_b}/{r.checked_b} ({_pct(r.rate_b)})", diff, _p(r.p_value), _p(r.p_adjusted),
                      "[bold red]yes[/]" if r.significant else "no")
    print_table(table)
    hidden = len(result.rows) - len(rows)
    if hidden:
        console.print(f"({hidden} row(s) with no violation on either side not shown; --all shows them)")
    significant = result.significant
    console.print(f"significantly above B: {len(significant)} row(s)"
                  + (": " + ", ".join(f"{r.label} {r.relation}{' ' + r.cls if r.cls else ''}" for r in significant)
                     if significant else ""))
    by_side = result.disagreements_by_side
    console.print(f"disagreements (one violates, the other not): {result.disagreements_total} "
                  f"(A only {by_side.get('A', 0)}, B only {by_side.get('B', 0)})")
    if result.disagreements:
        listing = Table()
        for header in ("subtask", "relation", "frame", "trial", "violated by", "classes", "replay"):
            listing.add_column(header, no_wrap=header != "classes")
        for d in result.disagreements[:SHOWN_DISAGREEMENTS]:
            listing.add_row(d.label, d.relation, d.frame_id, str(d.trial), d.violated_by, ", ".join(d.classes),
                            d.replay)
        print_table(listing)
        if result.disagreements_total > SHOWN_DISAGREEMENTS:
            console.print(f"(the first {SHOWN_DISAGREEMENTS}; --json lists up to {len(result.disagreements)})")
    if result.breakdown:
        breakdown = Table(title=f"recall and AP ({result.breakdown_ap}) by group, A beside B")
        for header in ("scope", "by", "group"):
            breakdown.add_column(header, no_wrap=True)
        for header in ("objects", "recall A", "recall B", "BEV AP A", "BEV AP B", "3D AP A", "3D AP B"):
            breakdown.add_column(header, justify="right")
        for g in result.breakdown:
            worse = g.recall_a < g.recall_b  # False when either is NaN
            breakdown.add_row(g.scope, g.dimension, g.group, str(g.objects),
                              f"[red]{_pct(g.recall_a)}[/]" if worse else _pct(g.recall_a), _pct(g.recall_b),
                              _ap(g.ap_bev_a), _ap(g.ap_bev_b), _ap(g.ap_3d_a), _ap(g.ap_3d_b))
        print_table(breakdown)
        console.print(f"groups: {escape(result.breakdown_rule)}", soft_wrap=True, highlight=False)


def print_comparisons(store: Any, task_id: int, baseline: int | None = None) -> None:
    """What ``run`` and ``report`` print of a task's comparisons (with ``baseline``, or the reference
    tasks its campaign created): the rates and tests and the disagreements; the breakdowns by
    group are in the report (and ``lidarfuzz compare``)."""
    from lidarfuzz.campaign.compare import compare_tasks, references_of
    from lidarfuzz.store.errors import StoreError

    for other in [baseline] if baseline is not None else references_of(store, task_id):
        try:
            result = compare_tasks(store, task_id, other, breakdown=False)
        except StoreError as exc:
            console.print(f"[yellow]no comparison with task {other}: {escape(str(exc))}[/]")
            continue
        print_comparison(result)
        console.print(f"(recall and AP by range, class, size and occlusion: in the report, or lidarfuzz compare "
                      f"{task_id} {other})")


def compare(
    task_a: Annotated[int, typer.Argument(help="The system under test's task (A).")],
    task_b: Annotated[int, typer.Argument(help="The reference or baseline task (B) on the same frames and "
                                               "operators.")],
    show_all: Annotated[bool, typer.Option("--all", help="Also list rows with no violation on either side.")] = False,
    no_breakdown: Annotated[bool, typer.Option("--no-breakdown", help="Skip recall and AP by range, class, size "
                                                                     "and occlusion (the slow part).")] = False,
    as_json: JsonOption = False,
    workspace: WorkspaceOption = WORKSPACE,
) -> None:
    """Compare two finished tasks: violation rates with a significance test (A above B?), the
    mutants where they disagree, and recall/AP by range band, class, size and occlusion."""
    from lidarfuzz.campaign.compare import compare_tasks

    result = compare_tasks(open_store(workspace), task_a, task_b, breakdown=not no_breakdown)
    if as_json:
        typer.echo(result.model_dump_json(by_alias=True, indent=2))
        return
    print_comparison(result, show_all=show_all)
