"""``lidarfuzz eval`` on abnormal input, against the KITTI devkit's rules (issue 23).

Usage: ``.venv/bin/python benchmarks/eval_abnormal.py [--cases 20] [--frames 8] [--seed 0] [--write-doc]``

No copy of the official devkit (``cpp/evaluate_object.cpp``) is in this repository and nothing is
fetched, so the reference is :func:`devkit_evaluate` below: a line-by-line transcription of the
devkit's ``eval_class``, ``cleanData``, ``computeStatistics``, ``getThresholds`` and
``imageBoxOverlap`` in plain Python loops, written apart from :mod:`lidarfuzz.oracles.kitti_eval`
(it shares no code with it). What it transcribes, and lidarfuzz must reproduce:

* a ground-truth box's 2D height is the signed ``y2 − y1`` (``height <= MIN_HEIGHT`` ignores it);
  a detection's is ``int32_t height = fabs(y1 − y2)`` (``height < MIN_HEIGHT`` ignores it), a double
  outside ``int32`` converting to ``INT_MIN`` as x86-64's ``cvttsd2si`` does;
* 2D overlap: ``w = min(x2) − max(x1)``, ``h = min(y2) − max(y1)``, 0 unless both ``> 0``, then
  ``inter / (area_a + area_b − inter)`` (or ``inter / area_a`` for DontCare), areas as written;
* ``valid_detection`` starts at ``NO_DETECTION = -10000000``; collecting TP scores takes a candidate
  only when ``det.thresh > valid_detection``; ``det.thresh < thresh`` drops a detection at a threshold;
* class names compared with ``strcasecmp``; Van / Person_sitting as the neighbour classes.

BEV and 3D overlaps come from a shapely intersection per pair (``benchmarks/eval.py``'s
``pairwise_iou_loop``), and DontCare regions count for the 2D metric only (the devkit's DontCare
lines carry no 3D box), as lidarfuzz documents.

Cases: ``--cases`` per kind of abnormality, each ``--frames`` frames of ``benchmarks/eval.py``'s
synthetic KITTI workload (seeded), altered: detection 2D boxes upside down (y1 > y2), ground-truth
boxes upside down, x1 > x2, scores at, below and just above the no-detection marker, degenerate and
huge 2D heights (0 px, ≥ 2³¹ px), class names in random case (written as label files and read by
``load_kitti_eval_frames``), and all of these at once. For every case: all 72 AP values (3 classes ×
3 difficulties × bbox/BEV/3D/AOS × R11/R40) against the transcription, and the same case with its
frames and each frame's detections shuffled, which must give bit-identical results. Then the
command line: bad ``--classes``/``--overlaps`` values and ``mutate`` runs that fail half-way must
give one line on stderr, exit code 2, and leave nothing at the destination.
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

sys.path.insert(0, str(Path(__file__).resolve().parent))

from eval import make_workload, pairwise_iou_loop
from lidarfuzz.io.kitti.labels import format_labels
from lidarfuzz.oracles.kitti_eval import KittiFrame, evaluate_kitti
from lidarfuzz.oracles.kitti_files import load_kitti_eval_frames
from lidarfuzz.scene.boxes import Boxes3D
from reliability_doc import provenance, write_section

# -- the devkit, transcribed ---------------------------------------------------------------------
CLASS_NAMES = ("Car", "Pedestrian", "Cyclist")
MIN_OVERLAP = {"bbox": (0.7, 0.5, 0.5), "bev": (0.7, 0.5, 0.5), "3d": (0.7, 0.5, 0.5)}
MIN_HEIGHT = (40, 25, 25)
MAX_OCCLUSION = (0, 1, 2)
MAX_TRUNCATION = (0.15, 0.3, 0.5)
N_SAMPLE_PTS = 41
NO_DETECTION = -10000000.0
INT_MIN = -(2**31)


@dataclass
class Box:
    """One label line as the devkit holds it (``tGroundtruth`` / ``tDetection``)."""

    type: str
    truncation: float
    occlusion: int
    alpha: float
    x1: float
    y1: float
    x2: float
    y2: float
    thresh: float = 0.0


@dataclass
class DevkitFrame:
    gt: list[Box]
    det: list[Box]
    overlap: dict[str, NDArray[np.float64]]  # BEV / 3D, n_det × n_gt


def strcasecmp_equal(a: str, b: str) -> bool:
    return a.lower() == b.lower()


def int32(value: float) -> int:
    """C++'s ``int32_t x = value`` on x86-64: truncation, ``INT_MIN`` when out of range or NaN."""
    if not math.isfinite(value) or not -(2.0**31) <= value < 2.0**31:
        return INT_MIN
    return int(value)


