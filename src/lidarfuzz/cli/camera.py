"""What ``lidarfuzz run`` prints for a camera task: DeepTest's figures on a steering system."""

from __future__ import annotations

import math
from typing import Any

from rich.markup import escape
from rich.table import Table

from lidarfuzz.cli.common import console, print_table

#: The ε columns printed (the paper's Table 7); the report has the whole grid.
EPSILONS = (0.01, 0.02, 0.03, 0.04, 0.05)


def _number(value: Any, digits: int = 4) -> str:
    return "–" if value is None or (isinstance(value, float) and math.isnan(value)) else f"{value:.{digits}g}"


def print_camera(store: Any, task_id: int) -> None:
    """MSE_orig, each transformation's MSE and Eq. 2/3 counts, Table 7 and the guided search."""
    from lidarfuzz.campaign.results import summarise

    data = summarise(store, task_id)
    info = data.kind_summary
    mse = info.get("mse_orig")
    console.print(f"MSE_orig = {_number(mse)} over {info.get('labelled', 0)} labelled of {info.get('images', 0)} "
                  "original images" + ("" if mse is not None else ": no label, so Eq. 2 judged nothing"))
    table = Table(title=f"transformations (task {task_id}): Eq. 2 against λ·MSE_orig, Eq. 3's filter")
    for name, justify in (("setting", "left"), ("images", "right"), ("MSE_t", "right"), ("MSE_t − MSE_orig", "right"),
                          ("violate Eq. 2", "right"), ("Eq. 3", "left")):
        table.add_column(name, justify=justify)  # type: ignore[arg-type]
    for entry in data.subtasks[1:]:
        d = entry.deeptest
        if d is None:
            table.add_row(escape(entry.label), str(entry.frames), "–", "–", "–", "no labelled image judged")
            continue
        eps = f"ε = {d.configured_epsilon:g}"
        verdict = f"kept at {eps}" if d.kept else f"filtered out at {eps}"
        verdict = verdict if d.filtered else "not filtered (composite)"
        table.add_row(escape(entry.label), str(d.mutants), _number(d.mse), _number(d.mse - d.mse_orig, 3),
                      f"{d.violated}/{d.mutants}", verdict)
    print_table(table)
    t7 = data.deeptest
    if t7 is not None and t7.counts:
        grid = Table(title=f"erroneous behaviours, Table 7's form (λ = {t7.configured_lambda:g}, "
                           f"ε = {t7.configured_epsilon:g} configured)")
        grid.add_column("λ", justify="right")
        columns = [t7.epsilons.index(e) for e in EPSILONS if e in t7.epsilons]
        for j in columns:
            grid.add_column(f"ε {t7.epsilons[j]:g}", justify="right")
        grid.add_column("no filter", justify="right")
        for i, lam in enumerate(t7.lambdas):
            grid.add_row(f"{lam:g}", *[str(t7.counts[i][j]) for j in columns], str(t7.unfiltered[i]))
        print_table(grid)
    guided = next((s for s in data.subtasks if s.operator == "guided"), None)
    if guided is not None and guided.search is not None:
        seeds = info.get("seed_coverage", {})
        cov = Table(title="guided search (Algorithm 1): neuron coverage")
        cov.add_column("criterion")
        cov.add_column("seed images", justify="right")
        cov.add_column("after the search", justify="right")
        for name, value in guided.search.coverage.items():
            before = seeds.get(name)
            cov.add_row(name.upper(), "–" if before is None else f"{100 * before:.1f}%", f"{100 * value:.1f}%")
        print_table(cov)
        st = guided.search.stats
        console.print(f"tests {st.get('tests', 0)}: kept (new coverage) {st.get('accepted', 0)}, violating Eq. 2 "
                      f"{st.get('violating', 0)}; unique findings {st.get('findings', 0)}")
    kinds = data.findings.by_kind
    console.print(f"findings: {data.findings.total} "
                  f"({', '.join(f'{k} {v}' for k, v in sorted(kinds.items())) or 'none'})")
