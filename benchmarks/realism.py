"""Realism of the mutation operators on real scans, next to a simulator frame.

Usage: ``.venv/bin/python benchmarks/realism.py [--realdata DIR] [--part operators|detectors|all]
[--severities 1,2,3,4,5] [--seed N]``

Real frames: the KITTI object-benchmark scans under ``DIR/kitti/training`` (default
``../shared/realdata``, i.e. ``/work/shared/realdata`` next to the repository). They are read in
place and never copied; when the folder is absent the script says so in one line and exits 0.

Prints Markdown:

1. the frames: points, and per range bin the share of zero-intensity returns (what separates real
   intensities from the simulator's);
2. every registered operator at each severity: the share of the source points lost, moved (by more
   than 1 cm) and added, on each real frame and on one simulator HDL-64E frame (same seeds:
   ``generator(seed, frame_id, 0, severity)``);
3. the weather operators: the share of the source points lost per range bin (0–10, 10–20, 20–40,
   40–80 m) on each frame;
4. (``--part detectors``) the built-in detectors' recall of the real labelled cars, printed by
   :func:`detector_recall` when this module defines it (see the slot at the end).
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from lidarfuzz.operators import available, generator
from lidarfuzz.scene.scene import Scene

DEFAULT_REALDATA = Path(__file__).resolve().parents[2] / "shared" / "realdata"
RANGE_BINS = ((0.0, 10.0), (10.0, 20.0), (20.0, 40.0), (40.0, 80.0))
WEATHER = ("fog", "rain", "snow", "wet_ground")
INDEX = "source_index"  # a foreign channel: operators keep it on the points they keep or move; added points get 0
MOVED_M = 0.01


@dataclass(frozen=True)
class Frame:
    name: str
    scene: Scene  # carries INDEX = 1 … N
    ranges: NDArray[np.float64]


@dataclass(frozen=True)
class Change:
    lost: NDArray[np.bool_]  # per source point
    moved: NDArray[np.bool_]  # per source point (kept, displaced by more than MOVED_M)
    added: int


def kitti_root(realdata: Path) -> Path | None:
    root = realdata / "kitti" / "training"
    return root if (root / "velodyne").is_dir() and any((root / "velodyne").glob("*.bin")) else None


def indexed(name: str, scene: Scene) -> Frame:
    cloud = scene.points
    scene = scene.with_points(cloud.with_channel(INDEX, np.arange(1, len(cloud) + 1, dtype=np.float32)))
    return Frame(name, scene, np.linalg.norm(cloud.xyz.astype(np.float64), axis=1))


def load_frames(root: Path) -> list[Frame]:
    from lidarfuzz.io import KittiDataset
    from lidarfuzz.sim import GenerationConfig, render_frames

    dataset = KittiDataset(root)
    frames = [indexed(f"KITTI {frame_id}", dataset.load(frame_id)) for frame_id in dataset.frame_ids()]
    frames.append(indexed("simulator", next(render_frames(GenerationConfig(frames=1, seed=0)))))
    return frames


def change(frame: Frame, mutant: Scene) -> Change:
    n = len(frame.scene.points)
    points = mutant.points
    if not points.has(INDEX):  # an operator that rebuilt the cloud without foreign channels
        raise RuntimeError("the mutant lost the source index channel")
    source = np.rint(points.channel(INDEX)).astype(np.int64) - 1
    known = source >= 0
    kept = np.zeros(n, bool)
    kept[source[known]] = True
    displacement = np.linalg.norm(points.xyz[known].astype(np.float64)
                                  - frame.scene.points.xyz[source[known]].astype(np.float64), axis=1)
    moved = np.zeros(n, bool)
    moved[source[known][displacement > MOVED_M]] = True
    return Change(lost=~kept, moved=moved, added=int((~known).sum()))


def percent(part: float, whole: float) -> str:
    return f"{100.0 * part / whole:.1f}" if whole else "–"


def print_frames(frames: Sequence[Frame]) -> None:
    labels = [f"{lo:g}–{hi:g} m" for lo, hi in RANGE_BINS]
    print("## Frames\n")
    print("| frame | points | zero intensity | " + " | ".join(f"zero, {b}" for b in labels) + " |")
    print("|---|---:|---:|" + "---:|" * len(labels))
    for frame in frames:
        zero = frame.scene.points.intensity == 0
        cells = []
        for lo, hi in RANGE_BINS:
            in_bin = (frame.ranges >= lo) & (frame.ranges < hi)
            cells.append(f"{percent(zero[in_bin].sum(), in_bin.sum())} % of {in_bin.sum():,}")
        print(f"| {frame.name} | {len(zero):,} | {percent(zero.sum(), len(zero))} % | " + " | ".join(cells) + " |")
    print()


def lidar_operators() -> dict[str, Any]:
    """The registered operators that mutate point clouds (the camera ones take images)."""
    return {name: cls for name, cls in available().items() if cls.modality == "lidar"}


def run_operators(frames: Sequence[Frame], severities: Sequence[int], seed: int) -> dict[tuple[str, int, str], Change]:
    results: dict[tuple[str, int, str], Change] = {}
    for name, cls in sorted(lidar_operators().items(), key=lambda kv: (kv[1].family, kv[0])):
        for severity in severities:
            op = cls.at_severity(severity)
            for frame in frames:
                mutant, _ = op(frame.scene, generator(seed, frame.scene.frame_id, 0, severity))
                results[(name, severity, frame.name)] = change(frame, mutant)
    return results


def print_operators(frames: Sequence[Frame], severities: Sequence[int],
                    results: dict[tuple[str, int, str], Change]) -> None:
    print("## Points lost / moved / added, % of the source frame\n")
    print("| operator | severity | " + " | ".join(f.name for f in frames) + " |")
    print("|---|---:|" + "---|" * len(frames))
    for name, cls in sorted(lidar_operators().items(), key=lambda kv: (kv[1].family, kv[0])):
        for severity in severities:
            cells = []
            for frame in frames:
                c = results[(name, severity, frame.name)]
                n = len(c.lost)
                cells.append(f"{percent(c.lost.sum(), n)} / {percent(c.moved.sum(), n)} / {percent(c.added, n)}")
            print(f"| {name} ({cls.family}) | {severity} | " + " | ".join(cells) + " |")
    print()


def print_weather_bins(frames: Sequence[Frame], severities: Sequence[int],
                       results: dict[tuple[str, int, str], Change]) -> None:
    print("## Weather: points lost per range bin, % of the source points in the bin\n")
    labels = [f"{lo:g}–{hi:g} m" for lo, hi in RANGE_BINS]
    print("| operator | severity | frame | " + " | ".join(labels) + " | all |")
    print("|---|---:|---|" + "---:|" * (len(labels) + 1))
    for name in WEATHER:
        for severity in severities:
            for frame in frames:
                lost = results[(name, severity, frame.name)].lost
                cells = []
                for lo, hi in RANGE_BINS:
                    in_bin = (frame.ranges >= lo) & (frame.ranges < hi)
                    cells.append(percent(lost[in_bin].sum(), in_bin.sum()))
                print(f"| {name} | {severity} | {frame.name} | " + " | ".join(cells)
                      + f" | {percent(lost.sum(), len(lost))} |")
    print()


def operators_part(root: Path, severities: Sequence[int], seed: int) -> None:
    start = time.perf_counter()
    frames = load_frames(root)
    print(f"# Operators on {len(frames) - 1} real KITTI frames ({root}) and one simulator frame, seed {seed}\n")
    print_frames(frames)
    results = run_operators(frames, severities, seed)
    print_operators(frames, severities, results)
    print_weather_bins(frames, severities, results)
    print(f"({time.perf_counter() - start:.0f} s)\n")


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--realdata", type=Path, default=DEFAULT_REALDATA,
                        help="folder holding kitti/training (default: ../shared/realdata)")
    parser.add_argument("--part", choices=("operators", "detectors", "all"), default="all")
    parser.add_argument("--severities", default="1,2,3,4,5", help="comma-separated severities")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    root = kitti_root(args.realdata)
    if root is None:
        print(f"realism: no real frames at {args.realdata / 'kitti' / 'training'}; skipped")
        return
    severities = [int(s) for s in args.severities.split(",") if s.strip()]
    if args.part in ("operators", "all"):
        operators_part(root, severities, args.seed)
    if args.part in ("detectors", "all"):
        recall = globals().get("detector_recall")
        if recall is None:
            print("## Detectors\n\n(not measured: this module defines no detector_recall yet)\n")
        else:
            recall(root)


# =========================================================================== detectors
# Slot for the detectors' section: define ``detector_recall(kitti: Path) -> None`` here (it prints
# its own Markdown section for the KITTI root ``kitti``, which holds velodyne/, label_2/, calib/);
# ``main`` calls it for ``--part detectors`` and ``--part all``.


def detector_recall(kitti: Path, sim_frames: int = 4) -> None:
    """The built-in detectors on the real labelled frames, next to a few simulator frames.

    For ``classic`` and ``pillars`` (its committed weights; skipped with a note without
    PyTorch): recall of the labelled cars the detector can reach (in its range and the camera's
    view) at bird's-eye IoU >= 0.5 and 3D IoU >= 0.5 / 0.7, and car boxes per frame that overlap
    no labelled object and no DontCare region ("false"), at scores >= 0.3 and >= 0.5
    (:func:`lidarfuzz.suts.learned.evaluation.recall_figures`). A handful of real frames hold a
    handful of cars: the per-frame rows show what each figure rests on.
    """
    from lidarfuzz.io.kitti import open_kitti
    from lidarfuzz.sim.dataset import GenerationConfig, render_frames
    from lidarfuzz.suts.learned.evaluation import recall_figures
    from lidarfuzz.suts.registry import create

    start = time.perf_counter()
    dataset = open_kitti(kitti)
    real = [dataset.load(f) for f in dataset.frame_ids()]
    simulated = list(render_frames(GenerationConfig(frames=sim_frames, seed=0)))
    print(f"## Detectors on {len(real)} real KITTI frames ({kitti}) and {sim_frames} simulator frames (seed 0)\n")
    print("| detector | frames | score | cars (in range) | BEV@0.5 | 3D@0.5 | 3D@0.7 | false boxes/frame |")
    print("|---|---|---:|---:|---:|---:|---:|---:|")
    notes, rows = [], []
    for name in ("classic", "pillars"):
        try:
            sut = create(name)
            sut.load()
        except ImportError as exc:  # pillars without the learned extra
            notes.append(f"{name}: not measured ({exc})")
            continue
        for label, scenes in (("real", real), ("simulator", simulated)):
            pairs = [(scene, sut.detect(scene)) for scene in scenes]
            for score in (0.3, 0.5):
                f = recall_figures(pairs, min_score=score).to_json()

                def cell(key: str, figures: dict = f) -> str:
                    return "–" if figures[key] is None else f"{100 * figures[key]:.0f} %"

                print(f"| {name} | {label} | ≥ {score} | {f['cars']} ({f['cars_in_range']}) | {cell('recall_bev_0.5')} "
                      f"| {cell('recall_3d_0.5')} | {cell('recall_3d_0.7')} | {f['false_boxes_per_frame']} |")
                if label == "real" and score == 0.3:
                    rows += [(name, r) for r in f["per_frame"]]
        sut.close()
    print("\nPer real frame (score >= 0.3): labelled cars (in range), each one's best BEV / 3D IoU, car boxes, "
          "false ones\n")
    print("| detector | frame | cars | best BEV IoU | best 3D IoU | car boxes | false |")
    print("|---|---|---:|---|---|---:|---:|")
    for name, r in rows:
        print(f"| {name} | {r['frame']} | {r['cars']} ({r['cars_in_range']}) | {r['best_bev_iou']} "
              f"| {r['best_3d_iou']} | {r['car_boxes']} | {r['false_boxes']} |")
    for note in notes:
        print(f"\n{note}")
    print(f"\n({time.perf_counter() - start:.0f} s)\n")


if __name__ == "__main__":
    main()