def image_box_overlap(a: Box, b: Box, criterion: int = -1) -> float:
    x1, y1 = max(a.x1, b.x1), max(a.y1, b.y1)
    x2, y2 = min(a.x2, b.x2), min(a.y2, b.y2)
    w, h = x2 - x1, y2 - y1
    if w <= 0 or h <= 0:
        return 0.0
    inter = w * h
    a_area = (a.x2 - a.x1) * (a.y2 - a.y1)
    b_area = (b.x2 - b.x1) * (b.y2 - b.y1)
    if criterion == -1:
        return inter / (a_area + b_area - inter)
    return inter / a_area


def clean_data(cls: int, frame: DevkitFrame, difficulty: int) -> tuple[list[int], list[Box], list[int], int]:
    ignored_gt: list[int] = []
    n_gt = 0
    for g in frame.gt:
        height = g.y2 - g.y1
        if strcasecmp_equal(g.type, CLASS_NAMES[cls]):
            valid_class = 1
        elif ((strcasecmp_equal(CLASS_NAMES[cls], "Pedestrian") and strcasecmp_equal("Person_sitting", g.type))
              or (strcasecmp_equal(CLASS_NAMES[cls], "Car") and strcasecmp_equal("Van", g.type))):
            valid_class = 0
        else:
            valid_class = -1
        ignore = (g.occlusion > MAX_OCCLUSION[difficulty] or g.truncation > MAX_TRUNCATION[difficulty]
                  or height <= MIN_HEIGHT[difficulty])
        if valid_class == 1 and not ignore:
            ignored_gt.append(0)
            n_gt += 1
        elif valid_class == 0 or (ignore and valid_class == 1):
            ignored_gt.append(1)
        else:
            ignored_gt.append(-1)
    dontcare = [g for g in frame.gt if strcasecmp_equal("DontCare", g.type)]
    ignored_det: list[int] = []
    for d in frame.det:
        valid_class = 1 if strcasecmp_equal(d.type, CLASS_NAMES[cls]) else -1
        height = int32(abs(d.y1 - d.y2))
        if height < MIN_HEIGHT[difficulty]:
            ignored_det.append(1)
        elif valid_class == 1:
            ignored_det.append(0)
        else:
            ignored_det.append(-1)
    return ignored_gt, dontcare, ignored_det, n_gt


@dataclass
class PrData:
    tp: int = 0
    fp: int = 0
    fn: int = 0
    similarity: float = 0.0
    v: list[float] | None = None


