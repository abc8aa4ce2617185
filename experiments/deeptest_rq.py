"""DeepTest's research questions on the learned detector (`pillars`) and the simulator's world.

One command per question; each writes ``docs/experiments/rqN.md`` (tables, the figures behind
them and the command that regenerates it) and prints the same::

    .venv/bin/python experiments/deeptest_rq.py rq1   # coverage vs output diversity
    .venv/bin/python experiments/deeptest_rq.py rq2   # neurons activated by different operators
    .venv/bin/python experiments/deeptest_rq.py rq3   # cumulative coverage: seeds, operators, guided search
    .venv/bin/python experiments/deeptest_rq.py rq4   # violations per relation and operator
    .venv/bin/python experiments/deeptest_rq.py rq5   # retraining with generated failures (GPU if present)

Data: the val split of the 200-frame seed-0 simulator set (``bench-out/classic-data``, made on
first use; the frames `benchmarks/suts.py` evaluates on, none of them seen in training).
Everything is seeded; results are reported as they come out.
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs" / "experiments"
DATA = ROOT / "bench-out" / "classic-data"
OPERATORS = ("gaussian_noise_addition", "uniform_point_deletion", "intensity_scaling", "outside_roi_scatter",
             "beam_missing", "fog", "rain", "snow", "gaussian_jitter", "random_region_point_deletion")


def ensure_data() -> list[str]:
    from lidarfuzz.sim.dataset import GenerationConfig, generate_dataset, is_complete

    config = GenerationConfig(frames=200, seed=0, val_fraction=0.5)
    if not is_complete(DATA, config):
        generate_dataset(DATA, config, workers=2, overwrite=True)
    return (DATA / "ImageSets" / "val.txt").read_text().split()


def setup(relations: list[Any] | None = None) -> tuple[Any, Any, Any]:
    from lidarfuzz.campaign.coverage_search import coverage_profile, profile_dirs
    from lidarfuzz.coverage import ActivationRecorder
    from lidarfuzz.io.kitti import open_kitti
    from lidarfuzz.oracles.relations.registry import from_spec
    from lidarfuzz.search.evaluate import SearchEvaluator
    from lidarfuzz.suts.learned.sut import PillarsDetector

    sut = PillarsDetector()
    sut.load()
    evaluator = SearchEvaluator(open_kitti(DATA), sut, relations or [from_spec("preservation")],
                                ActivationRecorder(sut.module))
    return sut, evaluator, coverage_profile(sut.module, profile_dirs(sut))


#: Text after this heading is written by hand (a manual look at results) and kept when a page is regenerated.
KEPT = "\n## Manual look"


def write(name: str, title: str, body: str, command: str, seconds: float) -> None:
    DOCS.mkdir(parents=True, exist_ok=True)
    text = (f"# {title}\n\nRegenerate: `{command}` ({seconds:.0f} s on the 2-core CPU machine).\n\n"
            f"{body.strip()}\n")
    page = DOCS / f"{name}.md"
    old = page.read_text() if page.exists() else ""
    if KEPT in old:
        text += old[old.index(KEPT):]
    page.write_text(text)
    print(text)


def nc_mask(values: dict[str, np.ndarray], threshold: float = 0.2) -> np.ndarray:
    from lidarfuzz.coverage import NeuronCoverage

    return NeuronCoverage(threshold).hits([np.asarray(v, dtype=np.float64)[None] for v in values.values()])[0]


def mutants(evaluator: Any, frames: list[str], severities: tuple[int, ...], seed: int = 0) -> list[dict[str, Any]]:
    """Each operator at each severity on each frame: the evaluation and its metadata."""
    from lidarfuzz.operators.registry import get
    from lidarfuzz.search.evaluate import ChainStep

    out = []
    for f_index, frame in enumerate(frames):
        for o_index, name in enumerate(OPERATORS):
            chains = [[ChainStep(get(name).at_severity(s).spec())] for s in severities]
            rngs = [np.random.default_rng(np.random.SeedSequence([seed, f_index, o_index, s])) for s in severities]
            for severity, e in zip(severities, evaluator.mutants(frame, chains, rngs), strict=True):
                out.append({"frame": frame, "operator": name, "severity": severity, "evaluation": e})
    return out


def output_change(source: Any, follow: Any) -> float:
    """1 − mean best BEV IoU of the source's confident detections in the follow-up (0: same output)."""
    from lidarfuzz.scene.geometry import iou_bev

    if source is None or follow is None:
        return float("nan")
    src = source.select(source.scores >= 0.3)
    fol = follow.select(follow.scores >= 0.3)
    if len(src) == 0:
        return 0.0 if len(fol) == 0 else 1.0
    if len(fol) == 0:
        return 1.0
    iou = iou_bev(src.as_array(), fol.as_array())
    return float(1.0 - iou.max(axis=1).mean())


