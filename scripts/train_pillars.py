"""Train the built-in learned detector (``pillars``) on the simulator and write its card.

Usage::

    .venv/bin/python scripts/train_pillars.py            # the committed weights' recipe
    .venv/bin/python scripts/train_pillars.py --epochs 2 --train-frames 64 --out /tmp/w.pt   # a quick try

Steps, each skipped when its output exists:

1. the training data: ``--train-frames`` simulator frames of seed ``--train-seed`` (every
   frame in the train split), generated with ``lidarfuzz gen``'s code;
2. the evaluation data: the 200 frames of seed 0 whose val split (the last 100)
   ``benchmarks/suts.py`` evaluates on — a different seed, so no training scene is in it;
3. training (``lidarfuzz.suts.learned.training``; seeded; on a GPU when there is one,
   else on the CPU);
4. KITTI AP|R40 (moderate; BEV and 3D) of the new weights and of the classic pipeline on
   that val split, written into the weights' metadata and into ``MODEL_CARD.md``.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path

import numpy as np

from lidarfuzz.io.kitti import open_kitti
from lidarfuzz.oracles.kitti_eval import KittiFrame, evaluate_kitti
from lidarfuzz.sim.dataset import GenerationConfig, generate_dataset, is_complete
from lidarfuzz.suts.classic import ClassicPipeline
from lidarfuzz.suts.learned.sut import DEFAULT_WEIGHTS, PillarsDetector, import_torch
from lidarfuzz.suts.learned.training import TrainConfig, load_frames, save_weights, split_ids, train

CLASSES = ("Car", "Pedestrian", "Cyclist")


def ensure_data(root: Path, frames: int, seed: int, val_fraction: float, workers: int) -> None:
    config = GenerationConfig(frames=frames, seed=seed, val_fraction=val_fraction)
    if not is_complete(root, config):
        print(f"generating {frames} frames of seed {seed} into {root} ...", flush=True)
        start = time.perf_counter()
        generate_dataset(root, config, workers=workers, overwrite=True)
        print(f"  {time.perf_counter() - start:.0f} s", flush=True)


def evaluate(sut: object, root: Path, split: str) -> dict[str, dict[str, float]]:
    """Moderate KITTI AP|R40 (BEV, 3D) per class of a SUT on a split, detections kept in the camera's view."""
    dataset = open_kitti(root)
    frames = []
    with sut:  # type: ignore[attr-defined]
        for frame_id in split_ids(root, split):
            scene = dataset.load(frame_id)
            dets = sut.detect(scene)  # type: ignore[attr-defined]
            if len(dets) and scene.calib is not None:
                dets = dets.select(scene.calib.in_view(dets.centers))
            frames.append(KittiFrame(scene.boxes, dets, scene.calib))
    result = evaluate_kitti(frames)
    return {
        cls: {m: round(float(result.get(m, cls, "moderate", "R40")), 2) for m in ("bev", "3d")} for cls in CLASSES
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--train-data", type=Path, default=Path("bench-out/pillars-train"))
    parser.add_argument("--train-frames", type=int, default=3000)
    parser.add_argument("--train-seed", type=int, default=1)
    parser.add_argument("--eval-data", type=Path, default=Path("bench-out/classic-data"))
    parser.add_argument("--epochs", type=int, default=TrainConfig.epochs)
    parser.add_argument("--batch-size", type=int, default=TrainConfig.batch_size)
    parser.add_argument("--lr", type=float, default=TrainConfig.lr)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--device", default="auto")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", type=Path, default=DEFAULT_WEIGHTS)
    parser.add_argument("--no-eval", action="store_true")
    parser.add_argument("--budget-minutes", type=float, default=None,
                        help="cut the epochs to what fits in this time (timed on the first epoch)")
    args = parser.parse_args()
    torch = import_torch()

    ensure_data(args.train_data, args.train_frames, args.train_seed, 0.0, args.workers)
    start = time.perf_counter()
    frames = load_frames(args.train_data, split_ids(args.train_data, "train"), CLASSES, workers=args.workers)
    objects = np.bincount(np.concatenate([c for _, _, c in frames]), minlength=len(CLASSES))
    print(f"loaded {len(frames)} frames ({dict(zip(CLASSES, objects.tolist(), strict=True))} objects) "
          f"in {time.perf_counter() - start:.0f} s", flush=True)
    config = TrainConfig(epochs=args.epochs, batch_size=args.batch_size, lr=args.lr, seed=args.seed)
    checkpoint = args.out.with_suffix(".partial.pt")

    def keep_checkpoint(net: object, row: dict) -> None:
        save_weights(net, checkpoint, {"epoch": row["epoch"], "partial": True})

    budget = args.budget_minutes * 60 if args.budget_minutes else None
    net, history = train(frames, config=config, device=args.device, log=lambda s: print(s, flush=True),
                         budget_seconds=budget, on_epoch=keep_checkpoint)
    config = TrainConfig(**{**config.__dict__, "epochs": history["epochs_run"]})
    checkpoint.unlink(missing_ok=True)
    meta = {
        "data": {"simulator_seed": args.train_seed, "frames": len(frames), "split": "train",
                 "objects": dict(zip(CLASSES, objects.tolist(), strict=True))},
        "train": {**config.__dict__, "device": history["device"], "seconds": history["seconds"],
                  "final_loss": history["epochs"][-1]["loss"] if history["epochs"] else None},
        "torch": torch.__version__,
        "gpu": torch.cuda.get_device_name(0) if history["device"] == "cuda" else None,
        "python": platform.python_version(),
        "command": " ".join(["python", *sys.argv]),
    }
    save_weights(net, args.out, meta)
    print(f"wrote {args.out} ({args.out.stat().st_size / 1e6:.1f} MB)", flush=True)
    if args.no_eval:
        return
    ensure_data(args.eval_data, 200, 0, 0.5, args.workers)
    scores = {
        "pillars": evaluate(PillarsDetector(weights=str(args.out)), args.eval_data, "val"),
        "classic": evaluate(ClassicPipeline(), args.eval_data, "val"),
    }
    meta["val"] = {"data": "simulator seed 0, 200 frames, val split (frames 100-199)", "ap_r40_moderate": scores}
    save_weights(net, args.out, meta)
    print(json.dumps(scores, indent=1))
    (args.out.parent / (args.out.stem + ".history.json")).write_text(json.dumps(history, indent=1))


if __name__ == "__main__":
    main()