def compute_statistics(cls: int, frame: DevkitFrame, dontcare: list[Box], ignored_gt: list[int],
                       ignored_det: list[int], compute_fp: bool, metric: str, compute_aos: bool = False,
                       thresh: float = 0.0) -> PrData:
    stat = PrData(v=[])
    assert stat.v is not None
    gt, det = frame.gt, frame.det
    min_overlap = MIN_OVERLAP[metric][cls]

    def overlap(j: int, i: int) -> float:
        if metric == "bbox":
            return image_box_overlap(det[j], gt[i], -1)
        return float(frame.overlap[metric][j, i])

    delta: list[float] = []
    assigned = [False] * len(det)
    ignored_threshold = [compute_fp and d.thresh < thresh for d in det]
    for i in range(len(gt)):
        if ignored_gt[i] == -1:
            continue
        det_idx = -1
        valid_detection = NO_DETECTION
        max_overlap = 0.0
        assigned_ignored_det = False
        for j in range(len(det)):
            if ignored_det[j] == -1 or assigned[j] or ignored_threshold[j]:
                continue
            o = overlap(j, i)
            if not compute_fp and o > min_overlap and det[j].thresh > valid_detection:
                det_idx, valid_detection = j, det[j].thresh
            elif (compute_fp and o > min_overlap and (o > max_overlap or assigned_ignored_det)
                  and ignored_det[j] == 0):
                max_overlap, det_idx, valid_detection, assigned_ignored_det = o, j, 1.0, False
            elif compute_fp and o > min_overlap and valid_detection == NO_DETECTION and ignored_det[j] == 1:
                det_idx, valid_detection, assigned_ignored_det = j, 1.0, True
        if valid_detection == NO_DETECTION and ignored_gt[i] == 0:
            stat.fn += 1
        elif valid_detection != NO_DETECTION and (ignored_gt[i] == 1 or ignored_det[det_idx] == 1):
            assigned[det_idx] = True
        elif valid_detection != NO_DETECTION:
            stat.tp += 1
            stat.v.append(det[det_idx].thresh)
            if compute_aos:
                delta.append(gt[i].alpha - det[det_idx].alpha)
            assigned[det_idx] = True
    if compute_fp:
        for i in range(len(det)):
            if not (assigned[i] or ignored_det[i] == -1 or ignored_det[i] == 1 or ignored_threshold[i]):
                stat.fp += 1
        nstuff = 0
        if metric == "bbox":  # DontCare lines have no 3D box: they overlap nothing in BEV and 3D
            for dc in dontcare:
                for j in range(len(det)):
                    if assigned[j] or ignored_det[j] in (-1, 1) or ignored_threshold[j]:
                        continue
                    if image_box_overlap(det[j], dc, 0) > min_overlap:
                        assigned[j] = True
                        nstuff += 1
        stat.fp -= nstuff
        if compute_aos:
            tmp = [0.0] + [(1.0 + math.cos(d)) / 2.0 for d in delta]
            if stat.tp > 0 or stat.fp > 0:
                total = 0.0
                for value in tmp:
                    total += value
                stat.similarity = total
            else:
                stat.similarity = -1
    return stat


def get_thresholds(v: list[float], n_groundtruth: float) -> list[float]:
    t: list[float] = []
    v = sorted(v, reverse=True)
    current_recall = 0.0
    for i in range(len(v)):
        l_recall = (i + 1) / n_groundtruth
        r_recall = (i + 2) / n_groundtruth if i < len(v) - 1 else l_recall
        if (r_recall - current_recall) < (current_recall - l_recall) and i < len(v) - 1:
            continue
        t.append(v[i])
        current_recall += 1.0 / (N_SAMPLE_PTS - 1.0)
    return t


def eval_class(frames: list[DevkitFrame], cls: int, metric: str, difficulty: int) -> tuple[list[float], list[float]]:
    compute_aos = metric == "bbox"
    v: list[float] = []
    n_gt = 0
    cleaned = []
    for frame in frames:
        ignored_gt, dontcare, ignored_det, n = clean_data(cls, frame, difficulty)
        n_gt += n
        cleaned.append((ignored_gt, dontcare, ignored_det))
        stat = compute_statistics(cls, frame, dontcare, ignored_gt, ignored_det, False, metric)
        assert stat.v is not None
        v += stat.v
    thresholds = get_thresholds(v, n_gt)
    pr = [PrData() for _ in thresholds]
    for frame, (ignored_gt, dontcare, ignored_det) in zip(frames, cleaned, strict=True):
        for t, thresh in enumerate(thresholds):
            tmp = compute_statistics(cls, frame, dontcare, ignored_gt, ignored_det, True, metric, compute_aos, thresh)
            pr[t].tp += tmp.tp
            pr[t].fp += tmp.fp
            pr[t].fn += tmp.fn
            if tmp.similarity != -1:
                pr[t].similarity += tmp.similarity
    precision = [0.0] * N_SAMPLE_PTS
    aos = [0.0] * N_SAMPLE_PTS
    for i, p in enumerate(pr):
        precision[i] = p.tp / (p.tp + p.fp)
        aos[i] = p.similarity / (p.tp + p.fp)
    for i in range(len(thresholds)):
        precision[i] = max(precision[i:])
        aos[i] = max(aos[i:])
    return precision, aos


