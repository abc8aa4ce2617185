"""The thesis's chapter-6 experiment 2 (Figures 6-1, 6-2, 6-3), by one command.

The thesis trained PointPillars on 5,237 KITTI frames, ran the other 2,244 (its test set T) and
every mutation operator's version of T through it, and drew, per class, the bbox, BEV and 3D AP
of the original ("control") and of each operator's data set (Car at IoU 0.7, Pedestrian and
Cyclist at 0.5). Here::

    .venv/bin/python experiments/thesis_exp2.py                          # pillars, every operator
    .venv/bin/python experiments/thesis_exp2.py --operators thesis       # the thesis's 8 only
    .venv/bin/python experiments/thesis_exp2.py --dataset ~/kitti/training --split val --option weights=my.pt

1. the data: the val split of the built-in simulator world (200 frames, seed 0, frames 100–199;
   made under ``bench-out/classic-data`` on first use, as ``experiments/deeptest_rq.py`` does; the
   built-in ``pillars`` weights were trained on another seed's frames), or ``--dataset`` (a KITTI
   folder; ``--split NAME`` restricts it to ``ImageSets/NAME.txt``). A split is given to the
   campaign as a folder of links to its frames (campaigns take a whole folder);
2. one campaign (the engine ``lidarfuzz run`` drives) draws ``--frames`` of them at random with
   ``--seed`` and runs the system on each original and on every operator's mutant at one
   ``--severity``; no relation is checked (the thesis compares AP only);
3. each subtask's KITTI AP is read from the task's summary
   (:func:`lidarfuzz.campaign.results.summarise`), one table per class and Figures 6-1..6-3 (grouped
   bars: bbox, BEV and 3D AP per data set) go to ``--out`` (a markdown page; the figures into
   ``images/`` beside it).
"""

from __future__ import annotations

import argparse
import math
import shlex
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
DEFAULT_OUT = ROOT / "docs" / "experiments" / "thesis_exp2.md"
WORK = ROOT / "bench-out" / "thesis-exp2"
WORLD = ROOT / "bench-out" / "classic-data"  # the world experiments/deeptest_rq.py and benchmarks/suts.py use
#: The thesis's eight operators, by the abbreviations it uses (each an alias of a registered operator).
THESIS_OPERATORS = ("UNA", "UPD", "NNA", "RRNA", "RRPD", "RAR", "UIM", "RIM")
METRICS = ("bbox", "bev", "3d")
#: The thesis's figures in its order: Figure 6-1 Car, 6-2 Cyclist, 6-3 Pedestrian, with the IoU they use.
FIGURES = (("6-1", "Car", 0.7), ("6-2", "Cyclist", 0.5), ("6-3", "Pedestrian", 0.5))
ORIGINAL = "original"


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--frames", type=int, default=12, help="frames drawn at random (default 12)")
    parser.add_argument("--seed", type=int, default=0, help="seeds the draw and the mutants (default 0)")
    parser.add_argument("--severity", type=int, default=3, help="every operator's severity, 1-5 (default 3)")
    parser.add_argument("--operators", nargs="+", default=["all"], metavar="NAME",
                        help="operator names or aliases, 'thesis' for the thesis's 8, 'all' (default) for every "
                             "registered operator")
    parser.add_argument("--sut", default="pillars", help="system under test: a SUT spec (lidarfuzz suts)")
    parser.add_argument("--option", action="append", default=[], metavar="KEY=VALUE",
                        help="an option of the system (repeatable), e.g. weights=path/to.pt")
    parser.add_argument("--dataset", type=Path, default=None,
                        help="a KITTI folder to test instead of the built-in world's val split")
    parser.add_argument("--split", default=None,
                        help="only the frames of ImageSets/SPLIT.txt (default: val for the built-in world, every "
                             "frame of --dataset)")
    parser.add_argument("--difficulty", choices=("easy", "moderate", "hard"), default="moderate",
                        help="KITTI difficulty of the figures and tables (default moderate)")
    parser.add_argument("--workers", type=int, default=1, help="worker processes (1: run in this process)")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT,
                        help="the markdown page (figures in images/ beside it)")
    parser.add_argument("--workspace", type=Path, default=None,
                        help="the campaign store (default: a new folder under bench-out/thesis-exp2/)")
    args = parser.parse_args(argv)
    for name in ("frames", "workers"):
        if getattr(args, name) < 1:
            parser.error(f"--{name} must be at least 1, got {getattr(args, name)}")
    if not 1 <= args.severity <= 5:
        parser.error(f"--severity must be 1 to 5, got {args.severity}")
    if args.dataset is not None and not args.dataset.exists():
        parser.error(f"--dataset {args.dataset}: no such folder")
    try:
        args.operators = operator_names(args.operators)
    except KeyError as exc:
        parser.error(f"--operators: {exc.args[0]}")
    return args