def rq1(args: argparse.Namespace) -> None:
    from scipy.stats import mannwhitneyu, spearmanr

    start = time.perf_counter()
    frames = ensure_data()[: args.frames]
    _, evaluator, _ = setup()
    rows = mutants(evaluator, frames, (1, 3, 5))
    nc = np.array([nc_mask(r["evaluation"].values).mean() if r["evaluation"].values else np.nan for r in rows])
    change = np.array([output_change(evaluator.original(r["frame"]).output, r["evaluation"].output) for r in rows])
    ok = np.isfinite(nc) & np.isfinite(change)
    rho, p = spearmanr(nc[ok], change[ok])
    per_op = []
    for name in OPERATORS:
        sel = ok & np.array([r["operator"] == name for r in rows])
        if sel.sum() >= 3 and np.ptp(nc[sel]) > 0 and np.ptp(change[sel]) > 0:
            r_op, p_op = spearmanr(nc[sel], change[sel])
            per_op.append(f"| {name} | {sel.sum()} | {r_op:+.2f} | {p_op:.3g} |")
        else:
            per_op.append(f"| {name} | {sel.sum()} | — | — |")
    # Wilcoxon rank-sum: inputs whose confident detections are mostly cars vs mostly vulnerable road users
    groups: dict[str, list[float]] = {"Car": [], "Pedestrian/Cyclist": []}
    for row, value in zip(rows, nc, strict=True):
        out = row["evaluation"].output
        if out is None or not np.isfinite(value):
            continue
        labels = out.labels[out.scores >= 0.3]
        if len(labels):
            cars = (labels == "Car").mean()
            groups["Car" if cars >= 0.5 else "Pedestrian/Cyclist"].append(float(value))
    stat, p_w = mannwhitneyu(groups["Car"], groups["Pedestrian/Cyclist"]) if all(groups.values()) else (np.nan, np.nan)
    # effect size of the rank-sum test: the rank-biserial correlation r = 2U / (n1 n2) - 1 (Cliff's
    # delta of the two groups: +1 when every car input has the higher NC, -1 when every other does)
    pairs = len(groups["Car"]) * len(groups["Pedestrian/Cyclist"])
    rank_biserial = 2 * stat / pairs - 1 if pairs else np.nan
    body = f"""
DeepTest's RQ1 asks whether neuron coverage tracks the diversity of the model's outputs. Here: for
{len(frames)} val frames × {len(OPERATORS)} operators × severities 1, 3, 5 ({int(ok.sum())} mutants), each
mutant's own neuron coverage (NC, t = 0.2, the share of the {nc_mask(rows[0]['evaluation'].values).size} watched
neurons it activates) against how much the detections changed from the frame's original output
(1 − mean best BEV IoU of the original's detections with score ≥ 0.3; 0 = unchanged).

**Spearman ρ = {rho:+.3f} (p = {p:.3g}, n = {int(ok.sum())}).**

| operator | n | Spearman ρ | p |
|---|---:|---:|---:|
{chr(10).join(per_op)}

Wilcoxon rank-sum (Mann–Whitney U) on per-input NC between inputs whose confident detections are mostly
cars (n = {len(groups['Car'])}, median NC {np.median(groups['Car']) if groups['Car'] else float('nan'):.3f}) and
mostly pedestrians/cyclists (n = {len(groups['Pedestrian/Cyclist'])}, median NC
{np.median(groups['Pedestrian/Cyclist']) if groups['Pedestrian/Cyclist'] else float('nan'):.3f}): U = {stat},
p = {p_w:.3g}; effect size (rank-biserial correlation, Cliff's δ) r = {rank_biserial:+.3f}
(|r| < 0.11 negligible, < 0.28 small, < 0.43 medium, else large, by Vargha & Delaney's bands as
Romano et al. translate them). The Spearman ρ above is its own effect size.

Reading: a positive ρ means inputs that activate more neurons also change the output more — DeepTest's
finding for steering models. The sign and size above are what this detector and world gave; with
per-input min-max scaling NC saturates near {np.nanmedian(nc):.2f} for most inputs, which limits how much it
can say (a known weakness of NC, and why KMNC/NBC/SNAC are tracked too).
"""
    write("rq1", "RQ1: neuron coverage vs output diversity", body,
          f"python experiments/deeptest_rq.py rq1 --frames {args.frames}", time.perf_counter() - start)