def devkit_evaluate(frames: list[DevkitFrame]) -> dict[str, dict[str, dict[str, dict[str, float]]]]:
    """AP in percent, ``ap[metric][class][difficulty]["R11" | "R40"]``, as the devkit computes it."""
    ap: dict[str, dict[str, dict[str, dict[str, float]]]] = {m: {} for m in ("bbox", "bev", "3d", "aos")}
    for cls, name in enumerate(CLASS_NAMES):
        for m in ap:
            ap[m][name] = {}
        for d, difficulty in enumerate(("easy", "moderate", "hard")):
            for metric in ("bbox", "bev", "3d"):
                precision, aos = eval_class(frames, cls, metric, d)
                ap[metric][name][difficulty] = _r11_r40(precision)
                if metric == "bbox":
                    ap["aos"][name][difficulty] = _r11_r40(aos)
    return ap


def _r11_r40(curve: list[float]) -> dict[str, float]:
    r11 = 0.0
    for i in range(0, N_SAMPLE_PTS, 4):
        r11 += curve[i]
    r40 = 0.0
    for i in range(1, N_SAMPLE_PTS):
        r40 += curve[i]
    return {"R11": r11 / 11.0 * 100.0, "R40": r40 / 40.0 * 100.0}


def devkit_frames(frames: Sequence[KittiFrame], names: Sequence[tuple[list[str], list[str]]] | None = None,
                  ) -> list[DevkitFrame]:
    """The devkit's view of lidarfuzz frames (``names``: the class names as written in the files)."""
    out = []
    for f, frame in enumerate(frames):
        gt_names, dt_names = names[f] if names is not None else (list(frame.gt.labels), list(frame.detections.labels))
        gt = [Box(str(gt_names[i]), float(frame.gt.truncation[i]), int(frame.gt.occlusion[i]),
                  float(frame.gt.alpha[i]), *(float(x) for x in frame.gt.bbox2d[i])) for i in range(len(frame.gt))]
        det = [Box(str(dt_names[i]), 0.0, 0, float(frame.detections.alpha[i]),
                   *(float(x) for x in frame.detections.bbox2d[i]), thresh=float(frame.detections.scores[i]))
               for i in range(len(frame.detections))]
        out.append(DevkitFrame(gt, det, pairwise_iou_loop(frame)))
    return out


# -- the abnormal cases ------------------------------------------------------------------------------
def _with(boxes: Boxes3D, **changes: NDArray[np.float64]) -> Boxes3D:
    return boxes.replace(**changes)


def _flip_y(boxes: Boxes3D, rng: np.random.Generator, share: float) -> Boxes3D:
    bbox = boxes.bbox2d.copy()
    flip = rng.random(len(boxes)) < share
    bbox[flip] = bbox[flip][:, [0, 3, 2, 1]]
    return _with(boxes, bbox2d=bbox)


def _flip_x(boxes: Boxes3D, rng: np.random.Generator, share: float) -> Boxes3D:
    bbox = boxes.bbox2d.copy()
    flip = rng.random(len(boxes)) < share
    bbox[flip] = bbox[flip][:, [2, 1, 0, 3]]
    return _with(boxes, bbox2d=bbox)


def _marker_scores(boxes: Boxes3D, rng: np.random.Generator) -> Boxes3D:
    scores = boxes.scores.copy()
    pick = rng.random(len(boxes))
    scores[pick < 0.1] = NO_DETECTION  # at the marker
    scores[(pick >= 0.1) & (pick < 0.2)] = NO_DETECTION - rng.uniform(1, 1e12)  # below it
    scores[(pick >= 0.2) & (pick < 0.3)] = NO_DETECTION + rng.uniform(0.001, 1)  # just above: ordinary
    return _with(boxes, scores=scores)


def _degenerate(boxes: Boxes3D, rng: np.random.Generator) -> Boxes3D:
    bbox = boxes.bbox2d.copy()
    pick = rng.random(len(boxes))
    flat = pick < 0.15
    bbox[flat, 3] = bbox[flat, 1]  # 0 px tall
    huge = (pick >= 0.15) & (pick < 0.3)
    bbox[huge, 3] = bbox[huge, 1] + rng.uniform(2.0**31, 2.0**40, int(huge.sum()))  # beyond int32
    return _with(boxes, bbox2d=bbox)


