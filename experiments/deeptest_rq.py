"""DeepTest's research questions on the learned detector (`pillars`) and the simulator's world.

One command per question; each writes ``docs/experiments/rqN.md`` (tables, the figures behind
them and the command that regenerates it) and prints the same::

    .venv/bin/python experiments/deeptest_rq.py rq1   # coverage vs output diversity
    .venv/bin/python experiments/deeptest_rq.py rq2   # neurons activated by different operators
    .venv/bin/python experiments/deeptest_rq.py rq3   # cumulative coverage: seeds, operators, guided search
    .venv/bin/python experiments/deeptest_rq.py rq4   # violations per relation and operator
    .venv/bin/python experiments/deeptest_rq.py rq5   # retraining with generated failures (GPU if present)
    .venv/bin/python experiments/deeptest_rq.py fig5  # Figure 5: NC per seed, each operator w.r.t. the seed
    .venv/bin/python experiments/deeptest_rq.py fig6  # Figure 6: label deviation of violating mutants vs originals

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
    fresh = {a: np.median([(activated[a][f] & ~originals[f]).sum() for f in activated[a]]) for a in names}
    both = [jaccard(activated[a][f] & ~originals[f], activated[b][f] & ~originals[f])
            for a, b in itertools.combinations(names, 2) for f in frames if f in activated[a] and f in activated[b]
            and (activated[a][f] & ~originals[f]).any() and (activated[b][f] & ~originals[f]).any()]
    body = f"""
DeepTest's RQ2 asks whether different transformations activate different neurons. For {len(frames)} val frames,
each operator at severity 3: the neurons each mutant activates (NC, t = 0.2) that the frame itself did not,
and the median Jaccard distance between those sets for every pair of operators (1 = disjoint, 0 = the same).

