"""Train the built-in learned detector (``pillars``) on the simulator, with domain randomisation, in one command.

Usage (the committed weights' recipe; one GPU, 16 cores, under 10 minutes in all)::

    PYTHONPATH=src python scripts/train_pillars.py --out-dir OUT --data-dir /tmp/pillars-data \\
        --workers 16 --deadline-minutes 8.4 [--real /path/to/kitti/training]

    # the real-frame figures of weights trained elsewhere (no training; a few minutes on a CPU)
    .venv/bin/python scripts/train_pillars.py --out-dir OUT --eval-only OUT/pillars-sim.pt \\
        --real ../shared/realdata/kitti/training

    .venv/bin/python scripts/train_pillars.py --out-dir /tmp/w --train-frames 16 --epochs 1 --no-eval   # a smoke run

Steps:

1. the training data: ``--train-frames`` simulator frames of seed ``--train-seed`` (every
   frame in the train split), rendered with ``lidarfuzz gen``'s code into ``--data-dir``,
   in shards whose realism settings differ when the simulator offers any
   (:func:`realism_shards`);
2. training (``lidarfuzz.suts.learned.training``; seeded; on a GPU when there is one, else
   on the CPU) with the per-frame domain randomisation of
   ``lidarfuzz.suts.learned.augment``; with ``--deadline-minutes`` the epochs are cut so
   the whole command, evaluation included, ends in time;
3. the neuron-coverage profile of the new weights over the first 300 training frames (what
   ``lidarfuzz profile pillars DATA --frames 300`` writes), named by the weights' fingerprint;
4. KITTI AP|R40 (moderate; BEV and 3D) of the new weights and of the classic pipeline on
   the simulator's val split (seed 0, 200 frames, frames 100–199: what ``benchmarks/suts.py``
   evaluates), and with ``--real DIR`` the figures on real labelled KITTI frames: recall of
   the labelled cars (BEV IoU ≥ 0.5, 3D IoU ≥ 0.5 and ≥ 0.7), false boxes per frame, and AP
   with the evaluator's small-sample warnings.

Everything goes to ``--out-dir``: ``pillars-sim.pt`` (weights, configuration and metadata,
figures included), ``pillars-sim.history.json``, ``pillars-sim.train.log``,
``<fingerprint>.npz`` (the profile) and ``figures.json``. Only numpy, torch, scipy, PIL,
yaml, networkx and the simulator's own dependencies (embreex, shapely, pydantic, trimesh)
are imported: no CLI, store or web code, so ``PYTHONPATH=src`` suffices.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import platform
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from lidarfuzz.io.kitti import open_kitti
from lidarfuzz.sim.dataset import GenerationConfig, generate_dataset, is_complete
from lidarfuzz.suts.classic import ClassicPipeline
from lidarfuzz.suts.learned.evaluation import real_frame_figures, split_ap
from lidarfuzz.suts.learned.sut import PillarsDetector, import_torch
from lidarfuzz.suts.learned.training import TrainConfig, load_frames, save_weights, split_ids, train

CLASSES = ("Car", "Pedestrian", "Cyclist")
STEM = "pillars-sim"
PROFILE_FRAMES = 300
#: Seconds kept back from ``--deadline-minutes`` for everything after training (measured on the
#: 16-core H100 machine: profile, two evaluations, the real frames; with room to spare).
EVAL_RESERVE_S = 90.0


class Tee:
    """Print to the console and to the run's log file."""

    def __init__(self, path: Path) -> None:
        self.file: TextIO = path.open("w", encoding="utf-8")

    def __call__(self, text: str) -> None:
        print(text, flush=True)
        self.file.write(text + "\n")
        self.file.flush()


