"""DeepTest's experiments (Tian et al., ICSE 2018) on the camera modality: the built-in world's images
and the three built-in steering networks, one command per table or figure of the paper::

    .venv/bin/python experiments/deeptest_camera.py table5   # RQ1: coverage vs steering angle and direction
    .venv/bin/python experiments/deeptest_camera.py fig5     # RQ2: coverage increase per seed and transformation
    .venv/bin/python experiments/deeptest_camera.py table6   # RQ3: cumulative coverage: seeds, transformations, guided
    .venv/bin/python experiments/deeptest_camera.py fig6     # deviation from the label: I_err vs I_orig
    .venv/bin/python experiments/deeptest_camera.py table8   # RQ4: Eq. 2/3 violations per model and transformation
    .venv/bin/python experiments/deeptest_camera.py table9   # RQ5: retraining Epoch with transformed images
    .venv/bin/python experiments/deeptest_camera.py all      # every one in turn

Data: a held-out test world, ``lidarfuzz gen --camera --image-size 320x240 --sensor VLP-16 --frames 200
--seed 2026`` (independent frames: each its own street, the ego vehicle off its lane's centre, so the
labels steer both ways), written to ``bench-out/deeptest-camera/`` on first use. Seed 2026 is none of
the training recipe's (``scripts/train_steering.py``: drive logs and frame sets of seeds 1–4, validation
101–102). Models: ``dave2``, ``epoch``, ``chauffeur`` with their committed weights (a network freshly
seeded with 0 stands in, and the page says so, while none are committed). Each command writes its
section of ``docs/experiments/deeptest_camera.md`` (regenerated in place; text under "Notes by hand"
is kept) and prints it. Everything is seeded; PyTorch runs on one thread.
"""

from __future__ import annotations

import argparse
import csv
import functools
import hashlib
import math
import re
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs" / "experiments"
PAGE = DOCS / "deeptest_camera.md"
IMAGES = DOCS / "images"
DATA = ROOT / "bench-out" / "deeptest-camera"
MODELS = ("chauffeur", "epoch", "dave2")
WORLD_SEED = 2026
WORLD_FRAMES = 200
IMAGE_SIZE = "320x240"
THRESHOLD = 0.2  # DeepTest's neuron-coverage threshold
LAMBDA, EPSILON = 5.0, 0.03  # Table 8's λ and ε
SEVERITIES = (1, 3, 5)  # the camera task's default severities (Table 8's "transformation, parameter")
#: Text after this heading is written by hand and kept when the page is regenerated.
KEPT = "\n## Notes by hand"


# -- statistics (tested in tests/experiments/test_deeptest_camera.py) ------------------------------
def cohens_d(a: Sequence[float] | NDArray[np.float64], b: Sequence[float] | NDArray[np.float64]) -> float:
    """Cohen's d of two samples: (mean a − mean b) / pooled standard deviation, the pooled variance
    ((n_a − 1) s_a² + (n_b − 1) s_b²) / (n_a + n_b − 2) with sample variances (ddof 1); NaN when it
    is undefined (fewer than three values, or both samples constant)."""
    x, y = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    if len(x) < 1 or len(y) < 1 or len(x) + len(y) < 3:
        return math.nan
    var_x = float(x.var(ddof=1)) if len(x) > 1 else 0.0
    var_y = float(y.var(ddof=1)) if len(y) > 1 else 0.0
    pooled = ((len(x) - 1) * var_x + (len(y) - 1) * var_y) / (len(x) + len(y) - 2)
    if pooled <= 0:
        return math.nan
    return float((x.mean() - y.mean()) / math.sqrt(pooled))


def effect_words(d: float) -> str:
    """Cohen's words for |d| as the paper's Table 5 uses them: negligible (< 0.2), small (< 0.5),
    medium (< 0.8), large; "n/a" for NaN."""
    if not math.isfinite(d):
        return "n/a"
    size = abs(d)
    return "negligible" if size < 0.2 else "small" if size < 0.5 else "medium" if size < 0.8 else "large"


def coverage_increase(seed: NDArray[np.bool_], transformed: Sequence[NDArray[np.bool_]]) -> float:
    """(N_T − N_O) / N_O: N_O neurons the seed activates, N_T those the seed and its transformed
    images activate together (DeepTest's RQ2/Figure 5); NaN when the seed activates none."""
    n_o = int(np.count_nonzero(seed))
    union = seed.copy()
    for hits in transformed:
        union |= hits
    return (int(np.count_nonzero(union)) - n_o) / n_o if n_o else math.nan


def improvement(before: float, after: float) -> float:
    """Relative decrease of an error: (before − after) / before (Table 9's improvement)."""
    return (before - after) / before if before > 0 else math.nan


def p_text(p: float) -> str:
    """A p-value with the paper's stars: *** p < 0.001, ** < 0.01, * < 0.05."""
    if not math.isfinite(p):
        return "—"
    stars = "***" if p < 0.001 else "**" if p < 0.01 else "*" if p < 0.05 else ""
    text = f"{p:.2g}" if p > 0 else "< 1e-300"  # below the smallest double scipy returns: 0
    return f"{text}{(' ' + stars) if stars else ''}"


# -- data -------------------------------------------------------------------------------------------
def world_root(seed: int, frames: int, size: str = IMAGE_SIZE) -> Path:
    return DATA / (f"scenes-{seed}-{frames}" + ("" if size == IMAGE_SIZE else f"-{size}"))


def ensure_world(seed: int = WORLD_SEED, frames: int = WORLD_FRAMES, size: str = IMAGE_SIZE,
                 root: Path | None = None) -> Path:
    """The test world (rendered with ``lidarfuzz gen --camera`` unless already complete)."""
    root = root or world_root(seed, frames, size)
    labels = root / "steering.csv"
    if labels.is_file() and len(labels.read_text().splitlines()) == frames + 1:
        return root
    lidarfuzz = Path(sys.executable).with_name("lidarfuzz")
    command = [str(lidarfuzz), "gen", "--camera", "--image-size", size, "--sensor", "VLP-16", "--frames", str(frames),
               "--seed", str(seed), "--workers", "1", "--out", str(root), "--overwrite"]
    print(f"rendering the test world: {' '.join(command[1:])}", flush=True)
    subprocess.run(command, check=True, capture_output=True)
    return root


