"""A structural task in the report and the web app: the tables of Neves et al.'s form, and the
views of :mod:`lidarfuzz.structural.views` (coverage per module/class/function, annotated source,
control-flow graphs, two logs side by side) as HTML fragments.

Everything is computed from the task summary's ``kind_summary``
(:class:`~lidarfuzz.campaign.structural_summary.StructuralSummary`): its numbers are the ones
``report.json`` carries. The source and the graphs are drawn from the code as it is now; when a
function's requirements no longer match those the task measured, the view says so.
"""

from __future__ import annotations

from typing import Any

from lidarfuzz.campaign.structural_summary import StructuralSummary
from lidarfuzz.store.contracts import TaskSummary

DASH = "–"


def _pct(value: float | None) -> str:
    return DASH if value is None else f"{100 * value:.1f} %"


def structural_summary(summary: TaskSummary) -> StructuralSummary | None:
    """The structural figures of a task summary (None: not a structural task)."""
    data = summary.kind_summary
    if not data or "tables" not in data:
        return None
    return StructuralSummary.model_validate(data)


def fragments(data: StructuralSummary) -> dict[str, Any]:
    """The views as HTML: ``coverage`` (field-test logs, and every log of the task), per function
    ``source`` and ``cfg`` (SVG) over every log, ``comparisons`` (each base log beside each log
    generated from it) and ``style`` (their CSS)."""
    from lidarfuzz.structural import views
    from lidarfuzz.structural.python_coverage import CodeModel
    from lidarfuzz.structural.requirements import union
    from lidarfuzz.structural.stored import from_labels

    total = from_labels(data.total)
    covered = {(e.ft, e.heuristic, e.strategy): from_labels(e.covered) for e in data.logs}
    field = union(*(c for (_, h, _), c in covered.items() if not h))
    every = union(*covered.values())
    out: dict[str, Any] = {
        "style": views.STYLE,
        "coverage_ft": views.table_html(views.coverage_table(total, field)),
        "coverage_all": views.table_html(views.coverage_table(total, every)),
        "functions": [], "comparisons": [], "note": "",
    }
    try:
        model: CodeModel | None = CodeModel.of(data.targets)
    except Exception as exc:  # the code is gone or moved: the numbers stand, the views cannot be drawn
        model, out["note"] = None, f"the targets cannot be read now ({exc}); only the numbers are shown"
    for function in data.functions:
        entry: dict[str, Any] = {"name": function, "source": "", "cfg": "", "note": ""}
        if model is not None:
            try:
                graph = model.graph(function)
            except Exception as exc:
                entry["note"] = str(exc)
            else:
                if graph.requirements() != frozenset(r for r in total if r.function == function):
                    entry["note"] = "the source changed since the task ran: the marks may be off"
                entry["source"] = views.source_html(graph, every)
                try:
                    entry["cfg"] = views.cfg_svg(graph, every)
                except Exception as exc:  # Graphviz's dot missing: the rest of the report still renders
                    entry["note"] = (entry["note"] + "; " if entry["note"] else "") + f"no graph: {exc}"
        out["functions"].append(entry)
    labels = {e.ft: e.name for e in data.logs if e.role == "field_test"}
    for (ft, heuristic, strategy), generated in sorted(covered.items()):
        base = covered.get((ft, heuristic, ""))
        if not strategy or base is None:
            continue
        names = (f"{heuristic} base", f"{heuristic}+{strategy}")
        out["comparisons"].append({"log": labels.get(ft, str(ft)), "names": names,
                                   "html": views.comparison_html(views.compare(total, base, generated), names)})
    return out