def rq2(args: argparse.Namespace) -> None:
    start = time.perf_counter()
    frames = ensure_data()[: args.frames]
    _, evaluator, _ = setup()
    rows = mutants(evaluator, frames, (3,))
    activated: dict[str, dict[str, np.ndarray]] = {}
    for row in rows:
        if row["evaluation"].values:
            activated.setdefault(row["operator"], {})[row["frame"]] = nc_mask(row["evaluation"].values)
    originals = {f: nc_mask(evaluator.original(f).values) for f in frames}
    names = [n for n in OPERATORS if n in activated]

    def jaccard(a: np.ndarray, b: np.ndarray) -> float:
        union = (a | b).sum()
        return float(1 - (a & b).sum() / union) if union else 0.0

    # DeepTest compares the neurons each transformation activates *beyond* the seed: new activations
    lines = ["| | " + " | ".join(n.replace("_", " ") for n in names) + " |", "|---" * (len(names) + 1) + "|"]
    means = []
    for a in names:
        cells = []
        for b in names:
            d = [jaccard(activated[a][f] & ~originals[f], activated[b][f] & ~originals[f])
                 for f in frames if f in activated[a] and f in activated[b]]
            cells.append(f"{np.median(d):.2f}")
            if a < b:
                means.append(np.median(d))
        lines.append(f"| {a.replace('_', ' ')} | " + " | ".join(cells) + " |")
    whole = [jaccard(activated[a][f], activated[b][f]) for a, b in itertools.combinations(names, 2) for f in frames
             if f in activated[a] and f in activated[b]]
    body = f"""
DeepTest's RQ2 asks whether different transformations activate different neurons. For {len(frames)} val frames,
each operator at severity 3: the neurons each mutant activates (NC, t = 0.2) that the frame itself did not,
and the median Jaccard distance between those sets for every pair of operators (1 = disjoint, 0 = the same).

Median over operator pairs: **{np.median(means):.2f}**; over all pairs of whole activation sets (seed's own
activations included): {np.median(whole):.2f}.

{chr(10).join(lines)}

Reading: distances near 1 mean the operators drive different parts of the network (DeepTest found this for
image transformations, which is what motivates combining them); distances near 0 mean they reach the same
neurons. Whole activation sets are dominated by what the seed frame already activates.
"""
    write("rq2", "RQ2: do different operators activate different neurons?", body,
          f"python experiments/deeptest_rq.py rq2 --frames {args.frames}", time.perf_counter() - start)


def rq3(args: argparse.Namespace) -> None:
    from lidarfuzz.coverage import make_criteria
    from lidarfuzz.search.algorithms import SearchConfig, make_search

    start = time.perf_counter()
    frames = ensure_data()[: args.frames]
    _, evaluator, profile = setup()
    specs = ["nc:0.2", "kmnc:10", "nbc", "snac", "tknc:2"]

    def fresh() -> list[Any]:
        return make_criteria(specs, profile)

    def feed(criteria: list[Any], values: dict[str, np.ndarray]) -> None:
        for c in criteria:
            c.update({k: v[None] for k, v in values.items()})

    seeds_only = fresh()
    for f in frames:
        feed(seeds_only, evaluator.original(f).values)
    cumulative = fresh()
    for f in frames:
        feed(cumulative, evaluator.original(f).values)
    rows = mutants(evaluator, frames, (1, 3, 5))
    for row in rows:
        if row["evaluation"].values:
            feed(cumulative, row["evaluation"].values)
    searches = {}
    for kind in ("guided", "fuzz"):
        config = SearchConfig(kind=kind, operators=OPERATORS, budget=len(rows), criteria=tuple(specs))
        search = make_search(config, frames, fresh(), seed=0)
        while not search.finished:
            search.step(evaluator)
        searches[kind] = search
    table = ["| criterion | seeds alone | + every operator × severity 1/3/5 | guided search | fuzz loop |",
             "|---|---:|---:|---:|---:|"]
    for i, name in enumerate(specs):
        values = [seeds_only[i].coverage(), cumulative[i].coverage(), searches["guided"].criteria[i].coverage(),
                  searches["fuzz"].criteria[i].coverage()]
        table.append(f"| {name.split(':')[0].upper()} | " + " | ".join(f"{100 * v:.1f}%" for v in values) + " |")
    g, z = searches["guided"].stats, searches["fuzz"].stats
    body = f"""
The form of DeepTest's Table 6: coverage of {len(frames)} seed frames alone, of the seeds plus every operator
of the pool at severities 1, 3 and 5 applied to each ({len(rows)} mutants), and of the guided search
(DeepTest's Algorithm 1) and the fuzz loop with the same budget of {len(rows)} tests, all with the same operators.
KMNC / NBC / SNAC use the training profile of the built-in weights (300 training frames).

{chr(10).join(table)}

Guided search: {g['tests']} tests, {g['accepted']} raised NC, {g['violating']} violated MR1. Fuzz loop:
{z['tests']} tests, {z['accepted']} accepted (valid and new NC), {z['invalid']} invalid, {z['violating']} violated
MR1, {z['findings']} unique findings after deduplication.
"""
    write("rq3", "RQ3: cumulative coverage — seeds, operators, guided search", body,
          f"python experiments/deeptest_rq.py rq3 --frames {args.frames}", time.perf_counter() - start)