@dataclass
class World:
    """The test world's images (full resolution) and labels."""

    root: Path
    dataset: Any
    ids: list[str]
    samples: list[Any]
    seed: int = WORLD_SEED

    @property
    def labels(self) -> NDArray[np.float64]:
        return np.array([float(s.steering) for s in self.samples])

    def describe(self) -> str:
        labels = self.labels
        return (f"`{self.root.relative_to(ROOT) if self.root.is_relative_to(ROOT) else self.root}`: "
                f"{len(self.ids)} frames, labels {labels.min():+.3f} … {labels.max():+.3f} rad "
                f"({int((labels > 0).sum())} left, {int((labels < 0).sum())} right)")


def open_world(root: Path, seed: int = WORLD_SEED) -> World:
    from lidarfuzz.io.images import open_image_dataset

    dataset = open_image_dataset(root)
    ids = sorted(dataset.frame_ids())
    return World(root, dataset, ids, [dataset.load(f) for f in ids], seed)


# -- models -----------------------------------------------------------------------------------------
@dataclass
class Model:
    name: str
    sut: Any
    weights: str  # what the page says about them

    @property
    def module(self) -> Any:
        return self.sut.module


def seeded_weights(name: str, seed: int = 0) -> Path:
    """A freshly initialised network (``torch.manual_seed(seed)``) saved as a weights file."""
    from lidarfuzz.suts.steering.builtin import save_network
    from lidarfuzz.suts.steering.networks import NETWORKS
    from lidarfuzz.suts.steering.pytorch import import_torch

    torch = import_torch()
    torch.manual_seed(seed)
    return save_network(NETWORKS[name](), name, DATA / "seeded" / f"{name}-{seed}.pt", {"seeded": seed})


def load_model(name: str, weights: Path | None = None) -> Model:
    """A built-in network with the committed weights (or ``weights``); a seeded, untrained one when
    no weights are committed yet (said in the page)."""
    from lidarfuzz.suts.steering.builtin import BUILTINS, WEIGHTS_DIR

    committed = WEIGHTS_DIR / f"{name}.pt"
    path = weights or committed
    if path.exists():
        digest = hashlib.sha256(path.read_bytes()).hexdigest()[:12]
        same = committed.exists() and hashlib.sha256(committed.read_bytes()).hexdigest()[:12] == digest
        where = (committed if same else path).resolve()
        text = f"`{where.relative_to(ROOT) if where.is_relative_to(ROOT) else where}` (sha256 {digest})"
    else:
        path = seeded_weights(name)
        text = "**untrained** (seeded 0; no committed weights yet)"
    sut = BUILTINS[name](weights=str(path), threads=1)
    sut.load()
    return Model(name, sut, text)


def weights_of(args: argparse.Namespace, name: str) -> Path | None:
    """``--weights-dir``'s file for ``name``, or None (the committed weights)."""
    return Path(args.weights_dir) / f"{name}.pt" if args.weights_dir else None


def set_threads() -> None:
    from lidarfuzz.suts.steering.pytorch import import_torch

    import_torch().set_num_threads(1)


def run_images(model: Model, samples: Sequence[Any], chunk: int = 64) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Per image: the predicted angle and the neurons it activates (NC at :data:`THRESHOLD`,
    layer-scaled as :class:`lidarfuzz.coverage.NeuronCoverage` defines it); one forward pass."""
    from lidarfuzz.coverage import ActivationRecorder, NeuronCoverage, check_values
    from lidarfuzz.suts.steering.pytorch import import_torch

    torch = import_torch()
    criterion = NeuronCoverage(THRESHOLD)
    angles, hits = [], []
    for start in range(0, len(samples), chunk):
        batch = model.sut.inputs(samples[start:start + chunk])
        recorder = ActivationRecorder(model.module)
        with torch.inference_mode(), recorder:
            out = model.module(batch)
        angles.append(out.double().numpy().reshape(-1))
        hits.append(criterion.hits(check_values(recorder.values())))
    return np.concatenate(angles), np.concatenate(hits)


# -- transformations --------------------------------------------------------------------------------
def table4() -> dict[str, list[tuple[str, dict[str, Any]]]]:
    """The seven simple transformations at Table 4's ten parameters each: {name: [(label, config)]}."""
    from lidarfuzz.operators.camera.affine import ROTATIONS, SCALES, SHEARS, TRANSLATIONS
    from lidarfuzz.operators.camera.convolutional import FILTERS_BY_STRENGTH
    from lidarfuzz.operators.camera.photometric import BRIGHTNESS_BIASES, CONTRAST_GAINS

    def one(values: list[float], key: str, fmt: str) -> list[tuple[str, dict[str, Any]]]:
        return [(fmt.format(v), {key: (v, v)}) for v in values]

    return {
        "image_blur": [(f, {"filters": (f,)}) for f in FILTERS_BY_STRENGTH],
        "image_brightness": one(BRIGHTNESS_BIASES, "bias_range", "β={:g}"),
        "image_contrast": one(CONTRAST_GAINS, "gain_range", "α={:g}"),
        "image_scale": one(SCALES, "factor_range", "s={:g}"),
        "image_shear": one(SHEARS, "sx_range", "sx={:g}"),
        "image_rotation": one(ROTATIONS, "angle_range", "q={:g}°"),
        "image_translation": one(TRANSLATIONS, "tx_range", "t={:g}"),
    }


def short(name: str) -> str:
    return name.removeprefix("image_")


def transform(name: str, config: dict[str, Any] | None, severity: int | None, sample: Any,
              rng: np.random.Generator) -> tuple[Any, dict[str, Any]]:
    """One transformed image and its parameters (an explicit config, or a severity)."""
    from lidarfuzz.operators.registry import get

    cls = get(name)
    operator = cls(**config) if config is not None else cls.at_severity(int(severity or 1))
    params = operator.sample(rng, sample)
    return operator.apply(sample, params), params.model_dump(mode="json")


def rng_for(*keys: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence([int(k) for k in keys]))


# -- the page ---------------------------------------------------------------------------------------
COMMANDS = ("table5", "fig5", "table6", "fig6", "table8", "table9")
HEADER = """# DeepTest's experiments on the camera modality

Tian et al. (ICSE 2018) on the built-in world's camera images and the three built-in steering networks
(`chauffeur`, `epoch`, `dave2`; `lidarfuzz.suts.steering`). One command per table or figure regenerates
its section: `.venv/bin/python experiments/deeptest_camera.py COMMAND` (`all` runs every one). Each section
states its data, seeds, weights and how long it took on the shared 2-core CPU machine (PyTorch on one thread).
Results are reported as they came out.
"""