def alter(frames: list[KittiFrame], kind: str, rng: np.random.Generator) -> list[KittiFrame]:
    out = []
    for frame in frames:
        gt, dt = frame.gt, frame.detections
        if kind in ("det_upside_down", "all"):
            dt = _flip_y(dt, rng, 0.3)
        if kind in ("gt_upside_down", "all"):
            gt = _flip_y(gt, rng, 0.3)
        if kind in ("x_swapped", "all"):
            gt, dt = _flip_x(gt, rng, 0.2), _flip_x(dt, rng, 0.2)
        if kind in ("marker_scores", "all"):
            dt = _marker_scores(dt, rng)
        if kind in ("degenerate", "all"):
            gt, dt = _degenerate(gt, rng), _degenerate(dt, rng)
        out.append(KittiFrame(gt, dt, frame.calib))
    return out


def _recase(name: str, rng: np.random.Generator) -> str:
    choice = int(rng.integers(0, 3))
    if choice == 0:
        return name.lower()
    if choice == 1:
        return name.upper()
    return "".join(c.upper() if rng.random() < 0.5 else c.lower() for c in name)


def through_files(frames: list[KittiFrame], rng: np.random.Generator, folder: Path,
                  ) -> tuple[list[KittiFrame], list[tuple[list[str], list[str]]]]:
    """Write the frames as label files with class names in random case, read them back with
    ``load_kitti_eval_frames``; also the names as written (for the transcription)."""
    labels, dets = folder / "label_2", folder / "dets"
    labels.mkdir(parents=True)
    dets.mkdir()
    written: list[tuple[list[str], list[str]]] = []
    for f, frame in enumerate(frames):
        names = []
        for boxes, where in ((frame.gt, labels), (frame.detections, dets)):
            lines = format_labels(boxes, frame.calib).splitlines()
            recased = [_recase(line.split(" ", 1)[0], rng) for line in lines]
            names.append(recased)
            text = "".join(f"{n} {line.split(' ', 1)[1]}\n" for n, line in zip(recased, lines, strict=True))
            (where / f"{f:06d}.txt").write_text(text)
        written.append((names[0], names[1]))
    loaded = load_kitti_eval_frames(labels, dets)
    # the loader uses the default calibration (no calib/ folder): the workload's is the same
    return loaded.frames, written


def shuffled(frames: list[KittiFrame], rng: np.random.Generator) -> list[KittiFrame]:
    return [KittiFrame(f.gt, f.detections.select(rng.permutation(len(f.detections))), f.calib)
            for f in (frames[i] for i in rng.permutation(len(frames)))]


KINDS = ("det_upside_down", "gt_upside_down", "x_swapped", "marker_scores", "degenerate", "class_case", "all")


@dataclass
class KindResult:
    cases: int = 0
    values: int = 0
    agreeing_cases: int = 0
    max_difference: float = 0.0
    permuted_identical: int = 0
    seconds: float = 0.0


def run_cases(num_cases: int, num_frames: int, seed: int) -> dict[str, KindResult]:
    pool = make_workload(num_cases * len(KINDS) * num_frames, seed)
    results: dict[str, KindResult] = {}
    case = 0
    for kind in KINDS:
        res = results[kind] = KindResult()
        start = time.perf_counter()
        for _ in range(num_cases):
            rng = np.random.default_rng([seed, case])
            frames = pool[case * num_frames:(case + 1) * num_frames]
            case += 1
            names = None
            if kind == "class_case":
                with tempfile.TemporaryDirectory() as tmp:
                    frames, names = through_files(frames, rng, Path(tmp))
            else:
                frames = alter(frames, kind, rng)
            ours = evaluate_kitti(frames)
            reference = devkit_evaluate(devkit_frames(frames, names))
            diffs = [abs(ours.ap[m][c][d][p] - reference[m][c][d][p])
                     for m in reference for c in reference[m] for d in reference[m][c] for p in ("R11", "R40")]
            res.cases += 1
            res.values += len(diffs)
            res.max_difference = max(res.max_difference, *diffs)
            res.agreeing_cases += all(x <= 1e-9 for x in diffs)
            again = evaluate_kitti(shuffled(frames, rng))
            res.permuted_identical += json.dumps(again.ap, sort_keys=True) == json.dumps(ours.ap, sort_keys=True)
        res.seconds = time.perf_counter() - start
        print(f"{kind:16} {res.cases} cases: {res.agreeing_cases} agree on all {res.values // res.cases} values "
              f"(max |ΔAP| {res.max_difference:.1e}); shuffled bit-identical {res.permuted_identical}/{res.cases} "
              f"({res.seconds:.1f} s)", flush=True)
    return results