def headline(summary: TaskSummary) -> str | None:
    """The report's one paragraph for a structural task (None for another kind)."""
    data = structural_summary(summary)
    if data is None:
        return None
    ft = [e for e in data.logs if e.role == "field_test"]
    every = next((t for t in data.tables if not t.function and t.criterion == "edge"), None)
    reach = "" if every is None else (
        f" The field-test logs cover {_pct(every.average[0])} of the edges on average; the best aggregated column "
        f"{_pct(max((v for v in every.average if v is not None), default=None))}.")
    failed = sum(e.failures for e in data.logs)
    violated = sum(c["violated"] for c in data.relations.values())
    return (f"lidarfuzz replayed {len(data.logs)} log(s) through {summary.task.model.name} under code coverage: "
            f"{len(ft)} field-test log(s), a base log per heuristic ({', '.join(data.heuristics)}) and a log per "
            f"strategy ({', '.join(data.strategies)}) from each.{reach} {failed} step(s) failed; decision relations "
            f"were violated {violated} time(s).")


def structural_view(summary: TaskSummary, *, with_fragments: bool = True) -> dict[str, Any] | None:
    """What the report's structural section shows (None for another kind of task)."""
    data = structural_summary(summary)
    if data is None:
        return None
    tables = [{"title": f"{'all-nodes' if t.criterion == 'node' else 'all-edges'} of "
                        f"{t.function or 'every target'} ({t.total} requirements)",
               "columns": t.columns, "rows": [(r.log, [_pct(v) for v in r.values]) for r in t.rows],
               "average": [_pct(v) for v in t.average]}
              for t in data.tables if t.function or len(data.functions) > 1]
    aggregated = [{"log": r.log, "heuristic": r.heuristic, "strategy": r.strategy,
                   "criterion": "all-nodes" if r.criterion == "node" else "all-edges", "base": _pct(r.base),
                   "generated": _pct(r.generated), "together": _pct(r.together), "aggregated": _pct(r.aggregated),
                   "new": r.new} for r in data.aggregated]
    reduction = [{"log": r.log, "heuristic": r.heuristic, "segments": f"{r.segments}/{r.log_segments}",
                  "frames": f"{r.frames}/{r.log_frames}", "nodes": f"{_pct(r.nodes)} of {_pct(r.log_nodes)}",
                  "edges": f"{_pct(r.edges)} of {_pct(r.log_edges)}"} for r in data.reduction]
    relations = [{"name": name, "checked": c["checked"], "violated": c["violated"]}
                 for name, c in sorted(data.relations.items())]
    return {"targets": data.targets, "segment_size": data.segment_size, "heuristics": data.heuristics,
            "strategies": data.strategies, "tables": tables, "aggregated": aggregated, "reduction": reduction,
            "relations": relations, "logs": len(data.logs),
            "views": fragments(data) if with_fragments else None}


#: The standalone page's own look (the report's section is styled by the report).
PAGE_STYLE = """
body { font: 14px/1.5 system-ui, sans-serif; color: #1f2328; margin: 12px 16px; }
table { border-collapse: collapse; margin: 6px 0 14px; }
th, td { border-bottom: 1px solid #d8dee4; padding: 3px 8px; text-align: right; }
th.left, td.left { text-align: left; }
h2 { font-size: 18px; } h3 { font-size: 15px; margin: 18px 0 4px; }
.note, .muted { color: #59636e; font-size: 13px; }
.wide { overflow-x: auto; }
table.lf-structural-table td { white-space: nowrap; }
"""


def section_html(summary: TaskSummary) -> str | None:
    """The report's structural section as a page of its own (what the web app's task page embeds);
    None for another kind of task."""
    from jinja2 import Environment, PackageLoader, StrictUndefined, select_autoescape

    view = structural_view(summary)
    if view is None:
        return None
    env = Environment(loader=PackageLoader("lidarfuzz.report", "templates"), autoescape=select_autoescape(
        ["html", "j2"], default=True), undefined=StrictUndefined, trim_blocks=True, lstrip_blocks=True)
    section = env.get_template("structural.html.j2").render(structural=view)
    title = f"task {summary.task.id}: structural coverage"
    return (f'<!DOCTYPE html><html lang="en"><head><meta charset="utf-8"><title>{title}</title>'
            f"<style>{PAGE_STYLE}</style></head><body>{section}</body></html>")


__all__ = ["PAGE_STYLE", "fragments", "headline", "section_html", "structural_summary", "structural_view"]