def realism_shards(frames: int, seed: int) -> list[tuple[int, int, dict[str, Any]]]:
    """(frames, seed, extra GenerationConfig fields) of each shard of the training data.

    Where the simulator has realism settings (``GenerationConfig.realism``), the training data
    is rendered with its domain-randomisation ranges (``RealismConfig.randomised()``: every
    frame's ground, sensor mounting, receiver, calibration and losses drawn from the frame's
    seed); on a simulator without them, as it is. One shard today; the list leaves room for
    mixing differently configured shards (each with its own seed, so no scene repeats).
    """
    names = {f.name for f in dataclasses.fields(GenerationConfig)}
    variants: list[dict[str, Any]] = [{}]
    if "realism" in names:
        from lidarfuzz.sim.realism import RealismConfig

        variants = [{"realism": RealismConfig.randomised()}]
    count = len(variants)
    return [
        (frames // count + (1 if i < frames % count else 0), seed + 1000 * i, variant)
        for i, variant in enumerate(variants)
    ]


def _jsonable(extra: dict[str, Any]) -> dict[str, Any]:
    return {k: v.model_dump(mode="json") if hasattr(v, "model_dump") else v for k, v in extra.items()}


def ensure_data(root: Path, frames: int, seed: int, val_fraction: float, workers: int,
                log: Callable[[str], None] = print, **extra: Any) -> None:
    """Render a simulator data set into ``root`` unless the same configuration is already there."""
    config = GenerationConfig(frames=frames, seed=seed, val_fraction=val_fraction, **extra)
    if not is_complete(root, config):
        start = time.perf_counter()
        generate_dataset(root, config, workers=workers, overwrite=True)
        how = f" with {', '.join(extra)}" if extra else ""
        log(f"rendered {frames} frames of seed {seed}{how} into {root} in {time.perf_counter() - start:.0f} s")


def build_profile(weights: Path, root: Path, frame_ids: list[str], out_dir: Path, threads: int) -> Path:
    """The neuron-coverage profile of the new weights over training frames, as ``lidarfuzz profile`` builds it."""
    torch = import_torch()
    from lidarfuzz.coverage import ActivationRecorder, NeuronProfile, module_fingerprint

    sut = PillarsDetector(weights=str(weights), threads=threads)
    sut.load()
    dataset = open_kitti(root)
    fingerprint = module_fingerprint(sut.module)
    recorder = ActivationRecorder(sut.module)
    profile = NeuronProfile(fingerprint)
    with torch.inference_mode():
        for start in range(0, len(frame_ids), 4):
            recorder.clear()
            with recorder:
                sut.detect_batch([dataset.load(f) for f in frame_ids[start:start + 4]])
            profile.update(recorder.values())
    return profile.save(out_dir / f"{fingerprint}.npz")


def evaluate_weights(weights: Path, train_root: Path | None, eval_root: Path, real_root: Path | None, out_dir: Path,
                     log: Callable[[str], None], start: float) -> dict[str, Any]:
    """Profile (over ``train_root``'s first frames, when given), simulator val AP and real-frame figures
    of a weights file, next to the previous built-in weights and the classic pipeline; writes ``figures.json``."""
    torch = import_torch()
    threads = max(1, min(16, torch.get_num_threads()))
    if train_root is not None:
        profile = build_profile(weights, train_root, split_ids(train_root, "train")[:PROFILE_FRAMES], out_dir, threads)
        log(f"profile {profile.name} after {time.perf_counter() - start:.0f} s")
    figures: dict[str, Any] = {}
    val = [open_kitti(eval_root).load(f) for f in split_ids(eval_root, "val")]
    suts = [("pillars", PillarsDetector(weights=str(weights), threads=threads)), ("classic", ClassicPipeline())]
    for name, sut in suts:
        with sut:
            figures.setdefault("simulator_val", {})[name] = split_ap(sut, val)
    figures["simulator_val"]["data"] = f"simulator seed 0, {len(val) * 2} frames, val split (the last half)"
    log("simulator val, AP|R40 moderate: " + json.dumps(
        {k: v["ap_r40_moderate"] for k, v in figures["simulator_val"].items() if isinstance(v, dict)}))
    if real_root is not None:
        real = open_kitti(real_root)
        scenes = [real.load(f) for f in real.frame_ids()]
        figures["real"] = {"data": str(real_root), "frames": len(scenes)}
        for name, sut in [("pillars", PillarsDetector(weights=str(weights), threads=threads)),
                          ("pillars (built-in weights)", PillarsDetector(threads=threads)),
                          ("classic", ClassicPipeline())]:
            with sut:
                figures["real"][name] = real_frame_figures(sut, scenes)
            row = figures["real"][name]["score>=0.3"]
            log(f"real {name}: recall BEV@0.5 {row['recall_bev_0.5']}, 3D@0.5 {row['recall_3d_0.5']}, "
                f"3D@0.7 {row['recall_3d_0.7']} of {row['cars_in_range']} cars; "
                f"false boxes/frame {row['false_boxes_per_frame']} (score >= 0.3)")
    (out_dir / "figures.json").write_text(json.dumps(figures, indent=1))
    return figures


def main() -> None:
    start = time.perf_counter()
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--out-dir", type=Path, required=True, help="weights, history, log, profile, figures")
    parser.add_argument("--data-dir", type=Path, default=Path("bench-out/pillars-dr"),
                        help="rendered training and evaluation data (reused when complete)")
    parser.add_argument("--train-frames", type=int, default=5000)
    parser.add_argument("--train-seed", type=int, default=1)
    parser.add_argument("--epochs", type=int, default=60,
                        help="epochs (cut to what fits with --deadline-minutes)")
    parser.add_argument("--deadline-minutes", type=float, default=None,
                        help="end the whole command in this time: epochs are cut to fit, evaluation included")
    parser.add_argument("--batch-size", type=int, default=TrainConfig.batch_size)
    parser.add_argument("--lr", type=float, default=TrainConfig.lr)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--augment", default="walls", choices=("default", "walls", "geometric", "none"),
                        help="the per-frame augmentation (walls: the committed weights' recipe)")
    parser.add_argument("--device", default="auto")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--eval-frames", type=int, default=200,
                        help="simulator frames of seed 0 to evaluate on (the last half: the val split)")
    parser.add_argument("--real", type=Path, default=None,
                        help="a KITTI-layout folder of real labelled frames to report recall and false boxes on")
    parser.add_argument("--no-eval", action="store_true", help="skip the profile and every evaluation")
    parser.add_argument("--eval-only", type=Path, default=None, metavar="WEIGHTS",
                        help="no training: evaluate these weights (simulator val, --real) into --out-dir/figures.json")
    args = parser.parse_args()
    torch = import_torch()
    args.out_dir.mkdir(parents=True, exist_ok=True)
    log = Tee(args.out_dir / ("eval.log" if args.eval_only else f"{STEM}.train.log"))
    log(f"python {platform.python_version()}, torch {torch.__version__}, "
        f"cuda {torch.cuda.get_device_name(0) if torch.cuda.is_available() else 'none'}")
    eval_root = args.data_dir / "eval"
    if args.eval_only is not None:
        ensure_data(eval_root, args.eval_frames, 0, 0.5, args.workers, log)
        evaluate_weights(args.eval_only, None, eval_root, args.real, args.out_dir, log, start)
        return

    shards = realism_shards(args.train_frames, args.train_seed)
    roots = []
    for index, (frames, seed, extra) in enumerate(shards):
        root = args.data_dir / f"train-{index}"
        ensure_data(root, frames, seed, 0.0, args.workers, log, **extra)
        roots.append(root)
    if not args.no_eval:
        ensure_data(eval_root, args.eval_frames, 0, 0.5, args.workers, log)

    loaded = time.perf_counter()
    frames_all = []
    for root in roots:
        frames_all += load_frames(root, split_ids(root, "train"), CLASSES, workers=args.workers)
    objects = np.bincount(np.concatenate([c for _, _, c in frames_all]), minlength=len(CLASSES))
    counts = dict(zip(CLASSES, objects.tolist(), strict=True))
    log(f"loaded {len(frames_all)} frames ({counts} objects) in {time.perf_counter() - loaded:.0f} s")

    config = TrainConfig(epochs=args.epochs, batch_size=args.batch_size, lr=args.lr, seed=args.seed,
                         augment=args.augment)
    budget = None
    if args.deadline_minutes is not None:
        budget = args.deadline_minutes * 60 - (time.perf_counter() - start) - (0 if args.no_eval else EVAL_RESERVE_S)
        log(f"training budget {budget:.0f} s")
        if budget <= 0:
            raise SystemExit(f"no time left to train within --deadline-minutes {args.deadline_minutes}")
    checkpoint = args.out_dir / f"{STEM}.partial.pt"

    def keep_checkpoint(net: object, row: dict[str, Any]) -> None:
        save_weights(net, checkpoint, {"epoch": row["epoch"], "partial": True})

    net, history = train(frames_all, config=config, device=args.device, log=log, budget_seconds=budget,
                         on_epoch=keep_checkpoint)
    config = dataclasses.replace(config, epochs=history["epochs_run"])
    weights = args.out_dir / f"{STEM}.pt"
    meta: dict[str, Any] = {
        "data": {"simulator_seed": args.train_seed, "frames": len(frames_all), "split": "train", "objects": counts,
                 "shards": [{"frames": f, "seed": s, **_jsonable(extra)} for f, s, extra in shards]},
        "train": {**config.to_json(), "device": history["device"], "seconds": history["seconds"],
                  "final_loss": history["epochs"][-1]["loss"] if history["epochs"] else None},
        "classes": list(CLASSES),
        "torch": torch.__version__,
        "gpu": torch.cuda.get_device_name(0) if history["device"] == "cuda" else None,
        "python": platform.python_version(),
        "command": " ".join(["python", *sys.argv]),
    }
    save_weights(net, weights, meta)
    checkpoint.unlink(missing_ok=True)
    (args.out_dir / f"{STEM}.history.json").write_text(json.dumps(history, indent=1))
    log(f"wrote {weights} ({weights.stat().st_size / 1e6:.1f} MB) after {time.perf_counter() - start:.0f} s")
    if args.no_eval:
        return

    figures = evaluate_weights(weights, roots[0], eval_root, args.real, args.out_dir, log, start)
    meta["figures"] = figures
    save_weights(net, weights, meta)
    log(f"done in {time.perf_counter() - start:.0f} s")


if __name__ == "__main__":
    main()