def write_section(name: str, title: str, body: str, command: str, seconds: float, page: Path | None = None) -> str:
    """Replace (or add) ``name``'s section of the page (default :data:`PAGE`), keep the others and the
    hand-written notes."""
    page = page or PAGE
    start, end = f"<!-- {name} -->", f"<!-- /{name} -->"
    section = (f"{start}\n## {title}\n\nRegenerate: `{command}` ({seconds:.0f} s).\n\n{body.strip()}\n{end}")
    old = page.read_text() if page.exists() else ""
    kept = old[old.index(KEPT):] if KEPT in old else ""
    sections = {m.group(1): m.group(0) for m in re.finditer(r"<!-- (\w+) -->.*?<!-- /\1 -->", old, flags=re.S)}
    sections[name] = section
    order = [c for c in COMMANDS if c in sections] + [c for c in sections if c not in COMMANDS]
    text = HEADER + "\n" + "\n\n".join(sections[c] for c in order) + "\n" + kept
    page.parent.mkdir(parents=True, exist_ok=True)
    page.write_text(text)
    print(section, flush=True)
    return section


def data_line(world: World, models: Sequence[Model]) -> str:
    weights = "; ".join(f"{m.name} {m.weights}" for m in models)
    return f"Data: {world.describe()} (`lidarfuzz gen --camera`, seed {world.seed}). Weights: {weights}."