# -- the command line ---------------------------------------------------------------------------------------
@dataclass
class CliCase:
    what: str
    args: list[str]
    expect: str  # a phrase the one line must hold
    destination: Path | None = None


def _lidarfuzz(args: list[str]) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-c", "from lidarfuzz.cli.app import main; main()", *args],
                          capture_output=True, text=True, timeout=300)


def cli_cases(root: Path) -> list[CliCase]:
    """Label and detection folders, and a KITTI sequence whose second scan is truncated."""
    from lidarfuzz.io import write_kitti
    from lidarfuzz.sim import GenerationConfig, render_frames

    frames = make_workload(2, 1)
    labels, dets = root / "label_2", root / "dets"
    labels.mkdir()
    dets.mkdir()
    for f, frame in enumerate(frames):
        (labels / f"{f:06d}.txt").write_text(format_labels(frame.gt, frame.calib))
        (dets / f"{f:06d}.txt").write_text(format_labels(frame.detections, frame.calib))
    scenes = list(render_frames(GenerationConfig(frames=3, seed=7, sequence=True, sensor="VLP-16")))
    log = root / "log"
    write_kitti(log, [s.replace(points=s.points.without_channels(["ring"])) for s in scenes])
    scan = log / "velodyne" / "000001.bin"
    scan.write_bytes(scan.read_bytes()[:1001])
    ev = ["eval", str(labels), str(dets)]
    out = root / "out"
    cases = [
        CliCase("eval --classes Truck", [*ev, "--classes", "Car,Truck"], "--classes: 'Truck' is not a class"),
        CliCase("eval --classes ','", [*ev, "--classes", ","], "--classes: no class given"),
        CliCase("eval --overlaps tight", [*ev, "--overlaps", "tight"], "--overlaps: 'tight' is not one of"),
        CliCase("mutate --op AVG (no --interleave)", ["mutate", str(log), str(out / "a"), "--op", "AVG"],
                "--op: AVG combines consecutive frames", out / "a"),
        CliCase("mutate --to tiff", ["mutate", str(log), str(out / "t"), "--op", "HGT", "--to", "tiff"],
                "unknown target format", out / "t"),
    ]
    for name, extra in (("avg", []), ("avg.mcap", []), ("avg_pcd", ["--to", "pcd"])):
        cases.append(CliCase(f"mutate --op AVG --interleave, ringless log, bad 2nd scan → {name}",
                             ["mutate", str(log), str(out / name), "--op", "AVG", "--interleave", *extra],
                             "000001.bin", out / name))
    cases.append(CliCase("mutate --op HGT, bad 2nd scan → folder", ["mutate", str(log), str(out / "h"), "--op", "HGT"],
                         "000001.bin", out / "h"))
    return cases


def run_cli(root: Path) -> list[tuple[CliCase, bool, str]]:
    (root / "out").mkdir()
    outcomes = []
    for case in cli_cases(root):
        result = _lidarfuzz(case.args)
        lines = result.stderr.splitlines()
        left = sorted(p.name for p in (root / "out").iterdir())
        ok = (result.returncode == 2 and len(lines) == 1 and case.expect in lines[0] and not left
              and "Traceback" not in result.stderr)
        shown = lines[0] if len(lines) == 1 else f"{len(lines)} lines, exit {result.returncode}, left {left}"
        shown = shown.replace(str(root), "…")
        outcomes.append((case, ok, shown))
        print(f"{'ok ' if ok else 'BAD'} {case.what}: {shown}", flush=True)
    return outcomes


# -- the report -------------------------------------------------------------------------------------------
DESCRIPTIONS = {
    "det_upside_down": "30 % of detection 2D boxes upside down (y1 > y2)",
    "gt_upside_down": "30 % of ground-truth 2D boxes upside down (DontCare too)",
    "x_swapped": "20 % of all 2D boxes with x1 > x2",
    "marker_scores": "30 % of scores at / below / just above −10⁷ (10 % each)",
    "degenerate": "15 % of 2D boxes 0 px tall, 15 % taller than 2³¹ px",
    "class_case": "class names in random case, through label files",
    "all": "all of the above at once",
}