Median over operator pairs: **{np.median(means):.2f}**; over the (operator pair, frame) cases where both
operators newly activate something: {np.median(both):.2f} (n = {len(both)}); over all pairs of whole activation
sets (seed's own activations included): {np.median(whole):.2f}.

{chr(10).join(lines)}

Neurons each operator newly activates on a frame (median over frames):
{', '.join(f'{a.replace("_", " ")} {fresh[a]:.0f}' for a in names)}.

Reading: distances near 1 mean the operators drive different parts of the network (DeepTest found this for
image transformations, which is what motivates combining them); distances near 0 mean they reach the same
neurons. Whole activation sets are dominated by what the seed frame already activates. An operator that
activates no new neuron on a frame is at distance 1 from every operator that does and at 0 from another that
does not (two empty sets), so its row says nothing about which neurons it drives.
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
    from lidarfuzz.operators.registry import get as get_operator
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
    data = summarise(store, task_id).dump()
    # a campaign checks a relation that assumes a harmless mutation only at the severities the operator is
    # meant to be harmless at (its harmless_up_to): say per cell which severities were checked
    checked_at: dict[tuple[str, str], list[int]] = {}
    for sub in data["subtasks"]:
        for rel in sub.get("relations") or []:
            checked_at.setdefault((rel, sub["operator"]), []).append(sub["severity"])
    lines = ["| operator | harmless up to | MR1 preservation: frames violated / checked | "
             "GT recall: violated / checked |",
             "|---|---:|---:|---:|"]
    by = {(r["relation"], r["operator"]): r for r in data["violations"]["relation_operator"]}
    for op in OPERATORS:
        cells = []
        for rel in ("preservation", "gt_recall"):
            r, at = by.get((rel, op)), sorted(checked_at.get((rel, op), []))
            cells.append("not checked" if r is None or not at else
                         f"{r['violated']}/{r['checked']} ({100 * (r['rate'] or 0):.1f}%) at {', '.join(map(str, at))}")
        lines.append(f"| {op} | {get_operator(op).harmless_up_to} | " + " | ".join(cells) + " |")
    body = f"""
The form of DeepTest's Tables 7–8 for a detector: how many frames violate each relation under each operator
and severity — MR1 (preservation: an object the detector found on the frame is still found, BEV IoU ≥ 0.5,
score ≥ 0.5, inside the drivable-area ROI) for the invariant operators, and ground-truth recall (a labelled
object found before is not lost) for all — on the first 40 frames of the seed-0 simulator set, `pillars` as SUT,
each operator at severities 1, 3 and 5. Both relations assume the mutation is harmless, so the campaign
checks them only at the severities each operator is meant to be harmless at (its `harmless_up_to`, with the
reason in its `harmless_because`); the cells say at which severities they were checked
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


#: Severities of fig5 and fig6: every level an operator has, as DeepTest varies each transformation's parameter.
SEVERITIES = (1, 2, 3, 4, 5)


def coverage_gain(seed: np.ndarray, transformed: list[np.ndarray]) -> tuple[int, int, float]:
    """Neurons a seed activates alone (N_O), with its transformed versions too (N_T, the union of
    the masks), and DeepTest's increase ``(N_T − N_O) / N_O`` (NaN when the seed activates none).

    Example:
        >>> coverage_gain(np.array([True, True, False, False]), [np.array([False, True, True, False])])
        (2, 3, 0.5)
    """
    union = np.asarray(seed, dtype=bool).copy()
    for mask in transformed:
        union |= np.asarray(mask, dtype=bool)
    n_o, n_t = int(np.count_nonzero(seed)), int(np.count_nonzero(union))
    return n_o, n_t, (n_t - n_o) / n_o if n_o else float("nan")


def matched_pairs_rank_biserial(x: np.ndarray, y: np.ndarray) -> float:
    """Effect size of the Wilcoxon signed-rank test of ``x`` against ``y`` (Kerby's matched-pairs
    rank-biserial correlation): ``(R+ − R−) / (R+ + R−)``, the rank sums of the positive and the
    negative differences ``x − y`` (zeros dropped as the test drops them, ties given their mean
    rank); +1 when every x exceeds its y, −1 when every one falls short, NaN without a difference.

    Example:
        >>> matched_pairs_rank_biserial(np.array([3.0, 1, 5, 2]), np.array([1.0, 2, 5, 0]))  # (5 − 1) / 6
        0.6666666666666666
    """
    from scipy.stats import rankdata

    diff = np.asarray(x, dtype=np.float64) - np.asarray(y, dtype=np.float64)
    diff = diff[diff != 0]
    if diff.size == 0:
        return float("nan")
    ranks = rankdata(np.abs(diff))
    plus, minus = float(ranks[diff > 0].sum()), float(ranks[diff < 0].sum())
    return (plus - minus) / (plus + minus)


def save_chart(fig: Any, name: str) -> str:
    """Write a matplotlib figure to ``docs/experiments/images/<name>.png``; the page's relative link."""
    from lidarfuzz.report.charts import figure_png

    images = DOCS / "images"
    images.mkdir(parents=True, exist_ok=True)
    (images / f"{name}.png").write_bytes(figure_png(fig))
    return f"images/{name}.png"


def fig5(args: argparse.Namespace) -> None:
    """DeepTest's Figure 5: per seed, NC of the seed alone and with one operator's mutants added."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    start = time.perf_counter()
    frames = ensure_data()[: args.frames]
    _, evaluator, _ = setup()
    rows = mutants(evaluator, frames, SEVERITIES)
    masks: dict[tuple[str, str], list[np.ndarray]] = {}
    failed = 0
    for row in rows:
        if row["evaluation"].values:
            masks.setdefault((row["frame"], row["operator"]), []).append(nc_mask(row["evaluation"].values))
        else:
            failed += 1
    seeds = {f: nc_mask(evaluator.original(f).values) for f in frames}
    gains: dict[str, list[tuple[int, int, float]]] = {}
    for name in OPERATORS:
        gains[name] = [coverage_gain(seeds[f], masks.get((f, name), [])) for f in frames]
    every = "all operators"
    gains[every] = [coverage_gain(seeds[f], [m for n in OPERATORS for m in masks.get((f, n), [])]) for f in frames]
    neurons = next(iter(seeds.values())).size
    table = ["| operator | seeds | median N_O | median N_T − N_O (neurons) | median increase (N_T − N_O) / N_O "
             "| quartiles | seeds with a gain |", "|---|---:|---:|---:|---:|---:|---:|"]
    for name, values in gains.items():
        n_o = np.array([v[0] for v in values])
        new = np.array([v[1] - v[0] for v in values])
        rel = 100 * np.array([v[2] for v in values])
        q1, q3 = np.nanpercentile(rel, [25, 75])
        table.append(f"| {name} | {len(values)} | {np.median(n_o):.0f} | {np.median(new):.0f} | "
                     f"**{np.nanmedian(rel):.2f} %** | {q1:.2f}–{q3:.2f} % | {int((new > 0).sum())} |")
    fig, ax = plt.subplots(figsize=(10, 4.2))
    labels = list(gains)
    data = [100 * np.array([v[2] for v in gains[n]]) for n in labels]
    ax.boxplot(data, showfliers=False)
    for i, values in enumerate(data, start=1):
        jitter = np.random.default_rng(i).uniform(-0.15, 0.15, len(values))
        ax.plot(i + jitter, values, "o", ms=3, alpha=0.6, color="tab:blue")
    ax.set_xticks(range(1, len(labels) + 1), [n.replace("_", "\n") for n in labels], fontsize=7)
    ax.set_ylabel("NC increase per seed, (N_T − N_O) / N_O (%)")
    ax.set_title(f"Neuron coverage per seed with each operator's mutants (severities 1–5) w.r.t. the seed alone; "
                 f"{len(frames)} seeds", fontsize=9)
    ax.grid(axis="y", alpha=0.3)
    fig.tight_layout()
    link = save_chart(fig, "fig5")
    plt.close(fig)
    body = f"""
DeepTest's Figure 5 (neuron coverage per seed image for individual transformations w.r.t. the baseline): for
each of {len(frames)} val frames (seeds), N_O = the neurons the seed alone activates (NC, t = 0.2, per-input
per-layer min-max scaling, {neurons} watched neurons of `pillars`) and, for each operator, N_T = the neurons
activated by the seed or by any of that operator's mutants of it at severities {', '.join(map(str, SEVERITIES))}
(one mutant per severity, seeded as the other questions; {len(rows)} mutants, {failed} without activations).
The increase per seed is DeepTest's (N_T − N_O) / N_O; the last row pools every operator's mutants of the seed.

![NC increase per seed and operator]({link})

{chr(10).join(table)}

Reading: DeepTest's Figure 5 reports, for each model and transformation, a seed's coverage with its
transformed images over the seed's alone. N_T cannot fall below N_O (it is a union with the seed), so the
question is how much each operator adds: here {sum(np.nanmedian([v[2] for v in gains[n]]) > 0 for n in OPERATORS)}
of {len(OPERATORS)} operators have a positive median increase, the largest
{max(OPERATORS, key=lambda n: np.nanmedian([v[2] for v in gains[n]])).replace('_', ' ')}'s, the smallest
{min(OPERATORS, key=lambda n: np.nanmedian([v[2] for v in gains[n]])).replace('_', ' ')}'s. The room is small:
one seed alone already activates a median {100 * np.median([v[0] for v in gains[every]]) / neurons:.0f} % of the
watched neurons (per-input min-max scaling puts most of each layer above t = 0.2, see RQ1), so for such a seed no
operator can add more than the remaining {100 - 100 * np.median([v[0] for v in gains[every]]) / neurons:.0f} %.
"""
    write("fig5", "Figure 5: neuron coverage per seed for individual operators w.r.t. the seed", body,
          f"python experiments/deeptest_rq.py fig5 --frames {args.frames}", time.perf_counter() - start)


def image_mse(stats: dict[str, Any], key: str) -> float:
    """One image's deviation from its labels: the mean of a ``deeptest_tolerance`` outcome's per-object
    squared centre errors under ``key`` (``squared_errors``: the mutant's, ``source_squared_errors``:
    its original's); NaN when no labelled object was found.

    Example:
        >>> image_mse({"squared_errors": [0.5, 1.5], "source_squared_errors": []}, "squared_errors")
        1.0
    """
    errors = np.asarray(stats.get(key, []), dtype=np.float64)
    return float(errors.mean()) if errors.size else float("nan")


def fig6(args: argparse.Namespace) -> None:
    """DeepTest's Figure 6: deviation from the labels of the mutants violating Eq. 2 vs their originals."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from scipy.stats import wilcoxon

    from lidarfuzz.oracles.relations.registry import from_spec

    start = time.perf_counter()
    frames = ensure_data()[: args.frames]
    _, evaluator, _ = setup()
    plain = from_spec("deeptest_tolerance")
    mse_orig, objects = plain.mse_orig_of((evaluator.original(f).scene.boxes, evaluator.original(f).output)
                                          for f in frames)
    relation = from_spec({"name": "deeptest_tolerance", "config": {"mse_orig": mse_orig}})
    evaluator.relations = [relation]
    rows = mutants(evaluator, frames, SEVERITIES)
    checked: list[tuple[dict[str, Any], dict[str, Any]]] = []
    for row in rows:
        for outcome in row["evaluation"].relations:
            if outcome.relation == relation.name and outcome.applicable:
                checked.append((row, {"holds": outcome.holds, **outcome.stats}))
    invalid = sum(1 for r in rows if not r["evaluation"].valid)
    errs = [(row, stats) for row, stats in checked if not stats["holds"]]
    err_mse = np.array([image_mse(s, "squared_errors") for _, s in errs])
    orig_mse = np.array([image_mse(s, "source_squared_errors") for _, s in errs])
    paired = np.isfinite(err_mse) & np.isfinite(orig_mse)
    x, y = err_mse[paired], orig_mse[paired]
    pooled_err = np.concatenate([s["squared_errors"] for _, s in errs]) if errs else np.zeros(0)
    pooled_orig = np.concatenate([s["source_squared_errors"] for _, s in errs]) if errs else np.zeros(0)
    pooled_all = np.concatenate([s["squared_errors"] for _, s in checked]) if checked else np.zeros(0)
    stat, p = wilcoxon(x, y) if x.size and np.any(x != y) else (float("nan"), float("nan"))
    r = matched_pairs_rank_biserial(x, y)
    limit = relation.config.lambda_ * mse_orig
    # an I_err whose original frame has an object over the same limit: the violation came with the seed
    inherited = np.array([max(s["source_squared_errors"], default=0.0) > limit for _, s in errs], dtype=bool)
    seeds_over = sorted({row["frame"] for row, s in checked if max(s["source_squared_errors"], default=0.0) > limit})
    distinct = len({row["frame"] for row, _ in errs})
    fresh_err = [v for (_, s), k in zip(errs, inherited, strict=True) if not k for v in s["squared_errors"]]
    fresh_orig = [v for (_, s), k in zip(errs, inherited, strict=True) if not k for v in s["source_squared_errors"]]
    per_op = ["| operator | mutants checked (valid) | I_err (violate Eq. 2) | median per-image MSE, I_err | "
              "of their I_orig |", "|---|---:|---:|---:|---:|"]
    for name in OPERATORS:
        n_checked = sum(1 for row, _ in checked if row["operator"] == name)
        sel = np.array([row["operator"] == name for row, _ in errs], dtype=bool)
        cells = (f"{np.nanmedian(err_mse[sel]):.3f} | {np.nanmedian(orig_mse[sel]):.3f}" if sel.any()
                 and np.isfinite(orig_mse[sel]).any() else "— | —")
        per_op.append(f"| {name} | {n_checked} | {int(sel.sum())} | {cells} |")
    fig, ax = plt.subplots(figsize=(6, 4.2))
    ax.boxplot([y, x], showfliers=False)
    for i, values in enumerate((y, x), start=1):
        jitter = np.random.default_rng(i).uniform(-0.12, 0.12, len(values))
        ax.plot(i + jitter, values, "o", ms=3, alpha=0.5, color="tab:blue" if i == 1 else "tab:red")
    ax.set_xticks([1, 2], [f"I_orig (originals)\nn = {len(y)}", f"I_err (violating mutants)\nn = {len(x)}"])
    ax.set_yscale("log")
    ax.axhline(relation.config.lambda_ * mse_orig, color="grey", ls="--", lw=1,
               label=f"λ · MSE_orig = {relation.config.lambda_:g} × {mse_orig:.3f} m²")
    ax.set_ylabel("per-image MSE of the box centres vs the labels (m²)")
    ax.legend(fontsize=8)
    ax.set_title("Deviation from the ground-truth labels, I_err vs I_orig", fontsize=9)
    fig.tight_layout()
    link = save_chart(fig, "fig6")
    plt.close(fig)
    ratio = pooled_err.mean() / pooled_orig.mean() if pooled_err.size and pooled_orig.size else float("nan")
    body = f"""
DeepTest's Figure 6: the transformed inputs whose outputs violate its relaxed relation (Eq. 2), I_err, deviate
from the human labels more than their originals I_orig. Here the labels are the ground-truth boxes and the
relation is lidarfuzz's `deeptest_tolerance` (`src/lidarfuzz/oracles/relations/detection.py`): each labelled
object that the detections match has a squared centre error (m²); an object lost altogether is left out
(that is `gt_recall`'s business); a mutant violates Eq. 2 when one of its objects' squared error exceeds
λ · MSE_orig, with λ = {relation.config.lambda_:g} (the relation's default, the paper's λ of Table 7's example)
and MSE_orig = {mse_orig:.4f} m², the mean squared centre error of `pillars` over the {objects} objects it
found on the {len(frames)} original frames (`DeepTestTolerance.mse_orig_of`, as a campaign computes it).

Scale: {len(frames)} val frames × {len(OPERATORS)} operators × severities {', '.join(map(str, SEVERITIES))} =
{len(rows)} mutants; {invalid} were invalid (an object kept less than half its points: the search's validity
constraint, whose premise is that the labels still hold), so {len(checked)} were judged, and
**{len(errs)} violate Eq. 2 (I_err)**. An image's deviation is the mean of its objects' squared errors (the
I_err mutant's and its original's own, each over the objects it found); {int((~paired).sum())} I_err had
no found object on the original and drop out of the paired test.

![I_err vs I_orig]({link})

| | I_orig | I_err |
|---|---:|---:|
| MSE over every found object (m²) | **{pooled_orig.mean() if pooled_orig.size else float('nan'):.4f}** \
({pooled_orig.size} objects) | **{pooled_err.mean() if pooled_err.size else float('nan'):.4f}** \
({pooled_err.size} objects) |
| median per-image MSE (m²) | {np.median(y) if y.size else float('nan'):.4f} | \
{np.median(x) if x.size else float('nan'):.4f} |

For comparison, every judged mutant together (violating or not): MSE {pooled_all.mean() if pooled_all.size
else float('nan'):.4f} m² over {pooled_all.size} objects.

**Wilcoxon signed-rank test** (scipy, two-sided, paired per image, n = {x.size}): W = {stat}, p = {p:.3g};
effect size: matched-pairs rank-biserial correlation r = {r:+.3f} (+1: every I_err deviates more than its
original; |r| < 0.1 negligible, < 0.3 small, < 0.5 medium, else large).

{chr(10).join(per_op)}

Where the I_err come from: they are mutants of {distinct} of the {len(frames)} seed frames, and
**{int(inherited.sum())} of the {len(errs)} are mutants of a seed whose original output already has an object over
λ · MSE_orig** (the seeds {', '.join(seeds_over) or 'none'}; DeepTest's relation flags every object over the
limit, also one the transformation did not put there: the relation's `new_only` option would not). The
other {int((~inherited).sum())} I_err have an object that the transformation pushed over the limit: MSE
{np.mean(fresh_err) if fresh_err else float('nan'):.4f} m² ({len(fresh_err)} objects) against their originals'
{np.mean(fresh_orig) if fresh_orig else float('nan'):.4f} m² ({len(fresh_orig)} objects).

**Against the paper.** DeepTest reports MSE 0.41 for I_err against 0.035 for the corresponding I_orig
(×{0.41 / 0.035:.1f}; steering angles of Udacity images, the difference significant by Wilcoxon). Here I_err's
MSE is {ratio:.2f} × its I_orig's ({pooled_err.mean() if pooled_err.size else float('nan'):.4f} vs
{pooled_orig.mean() if pooled_orig.size else float('nan'):.4f} m²), and I_orig's is itself
{pooled_orig.mean() / mse_orig if pooled_orig.size else float('nan'):.1f} × MSE_orig: the violating mutants
here mostly repeat their seed's own large error, slightly changed, rather than create one. The signed-rank
test finds I_err's per-image deviation consistently above its original's (the direction of the paper), but the
difference is small, not the paper's order of magnitude. Two caveats on that test: the {x.size} pairs share
{distinct} originals, so they are not independent and the p-value overstates the evidence; and an I_err is
selected *because* an object of it exceeds the limit, which biases its deviation upwards (as in the paper).
The scales do not compare (m² of a box centre against squared radians of a steering angle), nor does the
scale of the experiment ({len(frames)} seeds here, DeepTest's test sets of thousands of images).
"""
    write("fig6", "Figure 6: deviation from the labels, mutants violating DeepTest's relation vs their originals",
          body, f"python experiments/deeptest_rq.py fig6 --frames {args.frames}", time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("question", choices=["rq1", "rq2", "rq3", "rq4", "rq4-review", "fig5", "fig6"])
    parser.add_argument("--frames", type=int, default=10, help="val frames used as seeds (rq1-rq3, fig5, fig6)")
    parser.add_argument("--sample", type=int, default=12, help="findings drawn for the manual look (rq4-review)")
    parser.add_argument("--seed", type=int, default=0, help="seed of that sample")
    args = parser.parse_args()
    {"rq1": rq1, "rq2": rq2, "rq3": rq3, "rq4": rq4, "rq4-review": rq4_review, "fig5": fig5,
     "fig6": fig6}[args.question](args)


if __name__ == "__main__":
    sys.exit(main())