def rq4(args: argparse.Namespace) -> None:
    from lidarfuzz.campaign.results import summarise
    from lidarfuzz.campaign.runner import run_task
    from lidarfuzz.campaign.spec import parse_campaign
    from lidarfuzz.campaign.tasks import create_task
    from lidarfuzz.store.store import Store

    start = time.perf_counter()
    ensure_data()
    workspace = ROOT / "bench-out" / "rq4-workspace"
    import shutil

    shutil.rmtree(workspace, ignore_errors=True)
    store = Store(workspace)
    spec = parse_campaign({"dataset": str(DATA), "sut": "pillars", "seed": 0, "frames": 40,
                           "operators": [{"name": n, "severities": [1, 3, 5]} for n in OPERATORS],
                           "relations": ["preservation", "gt_recall"]})
    task_id = create_task(store, spec)
    from lidarfuzz.campaign.executor import InlineExecutor

    run_task(store, task_id, executor=InlineExecutor())
    data = summarise(store, task_id)
    lines = ["| operator (severities 1, 3, 5 pooled) | MR1 preservation: frames violated / checked | "
             "GT recall: violated / checked |",
             "|---|---:|---:|"]
    by = {(r["relation"], r["operator"]): r for r in data["violations"]["relation_operator"]}
    for op in sorted({r["operator"] for r in data["violations"]["relation_operator"]}):
        cells = []
        for rel in ("preservation", "gt_recall"):
            r = by.get((rel, op))
            cells.append("—" if r is None else f"{r['violated']}/{r['checked']} ({100 * (r['rate'] or 0):.0f}%)")
        lines.append(f"| {op} | " + " | ".join(cells) + " |")
    body = f"""
The form of DeepTest's Tables 7–8 for a detector: how many frames violate each relation under each operator
and severity — MR1 (preservation: an object the detector found on the frame is still found, BEV IoU ≥ 0.5,
score ≥ 0.5, inside the drivable-area ROI) for the invariant operators, and ground-truth recall (a labelled
object found before is not lost) for all — on the first 40 frames of the seed-0 simulator set, `pillars` as SUT
(task {task_id} in `{workspace.relative_to(ROOT)}`;
`lidarfuzz report {task_id} --workspace {workspace.relative_to(ROOT)}` shows each finding with bird's-eye pictures).

{chr(10).join(lines)}

Findings: {data['findings']['total']} ({', '.join(f'{k} {v}' for k, v in sorted(data['findings']['by_kind'].items()))}).

The manual look at a sample of these findings, for false positives, is below (`python
experiments/deeptest_rq.py rq4-review` recomputes its figures and pictures).
"""
    write("rq4", "RQ4: violations per relation and operator", body,
          "python experiments/deeptest_rq.py rq4", time.perf_counter() - start)