def table(header: Sequence[str], rows: Sequence[Sequence[Any]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(lines)


# -- RQ1: Table 5 -----------------------------------------------------------------------------------
def rq1_rows(angles: NDArray[np.float64], nc: NDArray[np.float64]) -> dict[str, Any]:
    """Spearman ρ of NC and angle; Mann–Whitney (Wilcoxon rank-sum) of NC, left (θ > 0) vs right
    (θ < 0) answers, with Cohen's d (left − right)."""
    from scipy.stats import mannwhitneyu, spearmanr

    out: dict[str, Any] = {"n": len(angles)}
    if np.ptp(nc) > 0 and np.ptp(angles) > 0:
        rho, p = spearmanr(nc, angles)
        out.update(rho=float(rho), p_rho=float(p))
    else:
        out.update(rho=math.nan, p_rho=math.nan)
    left, right = nc[angles > 0], nc[angles < 0]
    out.update(left=len(left), right=len(right), nc_left=float(np.mean(left)) if len(left) else math.nan,
               nc_right=float(np.mean(right)) if len(right) else math.nan)
    if len(left) and len(right):
        out["p_w"] = float(mannwhitneyu(left, right, alternative="two-sided").pvalue)
        out["d"] = cohens_d(left, right)
    else:
        out.update(p_w=math.nan, d=math.nan)
    return out


def table5(args: argparse.Namespace) -> str:
    start = time.perf_counter()
    world = open_world(ensure_world(args.seed, args.frames, args.image_size), args.seed)
    models = [load_model(m, weights_of(args, m)) for m in args.models]
    rows = []
    for model in models:
        angles, hits = run_images(model, world.samples)
        r = rq1_rows(angles, hits.mean(axis=1))
        order = "left > right" if r["nc_left"] > r["nc_right"] else "left < right"
        direction = f"{order} ({p_text(r['p_w'])})" if math.isfinite(r["p_w"]) else "—"
        rows.append([model.name, r["n"], f"{r['rho']:+.2f} ({p_text(r['p_rho'])})", f"{r['left']} / {r['right']}",
                     f"{r['nc_left']:.3f} / {r['nc_right']:.3f}", direction,
                     f"{r['d']:+.2f} {effect_words(r['d'])}"])
    body = f"""
RQ1: does neuron coverage vary with the output? Per original image of the test world, NC at threshold
{THRESHOLD} (DeepTest's Eq. 1: a neuron — a dense unit, or a convolution channel's mean — is activated when its
value, min–max scaled over its layer for that image, is above {THRESHOLD}; `lidarfuzz.coverage.NeuronCoverage` on
every ReLU the network's `coverage_layers()` names) against the model's own predicted angle θ (left positive).
Spearman rank correlation of NC and θ; NC of left-steering (θ > 0) vs right-steering (θ < 0) images by the
Wilcoxon rank-sum (Mann–Whitney, two-sided) test with Cohen's d (left − right; |d| < 0.2 negligible, < 0.5
small, < 0.8 medium, else large). `scipy.stats.spearmanr` / `mannwhitneyu`. *** p < 0.001, ** < 0.01, * < 0.05.

{data_line(world, models)}

{table(["model", "images", "Spearman ρ (NC, θ)", "left / right", "mean NC left / right",
        "Wilcoxon rank-sum", "Cohen's d"], rows)}
"""
    return write_section("table5", "Table 5 (RQ1): neuron coverage vs steering angle and direction", body,
                         command(args), time.perf_counter() - start)


# -- RQ2: Figure 5 ----------------------------------------------------------------------------------
def seed_ids(world: World, count: int, seed: int) -> list[int]:
    """``count`` seed images drawn from the world (seeded), in frame order."""
    order = np.random.default_rng(seed).permutation(len(world.ids))[:count]
    return sorted(int(i) for i in order)


def simple_transformations(world: World, seeds: Sequence[int], seed: int) -> list[tuple[int, str, str, Any]]:
    """(seed index, transformation, parameter label, image) for the seven simple transformations at
    Table 4's ten parameters on each seed image."""
    out = []
    for t_index, (name, settings) in enumerate(table4().items()):
        for p_index, (label, config) in enumerate(settings):
            for s in seeds:
                image, _ = transform(name, config, None, world.samples[s], rng_for(seed, s, t_index, p_index))
                out.append((s, name, label, image))
    return out


def fig5(args: argparse.Namespace) -> str:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from scipy.stats import wilcoxon

    start = time.perf_counter()
    world = open_world(ensure_world(args.seed, args.frames, args.image_size), args.seed)
    models = [load_model(m, weights_of(args, m)) for m in args.models]
    seeds = seed_ids(world, args.seeds, args.run_seed)
    tests = simple_transformations(world, seeds, args.run_seed)
    names = list(table4())
    increases: dict[str, dict[str, list[float]]] = {}
    for model in models:
        _, seed_hits = run_images(model, [world.samples[s] for s in seeds])
        _, hits = run_images(model, [t[3] for t in tests])
        per = {}
        for name in names:
            values = []
            for k, s in enumerate(seeds):
                rows = [hits[i] for i, t in enumerate(tests) if t[0] == s and t[1] == name]
                values.append(coverage_increase(seed_hits[k], rows))
            per[name] = values
        per["all seven"] = [coverage_increase(seed_hits[k], [hits[i] for i, t in enumerate(tests) if t[0] == s])
                            for k, s in enumerate(seeds)]
        increases[model.name] = per
    figure, axes = plt.subplots(1, len(models), figsize=(4.2 * len(models), 3.6), sharey=True, squeeze=False)
    for axis, model in zip(axes[0], models, strict=True):
        data = [np.asarray(increases[model.name][n]) * 100 for n in names]
        axis.boxplot([d[np.isfinite(d)] for d in data], showfliers=True)
        axis.set_xticks(range(1, len(names) + 1), [short(n) for n in names], rotation=45, ha="right", fontsize=8)
        axis.set_title(model.name)
        axis.grid(axis="y", alpha=0.3)
    axes[0][0].set_ylabel("NC increase over the seed image (%)")
    figure.suptitle(f"Neuron coverage per seed image, each transformation's 10 images w.r.t. the seed "
                    f"({len(seeds)} seeds)", fontsize=9)
    figure.tight_layout()
    IMAGES.mkdir(parents=True, exist_ok=True)
    png = IMAGES / "deeptest_camera_fig5.png"
    figure.savefig(png, dpi=110)
    plt.close(figure)
    rows = []
    for name in [*names, "all seven"]:
        cells = [short(name)]
        for model in models:
            v = np.asarray(increases[model.name][name], dtype=np.float64)
            v = v[np.isfinite(v)]
            p = float(wilcoxon(v, alternative="greater").pvalue) if np.any(v != 0) else math.nan
            cells.append(f"{100 * v.mean():.1f} % (median {100 * np.median(v):.1f}; p {p_text(p)})")
        rows.append(cells)
    body = f"""
RQ2 / Figure 5: per seed image and transformation, N_O = neurons the seed activates (NC, threshold {THRESHOLD}),
N_T = neurons the seed and the transformation's ten images (Table 4's ten parameters, each an explicit config:
translation t = tx = ty 10 … 100 px, scale 1.5 … 6, shear sx −0.1 … −1.0, rotation 3 … 30°, contrast α 1.2 … 3.0,
brightness β 10 … 100, blur the ten filters) activate together; the increase is (N_T − N_O) / N_O. Mean over the
seeds (median; one-sided Wilcoxon signed-rank p that the increase is above 0, `scipy.stats.wilcoxon`).
"all seven": the seed with all 70 of its images.

{data_line(world, models)} Seeds: {len(seeds)} images drawn with seed {args.run_seed}
(frames {', '.join(world.ids[s] for s in seeds)}); {len(tests)} transformed images per model (every setting is one
fixed value, so nothing is drawn).

{table(["transformation", *[m.name for m in models]], rows)}

![Figure 5]({png.relative_to(DOCS)})
"""
    return write_section("fig5", "Figure 5 (RQ2): neuron coverage increase per seed image and transformation", body,
                         command(args), time.perf_counter() - start)


# -- RQ3: Table 6 -----------------------------------------------------------------------------------
@dataclass
class GuidedRun:
    """What one guided search (Algorithm 1) produced."""

    covered: int
    total: int
    tests: int
    accepted: int
    violations: list[dict[str, Any]] = field(default_factory=list)


def guided(model: Model, world: World, seeds: Sequence[int], mse_orig: float, budget: int, seed: int) -> GuidedRun:
    """Algorithm 1 (``ImageGuidedSearch``, NC at :data:`THRESHOLD` as the guide, the seven simple
    transformations) from ``seeds`` for ``budget`` tests; each test judged by Eq. 2 (λ = 5, unfiltered)."""
    from lidarfuzz.campaign.camera import CameraSearch
    from lidarfuzz.coverage import ActivationRecorder, make_criteria
    from lidarfuzz.oracles.relations.steering import DeepTestSteering
    from lidarfuzz.search.images import ImageGuidedSearch, ImageSearchEvaluator

    config = CameraSearch.model_validate({"budget": budget, "criteria": [f"nc:{THRESHOLD}"],
                                          "guide": "nc"}).search_config()
    criteria = make_criteria(list(config.criteria))
    evaluator = ImageSearchEvaluator(world.dataset, model.sut, [DeepTestSteering(lambda_=LAMBDA, epsilon=EPSILON)],
                                     ActivationRecorder(model.module), mse_orig=mse_orig)
    search = ImageGuidedSearch(config, [world.ids[s] for s in seeds], criteria, seed)
    tests = accepted = 0
    violations = []
    while not search.finished:
        records = search.step(evaluator)
        if not records and search.finished:
            break
        for record in records:
            if record.role == "seed":
                continue
            tests += 1
            accepted += int(record.accepted)
            e = record.evaluation
            for outcome in e.relations:
                if outcome.applicable and not outcome.holds:
                    violations.append({"frame": e.frame_id, "chain": [s.name for s in e.chain],
                                       "prediction": float(e.output.steering), **outcome.stats})
    nc = criteria[0]
    return GuidedRun(int(nc.covered()), int(nc.total), tests, accepted, violations)


def mse_of(angles: NDArray[np.float64], labels: NDArray[np.float64]) -> float:
    return float(np.mean((angles - labels) ** 2))


def table6(args: argparse.Namespace) -> str:
    start = time.perf_counter()
    world = open_world(ensure_world(args.seed, args.frames, args.image_size), args.seed)
    models = [load_model(m, weights_of(args, m)) for m in args.models]
    seeds = seed_ids(world, args.seeds, args.run_seed)
    tests = simple_transformations(world, seeds, args.run_seed)
    rows = []
    for model in models:
        angles, all_hits = run_images(model, world.samples)
        mse_orig = mse_of(angles, world.labels)
        seed_hits = all_hits[seeds]
        _, hits = run_images(model, [t[3] for t in tests])
        total = seed_hits.shape[1]
        base = int(seed_hits.any(axis=0).sum())
        cumulative = int((seed_hits.any(axis=0) | hits.any(axis=0)).sum())
        run = guided(model, world, seeds, mse_orig, args.budget or len(tests), args.run_seed)
        assert run.total == total, (run.total, total)

        def pct(n: int, total: int = total) -> str:
            return f"{n:,} ({100 * n / total:.0f} %)"

        rows.append([model.name, total, pct(base), pct(cumulative), f"{pct(run.covered)}, {run.tests} tests",
                     f"{100 * (run.covered - base) / base:+.0f} %" if base else "—",
                     f"{100 * (run.covered - cumulative) / cumulative:+.0f} %" if cumulative else "—"])
    body = f"""
RQ3 / Table 6: cumulative neuron coverage (NC, threshold {THRESHOLD}: neurons activated by at least one image) of
the seed images alone (baseline), of the seeds with all their single transformations (seven transformations ×
Table 4's ten parameters: {len(tests)} images), and of DeepTest's Algorithm 1 (`ImageGuidedSearch`: a stack of
the seed images, two random transformations per try among the seven, each at a random severity up to the
strongest it is meant to be harmless at, a test kept when it raises NC, at most 5 failed tries per image and 6
transformations per chain) with a budget of the same {args.budget or len(tests)} tests, seeded {args.run_seed}
(the same seed gives the same tests). The search stops early when its stack runs dry; the tests it ran are
given.

{data_line(world, models)} Seeds: {len(seeds)} images drawn with seed {args.run_seed}.

{table(["model", "neurons", "baseline (seeds)", "cumulative transformations", "guided generation",
        "guided vs baseline", "guided vs cumulative"], rows)}
"""
    return write_section("table6", "Table 6 (RQ3): cumulative coverage: seeds, single transformations, guided "
                         "search", body, command(args), time.perf_counter() - start)


# -- RQ4: violations (Table 8, Figure 6) ------------------------------------------------------------
ALL_TRANSFORMATIONS = ("image_blur", "image_brightness", "image_contrast", "image_rotation", "image_scale",
                       "image_shear", "image_translation", "image_rain", "image_fog")


@dataclass
class Judged:
    """One model's Eq. 2 / Eq. 3 results on the world: per (transformation, severity) its MSE, whether
    Eq. 3 keeps it, and every transformed image's prediction and verdict."""

    mse_orig: float
    angles: NDArray[np.float64]  # on the originals
    settings: dict[tuple[str, int], dict[str, Any]]


JUDGED: dict[tuple[Any, ...], Judged] = {}


def judge(model: Model, world: World, severities: Sequence[int], seed: int) -> Judged:
    """Every transformation at every severity on every frame (one trial, seeded), judged by Eq. 2
    (``deeptest_steering``, λ = 5 against the data set's MSE_orig) and Eq. 3 (ε = 0.03; fog and rain
    unfiltered, as the paper's composite transformations)."""
    from lidarfuzz.campaign.camera import UNFILTERED
    from lidarfuzz.operators.registry import get
    from lidarfuzz.oracles.deeptest import keeps
    from lidarfuzz.oracles.relations.base import Pair
    from lidarfuzz.oracles.relations.steering import DeepTestSteering
    from lidarfuzz.suts.steering.base import Steering

    key = (model.name, model.weights, str(world.root), tuple(severities), seed)
    if key in JUDGED:  # `all` runs fig6, table8 and table9 on the same judgements
        return JUDGED[key]
    relation = DeepTestSteering(lambda_=LAMBDA, epsilon=EPSILON)
    angles, _ = run_images(model, world.samples)
    labels = world.labels
    mse_orig = mse_of(angles, labels)
    settings = {}
    for t_index, name in enumerate(ALL_TRANSFORMATIONS):
        cls = get(name)
        for severity in severities:
            images, params = [], []
            for f_index, sample in enumerate(world.samples):
                image, p = transform(name, None, severity, sample, rng_for(seed, f_index, t_index, severity))
                images.append(image)
                params.append(p)
            predicted, _ = run_images(model, images)
            mse = mse_of(predicted, labels)
            reference = {"mse_orig": mse_orig, "filtered": 0.0 if name in UNFILTERED else 1.0}
            holds = []
            for f_index, sample in enumerate(world.samples):
                pair = Pair(sample, images[f_index], Steering(float(angles[f_index])),
                            Steering(float(predicted[f_index])), operator_relation=cls.relation,
                            reference=reference, basis=cls.harmless_because)
                holds.append(relation(pair).holds)
            kept = name in UNFILTERED or keeps(mse, mse_orig, EPSILON)
            # the images are kept only where something violated (the review and Table 9 read those): memory
            settings[(name, severity)] = {"mse": mse, "kept": kept, "predicted": predicted, "holds": np.array(holds),
                                          "images": None if all(holds) else images, "params": params,
                                          "filtered": name not in UNFILTERED}
    judged = Judged(mse_orig, angles, settings)
    JUDGED[key] = judged
    return judged


TABLE7_EPSILONS = (0.001, 0.003, 0.01, 0.02, 0.03, 0.04, 0.05)


def table7_counts(judged: Judged, labels: NDArray[np.float64],
                  epsilons: Sequence[float] = TABLE7_EPSILONS) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Table 7 for one model: erroneous images per λ = 1 … 10 (rows) and ε (columns), over the settings
    Eq. 3 keeps at that ε (composite ones always), by :func:`lidarfuzz.oracles.deeptest.erroneous_table`;
    and per λ without the filter."""
    from lidarfuzz.oracles.deeptest import erroneous_table, transformation_errors

    transformations = []
    for setting in judged.settings.values():
        errors = (labels - setting["predicted"]) ** 2
        outcomes = [({"mse_orig": judged.mse_orig, "mse_orig_from": "data set", "lambda": LAMBDA, "epsilon": EPSILON,
                      "squared_errors": [float(e)], "filtered": setting["filtered"]}, bool(h))
                    for e, h in zip(errors, setting["holds"], strict=True)]
        found = transformation_errors(outcomes)
        assert found is not None
        transformations.append(found)
    grid = erroneous_table(transformations, epsilons=epsilons)
    return np.array(grid.counts, dtype=np.int64), np.array(grid.unfiltered, dtype=np.int64)


def violations_of(judged: Judged, counted_only: bool) -> list[tuple[str, int, int]]:
    """(transformation, severity, frame index) of every Eq. 2 violation (only kept transformations'
    when ``counted_only``)."""
    out = []
    for (name, severity), s in judged.settings.items():
        if counted_only and not s["kept"]:
            continue
        out += [(name, severity, int(i)) for i in np.flatnonzero(~s["holds"])]
    return out


def review_sample(pool: Sequence[tuple[Any, ...]], count: int, seed: int) -> list[tuple[Any, ...]]:
    """``count`` of ``pool``'s (model, transformation, severity, frame) violations for the manual review:
    shuffled with ``seed``, first one per (model, transformation) so that the sample spreads over both, then
    the rest in the shuffled order; returned in pool order."""
    order = np.random.default_rng(seed).permutation(len(pool)).tolist()
    seen: set[tuple[Any, Any]] = set()
    first = []
    for i in order:
        if (pool[i][0], pool[i][1]) not in seen:
            seen.add((pool[i][0], pool[i][1]))
            first.append(i)
    chosen = (first + [i for i in order if i not in set(first)])[:count]
    return [pool[i] for i in sorted(chosen)]


def table8(args: argparse.Namespace) -> str:
    import cv2

    from lidarfuzz.report.camera import pair_picture, png_bytes

    start = time.perf_counter()
    world = open_world(ensure_world(args.seed, args.frames, args.image_size), args.seed)
    models = [load_model(m, weights_of(args, m)) for m in args.models]
    seeds = seed_ids(world, args.seeds, args.run_seed)
    results = {m.name: judge(m, world, args.severities, args.run_seed) for m in models}
    searches = {m.name: guided(m, world, seeds, results[m.name].mse_orig, args.budget or 100, args.run_seed)
                for m in models}
    rows = []
    for name in ALL_TRANSFORMATIONS:
        cells = [short(name)]
        for model in models:
            r = results[model.name]
            parts = []
            for severity in args.severities:
                s = r.settings[(name, severity)]
                count = int((~s["holds"]).sum())
                parts.append(f"{count}" if s["kept"] else f"({count})")
            cells.append(" / ".join(parts))
        rows.append(cells)
    rows.append(["guided (Algorithm 1)", *[f"{len(searches[m.name].violations)} of {searches[m.name].tests}"
                                           for m in models]])
    rows.append(["**counted** (kept by Eq. 3, composite unfiltered)",
                 *[f"**{len(violations_of(results[m.name], True)) + len(searches[m.name].violations)}**"
                   for m in models]])
    counts = [table7_counts(results[m.name], world.labels) for m in models]
    grid = np.sum([c[0] for c in counts], axis=0)
    unfiltered = np.sum([c[1] for c in counts], axis=0)
    grid_rows = [[f"{k + 1}", *[f"{v:,}" for v in grid[k]], f"{unfiltered[k]:,}"] for k in range(len(grid))]
    mse_rows = [[m.name, f"{results[m.name].mse_orig:.5f}", f"{LAMBDA * results[m.name].mse_orig:.5f}",
                 ", ".join(f"{short(n)} {s}: {results[m.name].settings[(n, s)]['mse']:.4f}"
                           for n in ALL_TRANSFORMATIONS for s in args.severities
                           if not results[m.name].settings[(n, s)]["kept"]) or "none"]
                for m in models]
    # the manual-review sample: violations drawn at random (seeded) over models and transformations
    review = Path(args.review_dir)
    review.mkdir(parents=True, exist_ok=True)
    for stale in [*review.glob("[0-9][0-9]-*.png"), review / "review.csv"]:  # a previous run's sample
        stale.unlink(missing_ok=True)
    pool = [(m.name, *v) for m in models for v in violations_of(results[m.name], False)]
    chosen = review_sample(pool, args.review, args.run_seed)
    lines = []
    for k, (model_name, name, severity, f_index) in enumerate(chosen, start=1):
        r = results[model_name]
        s = r.settings[(name, severity)]
        label = float(world.labels[f_index])
        after = float(s["predicted"][f_index])
        title = (f"{model_name}: {short(name)} severity {severity} on {world.ids[f_index]}; "
                 f"(label - after)^2 = {(label - after) ** 2:.5f} > {LAMBDA:g} x MSE_orig = {LAMBDA * r.mse_orig:.5f}")
        picture = pair_picture(world.samples[f_index].image, s["images"][f_index].image, label=label,
                               before=float(r.angles[f_index]), after=after, title=title)
        file = f"{k:02d}-{model_name}-{short(name)}-s{severity}-{world.ids[f_index]}.png"
        size = (picture.shape[1] // 2, picture.shape[0] // 2)
        half = np.asarray(cv2.resize(picture, size, interpolation=cv2.INTER_AREA), dtype=np.uint8)
        (review / file).write_bytes(png_bytes(half))
        lines.append({"picture": file, "model": model_name, "transformation": name, "severity": severity,
                      "params": s["params"][f_index], "frame": world.ids[f_index], "label": f"{label:.5f}",
                      "original_prediction": f"{r.angles[f_index]:.5f}", "transformed_prediction": f"{after:.5f}",
                      "squared_error": f"{(label - after) ** 2:.5f}", "limit": f"{LAMBDA * r.mse_orig:.5f}",
                      "kept_by_eq3": s["kept"], "verdict (real bug / false positive)": "", "note": ""})
    if lines:
        with (review / "review.csv").open("w", newline="", encoding="utf-8") as handle:
            writer = csv.DictWriter(handle, fieldnames=list(lines[0]))
            writer.writeheader()
            writer.writerows(lines)
    where = review.relative_to(ROOT) if review.is_relative_to(ROOT) else review
    body = f"""
RQ4 / Table 8: erroneous behaviours per model and transformation. Every one of the nine transformations at
severities {', '.join(map(str, args.severities))} (each severity draws its parameter from two of Table 4's ten
values; rain and fog from the operators' own severity ranges) on every image of the test world, one seeded
trial each. An image violates Eq. 2 when (label − θ_t)² > λ · MSE_orig (λ = {LAMBDA:g}, MSE_orig the model's
MSE over the original images; `deeptest_steering`). A transformation at one severity counts only when Eq. 3
keeps it, |MSE_(trans, param) − MSE_orig| ≤ ε = {EPSILON}; rain, fog and the guided search are composite and not
filtered, as in the paper. Cells: violations at severity {' / '.join(map(str, args.severities))}; in brackets
where Eq. 3 drops that setting (not counted). Guided: Algorithm 1 from {len(seeds)} seed images, budget
{args.budget or 100} tests, seed {args.run_seed}, violations of Eq. 2 among its tests.

{data_line(world, models)}

{table(["transformation", *[m.name for m in models]], rows)}

Table 7's form: erroneous images over the three models (single transformations at the three severities, rain
and fog; not the guided search) for λ = 1 … 10 (rows) and ε (columns; the paper's 0.01 … 0.05 and two
smaller ones, since the errors here are front-wheel angles in rad², far below the paper's steering-wheel
ones); "none": no Eq. 3 filter (`lidarfuzz.oracles.deeptest.erroneous_table`).

{table(["λ", *[f"ε = {e:g}" for e in TABLE7_EPSILONS], "none"], grid_rows)}

MSE_orig (rad²), Eq. 2's limit λ · MSE_orig, and the settings Eq. 3 drops with their MSE:

{table(["model", "MSE_orig", "λ · MSE_orig", "dropped by Eq. 3 (MSE_(trans, param))"], mse_rows)}

Manual review: {len(chosen)} of the {len(pool)} violating pairs (all settings, counted or not), drawn with seed
{args.run_seed} (one per model and transformation first, then at random), are written as pictures at half size
(original | transformed; green the label, blue the original's prediction, red the transformed image's) to
`{where}/` with `review.csv` for a human to mark each as real bug or false positive (`verdict` column, empty).
The review is a person's job; the script only prepares it.
"""
    return write_section("table8", "Table 8 (RQ4): erroneous behaviours per model and transformation (λ = 5, "
                         "ε = 0.03)", body, command(args), time.perf_counter() - start)


def fig6(args: argparse.Namespace) -> str:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from scipy.stats import wilcoxon

    start = time.perf_counter()
    world = open_world(ensure_world(args.seed, args.frames, args.image_size), args.seed)
    models = [load_model(m, weights_of(args, m)) for m in args.models]
    labels = world.labels
    rows, boxes, names = [], [], []
    for model in models:
        r = judge(model, world, args.severities, args.run_seed)
        err, orig = [], []
        for name, severity, f_index in violations_of(r, False):
            err.append((labels[f_index] - r.settings[(name, severity)]["predicted"][f_index]) ** 2)
            orig.append((labels[f_index] - r.angles[f_index]) ** 2)
        e, o = np.asarray(err), np.asarray(orig)
        p = float(wilcoxon(e, o, alternative="greater").pvalue) if len(e) and np.any(e != o) else math.nan
        rows.append([model.name, len(e), f"{e.mean():.5f}" if len(e) else "—", f"{o.mean():.5f}" if len(o) else "—",
                     f"{e.mean() / o.mean():.1f}×" if len(e) and o.mean() > 0 else "—", p_text(p)])
        boxes += [e, o]
        names += [f"{model.name}\nI_err", f"{model.name}\nI_orig"]
    figure, axis = plt.subplots(figsize=(1.4 * len(boxes) + 1, 3.6))
    axis.boxplot([b if len(b) else np.array([np.nan]) for b in boxes], showfliers=True)
    axis.set_xticks(range(1, len(names) + 1), names, fontsize=8)
    axis.set_yscale("symlog", linthresh=1e-4)
    axis.set_ylim(bottom=0)  # squares: nothing below 0
    axis.set_ylabel("(θ − label)², rad²")
    axis.set_title("Deviation from the label: images violating Eq. 2 vs their originals", fontsize=9)
    axis.grid(axis="y", alpha=0.3)
    figure.tight_layout()
    IMAGES.mkdir(parents=True, exist_ok=True)
    png = IMAGES / "deeptest_camera_fig6.png"
    figure.savefig(png, dpi=110)
    plt.close(figure)
    body = f"""
Figure 6: the squared deviation from the label, (θ − label)², of every transformed image that violates Eq. 2
(I_err: λ = {LAMBDA:g}, all nine transformations at severities {', '.join(map(str, args.severities))}, counted by
Eq. 3 or not, as in the paper's figure) and of its original (I_orig). One-sided Wilcoxon signed-rank test on the
pairs (`scipy.stats.wilcoxon`, I_err > I_orig). The pairs are not independent (several transformations of one
original), so the p-value is optimistic. The paper: MSE 0.41 (I_err) vs 0.035 (I_orig).

{data_line(world, models)} Transformations seeded {args.run_seed}, one trial per image and setting.

{table(["model", "pairs", "MSE of I_err", "MSE of I_orig", "ratio", "Wilcoxon signed-rank p"], rows)}

![Figure 6]({png.relative_to(DOCS)})
"""
    return write_section("fig6", "Figure 6: deviation from the label of erroneous images vs their originals", body,
                         command(args), time.perf_counter() - start)


# -- RQ5: Table 9 -----------------------------------------------------------------------------------
DEFAULT_TRAIN = tuple(f"/tmp/steering-data/{kind}-{s}" for kind in ("drive", "scenes") for s in (1, 2, 3, 4))


def training_roots(data_dir: Path = Path("/tmp/steering-data")) -> list[Path]:
    """The committed weights' training data sets, as ``weights/steering.json`` records them (rendered
    ones under ``data_dir``, the training script's default), else the recipe's defaults."""
    import json

    from lidarfuzz.suts.steering.builtin import WEIGHTS_DIR

    record = WEIGHTS_DIR / "steering.json"
    if not record.is_file():
        return [Path(r) for r in DEFAULT_TRAIN]
    data = json.loads(record.read_text()).get("data", {})
    if "data_sets" in data:
        held = set(data.get("val_data_sets", []))
        return [Path(r) for r in data["data_sets"] if r not in held]
    return [data_dir / f"{kind}-{seed}" for kind, seed, _ in data.get("train_sets", [])]


def prefixed(prefix: str, text: str) -> None:
    print(f"{prefix}: {text}", flush=True)


def table9(args: argparse.Namespace) -> str:
    from lidarfuzz.suts.steering.builtin import PREPROCESS
    from lidarfuzz.suts.steering.networks import NETWORKS
    from lidarfuzz.suts.steering.training import Frames, TrainConfig, mse, predict, read_frames, train_network

    start = time.perf_counter()
    world = open_world(ensure_world(args.seed, args.frames, args.image_size), args.seed)
    model = load_model("epoch", weights_of(args, "epoch"))
    preprocess = PREPROCESS["epoch"]
    args.train_data = args.train_data or training_roots()
    missing = [r for r in args.train_data if not (Path(r) / "steering.csv").is_file()]
    if missing:
        raise SystemExit(f"--train-data: {missing[0]} holds no data set (render the training recipe's data with "
                         "scripts/train_steering.py, or pass other roots)")
    train = read_frames([Path(r) for r in args.train_data], preprocess, cache=Path("/tmp/steering-cache"))
    # the transformations that violated Eq. 2 on this model (kept by Eq. 3, or composite), at their severities
    judged = judge(model, world, args.severities, args.run_seed)
    violated = sorted({(n, s) for n, s, _ in violations_of(judged, True)})
    if not violated:
        raise SystemExit("table9: no transformation violated Eq. 2 on epoch; nothing to retrain with")
    order = np.random.default_rng(args.run_seed).permutation(len(world.ids))
    cut = round(0.66 * len(order))
    train_side, held_out = np.sort(order[:cut]), np.sort(order[cut:])
    labels = world.labels

    def pixels(indices: NDArray[np.int64], name: str | None, severity: int) -> NDArray[np.uint8]:
        if name is None:
            return np.stack([preprocess.pixels(world.samples[i].image) for i in indices])
        return np.stack([preprocess.pixels(judged.settings[(name, severity)]["images"][i].image) for i in indices])

    synthetic = np.concatenate([pixels(train_side, n, s) for n, s in violated])
    pool = len(synthetic)
    pick = np.sort(np.random.default_rng(args.run_seed).permutation(pool)[:args.synthetic])  # at most --synthetic
    synthetic = synthetic[pick]
    synthetic_labels = np.concatenate([labels[train_side]] * len(violated))[pick]
    extra = Frames(synthetic, synthetic_labels, np.full(len(synthetic), -1, np.int64),
                   tuple(f"synthetic/{i}" for i in range(len(synthetic))))
    # the control sees the same frames as often, untransformed: only the transformations differ
    plain = np.concatenate([pixels(train_side, None, 0)] * len(violated))[pick]
    same = Frames(plain, synthetic_labels, np.full(len(plain), -1, np.int64),
                  tuple(f"original/{i}" for i in range(len(plain))))

    def joined(more: Frames) -> Frames:
        return Frames(np.concatenate([train.images, more.images]), np.concatenate([train.labels, more.labels]),
                      np.concatenate([train.groups, more.groups]), train.frame_ids + more.frame_ids)

    config = TrainConfig(epochs=args.epochs, seed=args.run_seed, threads=args.threads)
    nets = {}
    seconds = {}
    for key, data in (("control", joined(same)), ("retrained", joined(extra))):
        net = NETWORKS["epoch"]()
        began = time.perf_counter()
        train_network(net, preprocess, data, config, log=functools.partial(prefixed, key))
        seconds[key] = time.perf_counter() - began
        nets[key] = net
    evaluation = [("original images", None, 0), *[(f"{short(n)} severity {s}", n, s) for n, s in violated]]
    rows = []
    for title, name, severity in evaluation:
        x, y = pixels(held_out, name, severity), labels[held_out]
        before = mse(predict(model.sut.module, preprocess, x), y)
        control = mse(predict(nets["control"], preprocess, x), y)
        after = mse(predict(nets["retrained"], preprocess, x), y)
        rows.append([title, len(y), f"{before:.5f}", f"{control:.5f}", f"{after:.5f}",
                     f"{100 * improvement(before, after):+.0f} %", f"{100 * improvement(control, after):+.0f} %"])
    body = f"""
RQ5 / Table 9: retraining the Epoch-like network with transformed images. The transformations that violated
Eq. 2 on `epoch` (λ = {LAMBDA:g}, kept by Eq. 3 at ε = {EPSILON} or composite; at severities
{', '.join(map(str, args.severities))}, seeded {args.run_seed}): {', '.join(f'{short(n)} {s}' for n, s in violated)}.
The test world's frames are split 66 / 34 % (seed {args.run_seed}): the transformed versions of the 66 %
({len(train_side)} frames × {len(violated)} settings = {pool} images, {len(synthetic)} of them drawn with seed
{args.run_seed} (`--synthetic`), each with its original's label)
join the original training data ({len(train)} frames: {', '.join(Path(r).name for r in args.train_data)}); the
network is retrained from scratch with `lidarfuzz.suts.steering.training.train_network` ({args.epochs} epochs,
seed {args.run_seed}, {args.threads} threads; {seconds['retrained']:.0f} s). The control is the same recipe on the
original training data and the same 66 % frames as often, untransformed ({seconds['control']:.0f} s), so that
neither retraining itself nor seeing the test world's streets is taken for the transformed images' effect.
MSE (rad²) on the held-out 34 % ({len(held_out)} frames), originals and each
setting's transformed versions; improvement = (before − after) / before.

{data_line(world, [model])}

{table(["test images", "images", "MSE before (epoch as tested)",
        "MSE control (retrained, + the same frames untransformed)", "MSE retrained (+ synthetic)",
        "improvement vs before", "improvement vs control"], rows)}
"""
    return write_section("table9", "Table 9 (RQ5): retraining Epoch with transformed images", body, command(args),
                         time.perf_counter() - start)


# -- command line -----------------------------------------------------------------------------------
def command(args: argparse.Namespace) -> str:
    return f"python experiments/deeptest_camera.py {args.command}" + (f" {' '.join(args.extra)}" if args.extra else "")


RUNNERS: dict[str, Callable[[argparse.Namespace], str]] = {
    "table5": table5, "fig5": fig5, "table6": table6, "fig6": fig6, "table8": table8, "table9": table9}


def parse(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("command", choices=[*RUNNERS, "all"])
    parser.add_argument("--frames", type=int, default=WORLD_FRAMES, help="frames of the test world")
    parser.add_argument("--seed", type=int, default=WORLD_SEED, help="the test world's seed")
    parser.add_argument("--image-size", default=IMAGE_SIZE, help="the test world's camera image size")
    parser.add_argument("--models", nargs="+", default=list(MODELS), choices=MODELS)
    parser.add_argument("--seeds", type=int, default=20, help="seed images for fig5, table6 and the guided search")
    parser.add_argument("--run-seed", type=int, default=0, help="seeds the draws, transformations and searches")
    parser.add_argument("--budget", type=int, default=0,
                        help="guided search tests (default: table6 as many as the single transformations, "
                             "table8 100)")
    parser.add_argument("--severities", type=int, nargs="+", default=list(SEVERITIES))
    parser.add_argument("--weights-dir", default=None, help="NAME.pt files to test instead of the committed weights")
    parser.add_argument("--review", type=int, default=8, help="violating pairs written for manual review")
    parser.add_argument("--review-dir", default=str(DOCS / "deeptest_camera_review"))
    parser.add_argument("--train-data", nargs="+", default=None,
                        help="table9: training data sets (default: the committed weights', from weights/steering.json)")
    parser.add_argument("--epochs", type=int, default=6, help="table9: training epochs")
    parser.add_argument("--synthetic", type=int, default=1000, help="table9: most transformed images added")
    parser.add_argument("--threads", type=int, default=2, help="table9: training threads")
    args = parser.parse_args(argv)
    raw = list(sys.argv[2:] if argv is None else argv[1:])
    args.extra = raw
    return args


def main(argv: list[str] | None = None) -> int:
    args = parse(argv)
    set_threads()
    for name in (COMMANDS if args.command == "all" else (args.command,)):
        args.command = name
        RUNNERS[name](args)
        set_threads()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
