"""Reports of a campaign task: a self-contained HTML page, JSON, CSV tables and JUnit XML.

:func:`write_report` writes them all for one task of the store::

    report.html       the report (offline: inline CSS, charts and pictures as data URIs)
    report.json       the task summary's JSON form (TaskSummary.dump() of lidarfuzz.campaign.results.summarise)
    ap.csv, delta_ap.csv, violations.csv, findings.csv
    junit.xml         gates as test cases, for CI (grammar: lidarfuzz.report.gates)
    comparison-B.json the comparison with task B (a baseline, or a reference task of the campaign;
                      lidarfuzz.campaign.compare.TaskComparison), one per compared task

Example:
    >>> from lidarfuzz.store import Store
    >>> files = write_report(Store("workspace"), 1, "out", gates=["ap_drop:3d:Car:*>10"])  # doctest: +SKIP
    >>> files.passed  # doctest: +SKIP
    True
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

from lidarfuzz.report.comparison import comparisons_for
from lidarfuzz.report.exports import finding_rows, junit_from_results, junit_xml, write_csvs, write_json
from lidarfuzz.report.gates import Gate, GateError, GateResult, evaluate, parse_gate, parse_gates
from lidarfuzz.report.html import render_html
from lidarfuzz.store.store import Store


@dataclass(frozen=True)
class ReportFiles:
    """What :func:`write_report` wrote, and whether every gate passed."""

    out_dir: Path
    html: Path
    json: Path
    ap_csv: Path
    delta_ap_csv: Path
    violations_csv: Path
    findings_csv: Path
    junit: Path
    passed: bool
    results: tuple[GateResult, ...] = ()
    comparisons: tuple[Path, ...] = ()

    @property
    def failed(self) -> tuple[GateResult, ...]:
        """The gates that failed or matched nothing."""
        return tuple(r for r in self.results if not r.passed)


def write_report(store: Store, task_id: int, out_dir: str | Path, *, baseline: int | None = None,
                 gates: Iterable[Gate | str] = (), images: int = 12) -> ReportFiles:
    """Write every report file of task ``task_id`` into ``out_dir`` (created; files overwritten).

    Works on an unfinished task too: the files show what exists and say so.

    Args:
        store: The campaign store.
        task_id: The task.
        out_dir: Where the files go.
        baseline: A task of another system on the same campaign, for Robo3D's CE and mCE, and
            compared with (violation rates and their significance, disagreements, recall and AP
            by group); without it, the reference tasks the task's campaign created are.
        gates: Rules (or parsed :class:`Gate`) for ``junit.xml``; none: the default set
            (see :mod:`lidarfuzz.report.exports`).
        images: How many findings get a bird's-eye picture (each takes about a second).

    Raises:
        GateError: When a rule does not parse (before anything is written).
        StoreError: When there is no such task.
    """
    from lidarfuzz.campaign.results import summarise
    from lidarfuzz.report.bev import finding_images

    parsed = parse_gates(gates)
    summary = summarise(store, task_id, baseline=baseline)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    results = evaluate(summary, parsed)
    top = [f.id for f in summary.findings.top]
    if summary.kind_summary.get("modality") == "camera":  # DeepTest's pairs: images and steering arrows
        from lidarfuzz.report.camera import finding_images as camera_images

        pictures = camera_images(store, top, limit=images)
    else:
        pictures = finding_images(store, top, limit=images)
    comparisons, notes = comparisons_for(store, task_id, baseline)
    compared = []
    for comparison in comparisons:
        path = out / f"comparison-{comparison.b.task}.json"
        path.write_text(comparison.model_dump_json(by_alias=True, indent=2), encoding="utf-8")
        compared.append(path)
    html = out / "report.html"
    html.write_text(render_html(summary, images=pictures, image_limit=images, comparisons=comparisons,
                                comparison_notes=notes), encoding="utf-8")
    report_json = write_json(summary, out / "report.json")
    csvs = write_csvs(summary, out, finding_rows(store, task_id))
    junit = out / "junit.xml"
    junit.write_text(junit_from_results(summary, results), encoding="utf-8")
    return ReportFiles(out, html, report_json, csvs["ap"], csvs["delta_ap"], csvs["violations"], csvs["findings"],
                       junit, all(r.passed for r in results), tuple(results), tuple(compared))


__all__ = ["Gate", "GateError", "GateResult", "ReportFiles", "junit_xml", "parse_gate", "render_html", "write_report"]
