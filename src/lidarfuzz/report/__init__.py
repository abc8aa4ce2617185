"""Reports of a campaign task: a self-contained HTML page, JSON, CSV tables and JUnit XML.

:func:`write_report` writes them all for one task of the store::

    report.html       the report (offline: inline CSS, charts and pictures as data URIs)
    report.json       the task summary's JSON form (TaskSummary.dump() of lidarfuzz.campaign.results.summarise)
    ap.csv, delta_ap.csv, violations.csv, findings.csv
    ratings.csv       raters' verdicts per operator, the thesis's Table 6-7 (lidarfuzz.report.ratings)
    junit.xml         gates as test cases, for CI (grammar: lidarfuzz.report.gates)
    comparison-B.json the comparison with task B (a baseline, or a reference task of the campaign;
                      lidarfuzz.campaign.compare.TaskComparison), one per compared task

The files appear whole or not at all: they are written into a hidden staging folder inside
``out_dir``, flushed to disk, and only then renamed onto their names, so a full disk or a crash
leaves the previous report (or nothing) at each name, never a truncated file.
:func:`render_report` gives ``report.html``'s text alone (``lidarfuzz report --out -``: nothing
written, so a read-only workspace can be reported).

Example:
    >>> from lidarfuzz.store import Store
    >>> files = write_report(Store("workspace"), 1, "out", gates=["ap_drop:3d:Car:*>10"])  # doctest: +SKIP
    >>> files.passed  # doctest: +SKIP
    True
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

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
    ratings_csv: Path | None = None

    @property
    def failed(self) -> tuple[GateResult, ...]:
        """The gates that failed or matched nothing."""
        return tuple(r for r in self.results if not r.passed)


@dataclass(frozen=True)
class _Parts:
    """What a report is made of, read from the store once."""

    summary: Any
    pictures: Any
    comparisons: Any
    notes: Any
    verdicts: Any

    def html(self, images: int) -> str:
        return render_html(self.summary, images=self.pictures, image_limit=images, comparisons=self.comparisons,
                           comparison_notes=self.notes, ratings=self.verdicts)


def _parts(store: Store, task_id: int, baseline: int | None, images: int) -> _Parts:
    from lidarfuzz.campaign.ratings import tally
    from lidarfuzz.campaign.results import summarise
    from lidarfuzz.report.bev import finding_images

    summary = summarise(store, task_id, baseline=baseline)
    top = [f.id for f in summary.findings.top]
    if summary.kind_summary.get("modality") == "camera":  # DeepTest's pairs: images and steering arrows
        from lidarfuzz.report.camera import finding_images as camera_images

        pictures = camera_images(store, top, limit=images)
    else:
        pictures = finding_images(store, top, limit=images)
    comparisons, notes = comparisons_for(store, task_id, baseline)
    return _Parts(summary, pictures, comparisons, notes, tally(store, task_id))


def render_report(store: Store, task_id: int, *, baseline: int | None = None, images: int = 12) -> str:
    """``report.html``'s text for task ``task_id`` (self-contained: pictures inline), writing nothing."""
    return _parts(store, task_id, baseline, images).html(images)


@contextlib.contextmanager
def _staged(out: Path) -> Iterator[Path]:
    """A hidden folder inside ``out`` to write into; on success every file in it is flushed to disk
    and renamed onto its name in ``out`` (a rename within one folder: all or nothing per file), and
    the folder removed; on failure the folder is removed and ``out`` keeps what it had."""
    staging: Path | None = None
    try:
        out.mkdir(parents=True, exist_ok=True)
        staging = Path(tempfile.mkdtemp(prefix=".report.", suffix=".tmp", dir=out))
        yield staging
        for made in sorted(staging.iterdir()):
            with open(made, "rb+") as handle:
                os.fsync(handle.fileno())
        for made in sorted(staging.iterdir()):
            os.replace(made, out / made.name)
    except OSError as exc:  # named by the file the user asked for, not the hidden one
        name = Path(exc.filename).name if staging is not None and exc.filename is not None and \
            Path(exc.filename).parent == staging else None
        raise OSError(exc.errno, exc.strerror, str(out / name) if name else str(out)) from exc
    finally:
        if staging is not None:
            shutil.rmtree(staging, ignore_errors=True)


def write_report(store: Store, task_id: int, out_dir: str | Path, *, baseline: int | None = None,
                 gates: Iterable[Gate | str] = (), images: int = 12) -> ReportFiles:
    """Write every report file of task ``task_id`` into ``out_dir`` (created; files overwritten).

    Works on an unfinished task too: the files show what exists and say so. Each file appears
    whole or not at all (see above).

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
        OSError: When the disk fails (full, read-only, ...): no file of this report is left
            half-written.
    """
    from lidarfuzz.report.ratings import write_ratings_csv

    parsed = parse_gates(gates)
    parts = _parts(store, task_id, baseline, images)
    summary = parts.summary
    out = Path(out_dir)
    results = evaluate(summary, parsed)
    with _staged(out) as staging:
        compared = []
        for comparison in parts.comparisons:
            name = f"comparison-{comparison.b.task}.json"
            (staging / name).write_text(comparison.model_dump_json(by_alias=True, indent=2), encoding="utf-8")
            compared.append(out / name)
        (staging / "report.html").write_text(parts.html(images), encoding="utf-8")
        write_json(summary, staging / "report.json")
        csvs = {key: out / path.name for key, path in
                write_csvs(summary, staging, finding_rows(store, task_id)).items()}
        (staging / "junit.xml").write_text(junit_from_results(summary, results), encoding="utf-8")
        write_ratings_csv(parts.verdicts, staging / "ratings.csv")
    return ReportFiles(out, out / "report.html", out / "report.json", csvs["ap"], csvs["delta_ap"],
                       csvs["violations"], csvs["findings"], out / "junit.xml", all(r.passed for r in results),
                       tuple(results), tuple(compared), out / "ratings.csv")


__all__ = ["Gate", "GateError", "GateResult", "ReportFiles", "junit_xml", "parse_gate", "render_html", "render_report",
           "write_report"]