def operator_names(choice: Sequence[str]) -> list[str]:
    """Registered operator names for ``choice`` (names, aliases, ``thesis``, ``all``), each once, in
    the order given; ``all`` lists every registered operator, the thesis's eight first (in its order),
    then the others in the registry's order."""
    from lidarfuzz.operators.registry import available, get

    names: list[str] = []
    for item in choice:
        if item.lower() == "all":
            thesis = [get(alias).name for alias in THESIS_OPERATORS]
            found = thesis + [n for n in available() if n not in thesis]
        elif item.lower() == "thesis":
            found = [get(alias).name for alias in THESIS_OPERATORS]
        else:
            found = [get(item).name]  # an unknown name raises KeyError naming it
        names += [n for n in found if n not in names]
    return names


def thesis_label(operator: str) -> str:
    """The thesis's abbreviation of ``operator`` when it has one (``uniform_noise_addition`` → ``UNA``),
    else its name."""
    from lidarfuzz.operators.registry import get

    aliases = {a.upper() for a in get(operator).aliases}
    return next((a for a in THESIS_OPERATORS if a in aliases), operator)


def split_view(root: Path, split: str, dest: Path) -> Path:
    """A folder of links to the frames of ``root``'s ``ImageSets/<split>.txt``: every per-frame file
    (``velodyne/<id>.bin``, ``label_2/<id>.txt``, ``calib``, ``roi``, …) and the top-level files.
    Reused when it lists the same frames."""
    listing = root / "ImageSets" / f"{split}.txt"
    if not listing.is_file():
        raise SystemExit(f"--split {split}: {listing} does not exist")
    ids = listing.read_text(encoding="utf-8").split()
    if not ids:
        raise SystemExit(f"--split {split}: {listing} lists no frame")
    stamp = dest / ".frames"
    if stamp.is_file() and stamp.read_text(encoding="utf-8").split() == ids:
        return dest
    wanted = set(ids)
    for entry in sorted(root.iterdir()):
        if entry.is_dir() and entry.name != "ImageSets":
            (dest / entry.name).mkdir(parents=True, exist_ok=True)
            for item in entry.iterdir():
                link = dest / entry.name / item.name
                if item.name.split(".", 1)[0] in wanted and not link.is_symlink():
                    link.symlink_to(item.resolve())
        elif entry.is_file() and not (dest / entry.name).is_symlink():
            dest.mkdir(parents=True, exist_ok=True)
            (dest / entry.name).symlink_to(entry.resolve())
    stamp.write_text("\n".join(ids) + "\n", encoding="utf-8")
    return dest