def rq4_review(args: argparse.Namespace) -> None:
    """The false-positive check of RQ4's findings: for every lost object, how many of its points
    the mutant kept (a relation's premise is that the object is still there to be seen), plus
    bird's-eye pictures of a seeded sample for the manual look."""
    from lidarfuzz.report.bev import draw_pair, load_pair
    from lidarfuzz.report.charts import figure_png
    from lidarfuzz.scene.geometry import points_in_boxes
    from lidarfuzz.store.models import Finding
    from lidarfuzz.store.store import Store

    workspace = ROOT / "bench-out" / "rq4-workspace"
    store = Store(workspace)
    with store.session() as s:
        rows = [(f.id, f.kind, f.cls) for f in s.query(Finding).order_by(Finding.id)]
    datasets: dict[str, Any] = {}
    table = []
    for finding_id, kind, cls in rows:
        pair = load_pair(store, finding_id, datasets=datasets)
        if pair.mutant is None:
            continue
        if pair.lost_gt:  # the labelled object, in the source and (moved with it) in the mutant
            g, f = pair.lost_gt[0], pair.lost_gt_follow[0]
            before_box = pair.source.boxes.as_array()[g:g + 1]
            after_box = pair.mutant.boxes.as_array()[f:f + 1] if f >= 0 else None
        elif pair.lost_source:  # the detection the follow-up lost (invariant operators move nothing)
            before_box = after_box = pair.source_detections.as_array()[pair.lost_source[0]:pair.lost_source[0] + 1]
        else:
            continue
        before = int(points_in_boxes(pair.source.points.xyz, before_box).sum())
        after = 0 if after_box is None else int(points_in_boxes(pair.mutant.points.xyz, after_box).sum())
        table.append({"id": finding_id, "kind": kind, "cls": cls, "label": pair.finding["label"],
                      "range": float(np.hypot(*before_box[0, :2])), "before": before, "after": after})
    kept = np.array([t["after"] / max(t["before"], 1) for t in table])
    lines = ["| relation | findings | object kept ≥ 50 % of its points | kept < 10 % (the premise fails) |",
             "|---|---:|---:|---:|"]
    for kind in sorted({t["kind"] for t in table}):
        mask = np.array([t["kind"] == kind for t in table])
        lines.append(f"| {kind} | {int(mask.sum())} | {int((kept[mask] >= 0.5).sum())} | "
                     f"{int((kept[mask] < 0.1).sum())} |")
    by_op: dict[str, list[float]] = {}
    for t, k in zip(table, kept, strict=True):
        by_op.setdefault(t["label"].split("@")[0], []).append(k)
    op_lines = ["| operator | findings | median share of the lost object's points kept |", "|---|---:|---:|"]
    for op, values in sorted(by_op.items()):
        op_lines.append(f"| {op} | {len(values)} | {100 * float(np.median(values)):.0f} % |")
    rng = np.random.default_rng(args.seed)
    sample = sorted(rng.choice(len(table), size=min(args.sample, len(table)), replace=False).tolist())
    images = ROOT / "docs" / "experiments" / "images" / "rq4"
    images.mkdir(parents=True, exist_ok=True)
    sample_lines = ["| finding | relation | operator | class | range | points before → after |",
                    "|---|---|---|---|---:|---:|"]
    for i in sample:
        t = table[i]
        pair = load_pair(store, t["id"], datasets=datasets)
        (images / f"finding-{t['id']}.png").write_bytes(figure_png(draw_pair(pair)))
        sample_lines.append(f"| [{t['id']}](images/rq4/finding-{t['id']}.png) | {t['kind']} | {t['label']} | "
                            f"{t['cls']} | {t['range']:.1f} m | {t['before']} → {t['after']} |")
    print("\n".join(lines), "\n\n" + "\n".join(op_lines), "\n\n" + "\n".join(sample_lines))
    (ROOT / "bench-out" / "rq4-review.json").write_text(json.dumps(table, indent=1))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("question", choices=["rq1", "rq2", "rq3", "rq4", "rq4-review"])
    parser.add_argument("--frames", type=int, default=10, help="val frames used as seeds (rq1-rq3)")
    parser.add_argument("--sample", type=int, default=12, help="findings drawn for the manual look (rq4-review)")
    parser.add_argument("--seed", type=int, default=0, help="seed of that sample")
    args = parser.parse_args()
    {"rq1": rq1, "rq2": rq2, "rq3": rq3, "rq4": rq4, "rq4-review": rq4_review}[args.question](args)


if __name__ == "__main__":
    sys.exit(main())