def markdown(results: dict[str, KindResult], cli: list[tuple[CliCase, bool, str]], command: str, frames: int,
             elapsed: float) -> str:
    cases = sum(r.cases for r in results.values())
    agree = sum(r.agreeing_cases for r in results.values())
    identical = sum(r.permuted_identical for r in results.values())
    values = sum(r.values for r in results.values())
    worst = max(r.max_difference for r in results.values())
    lines = [
        provenance(command),
        "",
        f"**{agree} of {cases} abnormal cases** ({values:,} AP values) give the devkit's AP to within 10⁻⁹ "
        f"(largest difference {worst:.1e} percentage points); **{identical} of {cases}** give bit-identical "
        f"results with their frames and detections shuffled; **{sum(ok for _, ok, _ in cli)} of {len(cli)}** "
        "command-line mistakes and half-way failures give one line, exit code 2 and nothing at the destination "
        f"({elapsed:.0f} s in all).",
        "",
        "The reference is a line-by-line transcription of the devkit's `cleanData`, `computeStatistics`, "
        "`getThresholds`, `imageBoxOverlap` and `eval_class` (`benchmarks/eval_abnormal.py`; no copy of "
        "`evaluate_object.cpp` is in the repository): a detection's 2D height `int32_t(fabs(y1 − y2))`, a "
        "ground truth's the signed `y2 − y1`; an upside-down box overlaps nothing in 2D; a detection scored "
        "at or below `NO_DETECTION` (−10⁷) never becomes a candidate; class names compared with `strcasecmp`. "
        f"Each case is {frames} frames of `benchmarks/eval.py`'s synthetic KITTI workload, altered; all 72 AP "
        "values (3 classes × 3 difficulties × bbox/BEV/3D/AOS × R11/R40) are compared.",
        "",
        "Where lidarfuzz departs from the devkit on purpose (not counted here): a detection line without a "
        "2D box (`-1 -1 -1 -1`) or alpha (`-10`) gets both by "
        "projection, where the devkit would see a 0 px box and turn AOS off for every class; a class with no "
        "detection scores 0 where the devkit leaves it out; an unknown class name or a score that is not a "
        "finite number is refused in one line naming the file and line, where the devkit reads on.",
        "",
        "| abnormality | cases | agree with the devkit | max \\|ΔAP\\| | shuffled, bit-identical |",
        "|---|---:|---:|---:|---:|",
    ]
    for kind, r in results.items():
        lines.append(f"| {DESCRIPTIONS[kind]} | {r.cases} | {r.agreeing_cases} | {r.max_difference:.1e} | "
                     f"{r.permuted_identical} |")
    lines += ["", "| command | one line, exit 2, nothing left | what it printed |", "|---|---|---|"]
    for case, ok, shown in cli:
        shown = shown.replace("|", "\\|")
        lines.append(f"| `{case.what}` | {'yes' if ok else '**no**'} | {shown[:160]} |")
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", type=int, default=20, help="cases per kind of abnormality")
    parser.add_argument("--frames", type=int, default=8, help="frames per case")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--write-doc", action="store_true", help="rewrite the eval section of docs/reliability.md")
    args = parser.parse_args(argv)
    start = time.perf_counter()
    results = run_cases(args.cases, args.frames, args.seed)
    root = Path(tempfile.mkdtemp(prefix="eval_abnormal."))
    try:
        cli = run_cli(root)
    finally:
        shutil.rmtree(root, ignore_errors=True)
    elapsed = time.perf_counter() - start
    command = "python benchmarks/eval_abnormal.py " + " ".join(
        f"--{k.replace('_', '-')} {v}" for k, v in (("cases", args.cases), ("frames", args.frames),
                                                     ("seed", args.seed))) + (" --write-doc" if args.write_doc else "")
    text = markdown(results, cli, command, args.frames, elapsed)
    print("\n" + text)
    if args.write_doc:
        write_section("eval", text)
        print("\nwrote the eval section of docs/reliability.md")
    failed = [k for k, r in results.items() if r.agreeing_cases != r.cases or r.permuted_identical != r.cases]
    if failed or not all(ok for _, ok, _ in cli):
        sys.exit(1)


if __name__ == "__main__":
    main()