def ensure_data(args: argparse.Namespace) -> Path:
    """The folder the campaign tests: the built-in world's val split, or ``--dataset`` (its ``--split``)."""
    if args.dataset is None:
        from lidarfuzz.sim.dataset import GenerationConfig, generate_dataset, is_complete

        config = GenerationConfig(frames=200, seed=0, val_fraction=0.5)
        if not is_complete(WORLD, config):
            print(f"generating the world: 200 frames, seed 0 -> {WORLD}", flush=True)
            generate_dataset(WORLD, config, workers=args.workers, overwrite=True)
        return split_view(WORLD, args.split or "val", WORK / f"world-{args.split or 'val'}")
    if args.split is None:
        return args.dataset.resolve()
    from lidarfuzz.io.kitti import find_kitti_root

    root = find_kitti_root(args.dataset)
    if root is None:
        raise SystemExit(f"--dataset {args.dataset}: not a KITTI layout (no velodyne/ here or under training/)")
    name = f"{args.dataset.resolve().name}-{args.split}"
    return split_view(root, args.split, WORK / "splits" / name)


def run_campaign(args: argparse.Namespace, data: Path, options: dict[str, Any]) -> tuple[Any, int]:
    """Create and run the campaign; returns the store and the task's id."""
    from lidarfuzz.campaign.executor import InlineExecutor
    from lidarfuzz.campaign.runner import run_task
    from lidarfuzz.campaign.spec import parse_campaign
    from lidarfuzz.campaign.tasks import create_task
    from lidarfuzz.store import Store
    from lidarfuzz.store.models import Status

    spec = parse_campaign({
        "name": f"thesis-exp2 {args.sut}", "dataset": str(data), "sut": args.sut, "seed": args.seed,
        "frames": args.frames, "frame_order": "random", "relations": [],
        "operators": [{"name": name, "severities": [args.severity]} for name in args.operators],
    })
    workspace = args.workspace or WORK / f"ws-{int(time.time())}"
    workspace.mkdir(parents=True, exist_ok=True)
    store = Store(workspace)
    task_id = create_task(store, spec, sut_options=options)
    step = max(1, args.frames * (1 + len(args.operators)) // 20)

    def progress(event: Any) -> None:
        if event.task_done % step == 0 or event.task_done == event.task_total:
            print(f"  {event.task_done}/{event.task_total} units", flush=True)

    executor = InlineExecutor() if args.workers == 1 else None  # one worker: no process to start
    outcome = run_task(store, task_id, executor=executor, workers=args.workers, progress=progress)
    if outcome.status != Status.DONE:
        raise SystemExit(f"the campaign (task {task_id}, {workspace}) ended {outcome.status.value}")
    return store, task_id


@dataclass(frozen=True)
class Row:
    """One data set's AP for one class: ``ap[metric]`` (None: no AP) and the change from the original."""

    label: str  # "original", or the operator's thesis abbreviation or name
    operator: str  # "" for the original
    ap: dict[str, float | None]
    delta: dict[str, float | None]
    objects: int | None  # counted ground-truth objects of the class at the difficulty


def class_rows(subtasks: Sequence[Any], cls: str, difficulty: str = "moderate", points: str = "R40") -> list[Row]:
    """Per data set (the original first, as the summary lists it), ``cls``'s bbox, BEV and 3D AP and
    their change from the original's (mutant − original, AP points).

    ``subtasks`` are the summary's entries (:class:`~lidarfuzz.store.contracts.SubtaskSummary`, or
    anything with ``label``, ``operator`` and ``ap``); an AP that is absent or not finite is None,
    and so is a change either side of which is None.
    """
    from lidarfuzz.report.charts import ap_value

    rows: list[Row] = []
    base: dict[str, float | None] = {}
    for index, entry in enumerate(subtasks):
        ap = {m: ap_value(entry.ap, m, cls, difficulty, points) for m in METRICS}
        original = index == 0 and entry.operator == ORIGINAL
        if original:
            base = ap
        delta = {m: None if ap[m] is None or base.get(m) is None else ap[m] - base[m] for m in METRICS}  # type: ignore[operator]
        counts = entry.ap.num_objects.get(cls, {}) if entry.ap is not None else {}
        label = ORIGINAL if original else thesis_label(entry.operator)
        rows.append(Row(label, "" if original else entry.operator, ap, delta, counts.get(difficulty)))
    return rows


def _num(value: float | None, signed: bool = False) -> str:
    if value is None or not math.isfinite(value):
        return "—"
    return f"{value:+.1f}" if signed else f"{value:.1f}"


def _relative(row: Row, base: Row, metric: str) -> str:
    before, change = base.ap[metric], row.delta[metric]
    if before is None or change is None or before == 0:
        return "—"
    return f"{100 * change / before:+.0f} %"


def table_markdown(rows: Sequence[Row]) -> str:
    """One class's table: per data set the three APs, their changes (points) and the 3D change in %."""
    lines = ["| data set | operator | bbox AP | Δ | BEV AP | Δ | 3D AP | Δ | 3D change | objects |",
             "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    base = rows[0]
    for row in rows:
        cells = [row.label, f"`{row.operator}`" if row.operator else "—"]
        for metric in METRICS:
            cells += [_num(row.ap[metric]), "" if row is base else _num(row.delta[metric], signed=True)]
        cells += ["" if row is base else _relative(row, base, "3d"), "—" if row.objects is None else str(row.objects)]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def figure(rows: Sequence[Row], title: str, ylabel: str) -> bytes:
    """The thesis's figure form: per data set a group of three bars (bbox, BEV, 3D AP), the
    original's values as dashed lines."""
    from matplotlib.figure import Figure

    from lidarfuzz.report.charts import METRIC_COLOURS, METRIC_NAMES, figure_png

    fig = Figure(figsize=(max(6.0, 1.5 + 0.42 * len(rows)), 4.2), dpi=80, layout="constrained")
    ax = fig.subplots()
    width = 0.27
    top = 0.0
    for k, metric in enumerate(METRICS):
        values = [row.ap[metric] for row in rows]
        xs = [i + (k - 1) * width for i in range(len(rows))]
        ax.bar(xs, [v or 0.0 for v in values], width, color=METRIC_COLOURS[metric], label=METRIC_NAMES[metric])
        top = max([top, *(v for v in values if v is not None)])
        if values[0] is not None:
            ax.axhline(values[0], color=METRIC_COLOURS[metric], lw=0.8, ls="--")
    if rows and rows[0].objects:
        from lidarfuzz.oracles.kitti_eval import ap_ceiling

        ceiling = ap_ceiling(rows[0].objects)[0]
        if ceiling < 100.0:
            ax.axhline(ceiling, color="#999999", lw=1.0, ls=":",
                       label=f"highest AP|R40 with {rows[0].objects} objects")
            top = max(top, ceiling)
    ax.set_xticks(range(len(rows)), [row.label for row in rows], rotation=60, ha="right", fontsize=8)
    ax.set_xlim(-0.6, len(rows) - 0.4)
    ax.set_ylim(0, min(100.0, max(10.0, 10.0 * math.ceil(top * 1.15 / 10.0))))
    ax.set_ylabel(ylabel, fontsize=9)
    ax.set_title(title, fontsize=10)
    ax.grid(axis="y", lw=0.4, alpha=0.5)
    ax.set_axisbelow(True)
    ax.legend(fontsize=8, ncols=4, loc="upper right", frameon=False)
    return figure_png(fig)


#: A change smaller than this (AP points) is not counted as an operator hurting a class in the checks
#: of the thesis's conclusions: with a few dozen objects one detection more or less moves AP by several.
MATERIAL = 5.0


def lowered(rows: Sequence[Row], metric: str = "3d", by: float = 0.0) -> list[Row]:
    """The operators' rows whose ``metric`` AP is below the original's by more than ``by`` points,
    largest drop first."""
    found = [r for r in rows[1:] if r.delta[metric] is not None and r.delta[metric] < -by]  # type: ignore[operator]
    return sorted(found, key=lambda r: (r.delta[metric], r.label))  # type: ignore[arg-type, return-value]


def mean_change(rows: Sequence[Row], metric: str = "3d", relative: bool = False) -> float | None:
    """The mean change of ``metric`` AP over the operators' rows, in points or (``relative``) in
    percent of the original's AP. None: no operator has one, or the original frames have no object
    of the class (its AP is then 0 whatever the system does), or (``relative``) the original's AP is 0."""
    if not rows or rows[0].objects == 0:
        return None
    values = [r.delta[metric] for r in rows[1:] if r.delta[metric] is not None]
    if not values:
        return None
    mean: float = sum(values) / len(values)  # type: ignore[arg-type]
    if not relative:
        return mean
    base = rows[0].ap[metric]
    return None if not base else 100.0 * mean / base


def thesis_checks(by_class: dict[str, list[Row]]) -> str:
    """Each of the thesis's conclusions beside what these rows say (3D AP, the metric it stresses)."""

    def names(rows: list[Row]) -> str:
        return ", ".join(f"{r.label} ({_num(r.delta['3d'], signed=True)})" for r in rows) or "none"

    car = by_class["Car"]
    car_low = lowered(car, by=MATERIAL)
    thesis_four = {"UNA", "UPD", "NNA", "RRNA"}
    outside = [r for r in car_low if r.label not in thesis_four]
    means = {cls: mean_change(rows) for cls, rows in by_class.items()}
    ranked = sorted((m, c) for c, m in means.items() if m is not None)

    def relative(cls: str) -> str:
        value = mean_change(by_class[cls], relative=True)
        return "" if value is None else f" ({value:+.0f} %)"

    ped = {r.label: r for r in by_class["Pedestrian"]}
    upd = ped.get("UPD")
    upd_text = "not run (UPD was not among the operators)"
    if upd is not None:
        base = ped[ORIGINAL]
        upd_text = f"Pedestrian 3D AP {_num(base.ap['3d'])} → {_num(upd.ap['3d'])} ({_relative(upd, base, '3d')})"
    quiet = {cls: ", ".join(f"{r.label} {_num(r.delta['3d'], signed=True)}" for r in rows
                            if r.label in ("RAR", "UIM", "RIM")) for cls, rows in by_class.items()}
    quiet_text = "; ".join(f"{cls}: {text}" for cls, text in quiet.items() if text) or "not run"
    lines = [
        "| the thesis says | here (3D AP, change in points: mutant − original) |", "|---|---|",
        f"| Car is hurt little, and only by UNA, UPD, NNA and RRNA | Car 3D AP lowered by more than {MATERIAL:g} "
        f"points by {len(car_low)} of {len(car) - 1} operators: {names([r for r in car_low if r.label in thesis_four])}"
        f" of those four, and {names(outside[:8])}"
        f"{' …' if len(outside) > 8 else ''} |",
        "| Pedestrian is hurt most, then Cyclist, Car least | mean change over the operators: "
        + (", ".join(f"{c} {_num(m, signed=True)}{relative(c)}" for m, c in ranked) or "—")
        + "".join(f"; {c}: no object in the original frames" for c, m in means.items() if m is None) + " |",
        f"| UPD more than halves Pedestrian 3D AP | {upd_text} |",
        f"| rotation (RAR) and intensity changes (UIM, RIM) hurt little | {quiet_text} |",
    ]
    return "\n".join(lines)


def report(args: argparse.Namespace, summary: Any, by_class: dict[str, list[Row]], command: str, seconds: float,
           images: dict[str, Path], data: Path) -> str:
    """The markdown page (without its hand-written part)."""
    task = summary.task
    source = f"`{args.dataset}`" + (f", split `{args.split}`" if args.split else "") if args.dataset else \
        "the built-in simulator world's val split (200 frames, seed 0, frames 100–199; `bench-out/classic-data`)"
    failures = sum(s.failures for s in summary.subtasks)
    options = ", ".join(f"{k}={v}" for k, v in task.model.options.items()) or "none"
    parts = [
        "# The thesis's experiment 2 (Figures 6-1, 6-2, 6-3)\n",
        f"Regenerate: `{command}` ({seconds:.0f} s on the 2-core CPU machine, {args.workers} worker"
        f"{'s' if args.workers > 1 else ''}).\n",
        f"System `{args.sut}` (options: {options}; fingerprint `{task.model.fingerprint[:12]}`); {task.frames} frames "
        f"drawn at random (seed {args.seed}) from {source}; {len(summary.subtasks) - 1} operators at severity "
        f"{args.severity}, one mutant per frame; {task.done} system runs, {failures} of them without output "
        f"(scored as no detections). AP is KITTI's **AP|R40** (40 recall points: the official metric since "
        f"2019; the thesis's era and its PointPillars code reported AP|R11), difficulty **{args.difficulty}**, "
        f"at the thesis's IoU: Car 0.7, Pedestrian and Cyclist 0.5. Δ: mutant − original in AP points. "
        f"Data folder: `{data}`.\n",
        "**bbox AP** is available: a LiDAR-only detector gives no image boxes, so, as in KITTI's evaluation of "
        "PointPillars (and the devkit's Python ports), each detected 3D box is projected into the camera image "
        "through the frame's calibration and its 2D extent compared with the labelled 2D box (here the simulator's "
        "projection of the true box). It measures the 3D box's placement seen from the camera, not a camera "
        "detector.\n",
    ]
    if summary.ap_warnings:
        parts.append("Warnings from the evaluation (AP from few objects cannot reach 100; a change of one "
                     "detection moves it by whole steps):\n\n" + "\n".join(f"- {w}" for w in summary.ap_warnings)
                     + "\n")
    parts.append("## What the thesis concluded, checked here\n\n" + thesis_checks(by_class) + "\n")
    for number, cls, iou in FIGURES:
        rows = by_class[cls]
        path = images[cls]
        rel = path.relative_to(args.out.parent) if path.is_relative_to(args.out.parent) else path
        parts.append(f"## Figure {number}: {cls} (IoU {iou})\n\n![Figure {number}: {cls}]({rel})\n\n"
                     f"{table_markdown(rows)}\n")
    return "\n".join(parts)


#: Text after this heading is written by hand and kept when the page is regenerated.
KEPT = "\n## How this differs from the thesis"


def main(argv: list[str] | None = None) -> dict[str, list[Row]]:
    """Run the experiment; returns the rows per class and writes the page and the figures."""
    from lidarfuzz.campaign.results import summarise
    from lidarfuzz.operators.mutate import parse_assignments

    args = parse_args(argv)
    start = time.perf_counter()
    options = parse_assignments(args.option)
    data = ensure_data(args)
    store, task_id = run_campaign(args, data, options)
    summary = summarise(store, task_id)
    if summary.subtasks[0].ap is None:
        raise SystemExit(f"no AP for the original frames: are they labelled? (task {task_id})")
    by_class = {cls: class_rows(summary.subtasks, cls, args.difficulty) for _, cls, _ in FIGURES}
    seconds = time.perf_counter() - start
    images: dict[str, Path] = {}
    for number, cls, iou in FIGURES:
        path = args.out.parent / "images" / f"{args.out.stem}_fig{number}.png"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(figure(by_class[cls], f"Figure {number}: {cls} (IoU {iou}), {summary.task.frames} frames, "
                                               f"severity {args.severity}", f"AP|R40 ({args.difficulty}) %"))
        images[cls] = path
    given = sys.argv[1:] if argv is None else argv
    command = " ".join(["python experiments/thesis_exp2.py", *(shlex.quote(a) for a in given)])
    text = report(args, summary, by_class, command, seconds, images, data)
    old = args.out.read_text() if args.out.exists() else ""
    if KEPT in old:
        text += old[old.index(KEPT):]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(text)
    print(text)
    return by_class


if __name__ == "__main__":
    main()
