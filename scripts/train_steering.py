"""Train the built-in steering networks (``epoch``, ``dave2``, ``chauffeur``) on the simulator's camera.

Usage (the committed weights' recipe; a 2-core CPU)::

    .venv/bin/python scripts/train_steering.py --data-dir /tmp/steering-data \\
        --out-dir src/lidarfuzz/suts/steering/weights

    .venv/bin/python scripts/train_steering.py --out-dir /tmp/w --train-seeds 1 --val-seeds 2 \\
        --frames 40 --epochs 1       # a smoke run

Steps:

1. **data**: drive logs (``lidarfuzz gen --camera --drive --frames N --seed S``: the ego vehicle
   drives up a street, stops at a junction, turns left or right and drives on) and sets of
   independent frames (``lidarfuzz gen --camera``: each frame its own street, the ego vehicle
   put off its lane's centre and heading, so the pure-pursuit label steers it back), rendered at
   ``--image-size`` into ``--data-dir`` unless already there; ``steering.csv`` holds the
   front-wheel angle per frame. Training and validation sets have different seeds (other
   streets, junctions and traffic: no validation scene is seen in training).
   ``--data ROOT ...`` trains on existing data sets instead (the last ``--val-count`` are held out);
2. each network's input is cached as uint8 at its resolution in ``--cache`` (``/tmp``);
3. **training** (``lidarfuzz.suts.steering.training``): MSE, Adam (lr 1e-3, cosine decay), batch
   64, left–right flips with the label negated, seeded, ``torch.set_num_threads(--threads)``, CPU;
4. **validation**: MSE on the held-out logs, and the MSE of always answering the training
   labels' mean (the baseline a network must beat);
5. the **neuron-coverage profile** of each network's weights over its training inputs (what
   KMNC, NBC and SNAC compare with), ``<fingerprint>.npz`` beside the weights.

Writes to ``--out-dir``: ``epoch.pt``, ``dave2.pt``, ``chauffeur.pt`` (float32 state dicts with
their metadata), the profiles, ``steering.json`` (data, parameters, seconds, MSEs) and
``steering.train.log``.
"""

from __future__ import annotations

import argparse
import json
import platform
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from lidarfuzz.coverage import build_profile, module_fingerprint
from lidarfuzz.suts.steering.builtin import PREPROCESS, load_network, save_network
from lidarfuzz.suts.steering.networks import NETWORKS
from lidarfuzz.suts.steering.pytorch import import_torch
from lidarfuzz.suts.steering.training import Frames, TrainConfig, mse, predict, read_frames, read_labels, train_network

PROFILE_FRAMES = 1000


class Tee:
    """Print to the console and to the run's log file."""

    def __init__(self, path: Path) -> None:
        self.file: TextIO = path.open("w", encoding="utf-8")

    def __call__(self, text: str) -> None:
        print(text, flush=True)
        self.file.write(text + "\n")
        self.file.flush()


def render(data_dir: Path, sets: list[tuple[str, int, int]], jobs: int, size: str, log: Tee) -> list[Path]:
    """Data sets ``(kind, seed, frames)`` with the camera (``lidarfuzz gen``; kind ``drive`` for a
    drive log, ``scenes`` for independent frames), ``jobs`` at a time, skipping complete ones."""
    lidarfuzz = Path(sys.executable).with_name("lidarfuzz")
    roots = [data_dir / f"{kind}-{seed}" for kind, seed, _ in sets]

    def one(spec: tuple[str, int, int], root: Path) -> None:
        kind, seed, frames = spec
        if (root / "steering.csv").is_file() and len(read_labels(root)) == frames:
            return
        # the LiDAR sweeps gen writes beside the images are not used: the 16-beam sensor is the cheapest
        command = [str(lidarfuzz), "gen", "--camera", "--image-size", size, "--sensor", "VLP-16",
                   "--frames", str(frames), "--seed", str(seed), "--workers", "1", "--out", str(root), "--overwrite",
                   *(["--drive"] if kind == "drive" else [])]
        start = time.perf_counter()
        subprocess.run(command, check=True, capture_output=True)
        log(f"rendered {kind} seed {seed} ({frames} frames) in {time.perf_counter() - start:.0f} s")

    with ThreadPoolExecutor(max_workers=jobs) as pool:
        list(pool.map(one, sets, roots))
    return roots


def data_sets(drive_seeds: list[int], scene_seeds: list[int], drive_frames: int, scene_frames: int,
              ) -> list[tuple[str, int, int]]:
    """The ``(kind, seed, frames)`` of drive logs and sets of independent frames."""
    return ([("drive", s, drive_frames) for s in drive_seeds] + [("scenes", s, scene_frames) for s in scene_seeds])


def describe(frames: Frames) -> dict[str, Any]:
    turning = np.abs(frames.labels) > 1e-3
    return {"frames": len(frames), "turning_frames": int(turning.sum()),
            "label_mean": float(frames.labels.mean()), "label_std": float(frames.labels.std()),
            "label_min": float(frames.labels.min()), "label_max": float(frames.labels.max())}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out-dir", type=Path, required=True)
    parser.add_argument("--data-dir", type=Path, default=Path("/tmp/steering-data"))
    parser.add_argument("--cache", type=Path, default=Path("/tmp/steering-cache"))
    parser.add_argument("--data", type=Path, nargs="*", help="existing data sets instead of rendering logs")
    parser.add_argument("--val-count", type=int, default=2, help="with --data: the last N data sets are validation")
    parser.add_argument("--drive-seeds", type=int, nargs="*", default=[1, 2, 3, 4], help="training drive logs")
    parser.add_argument("--scene-seeds", type=int, nargs="*", default=[1, 2, 3, 4],
                        help="training sets of independent frames")
    parser.add_argument("--val-drive-seeds", type=int, nargs="*", default=[101, 102])
    parser.add_argument("--val-scene-seeds", type=int, nargs="*", default=[101])
    parser.add_argument("--drive-frames", type=int, default=150, help="frames per drive log")
    parser.add_argument("--scene-frames", type=int, default=200, help="frames per set of independent frames")
    parser.add_argument("--image-size", default="320x240", help="camera image size the data are rendered at")
    parser.add_argument("--jobs", type=int, default=2, help="data sets rendered at once")
    parser.add_argument("--networks", nargs="*", default=list(NETWORKS))
    parser.add_argument("--epochs", type=int, default=12)
    parser.add_argument("--lr", type=float, default=1e-3)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args(argv)

    torch = import_torch()
    args.out_dir.mkdir(parents=True, exist_ok=True)
    part = "" if args.networks == list(NETWORKS) else "." + "+".join(args.networks)
    log = Tee(args.out_dir / f"steering{part}.train.log")
    log(f"python {platform.python_version()}, torch {torch.__version__}, threads {args.threads}, "
        f"{platform.processor() or platform.machine()}")
    start = time.perf_counter()
    if args.data:
        roots = list(args.data)
        train_roots, val_roots = roots[:-args.val_count], roots[-args.val_count:]
        data_info: dict[str, Any] = {"data_sets": [str(r) for r in roots], "val_data_sets": [str(r) for r in val_roots]}
    else:
        train_sets = data_sets(args.drive_seeds, args.scene_seeds, args.drive_frames, args.scene_frames)
        val_sets = data_sets(args.val_drive_seeds, args.val_scene_seeds, args.drive_frames, args.scene_frames)
        roots = render(args.data_dir, train_sets + val_sets, args.jobs, args.image_size, log)
        train_roots, val_roots = roots[:len(train_sets)], roots[len(train_sets):]
        data_info = {"rendered": "lidarfuzz gen --camera --image-size SIZE --sensor VLP-16 --frames N --seed S "
                                 "[--drive]", "image_size": args.image_size,
                     "train_sets": [list(t) for t in train_sets], "val_sets": [list(t) for t in val_sets]}
    log(f"data ready after {time.perf_counter() - start:.0f} s")
    figures: dict[str, Any] = {"data": data_info, "networks": {}, "torch": torch.__version__,
                               "python": platform.python_version(), "command": " ".join(["scripts/train_steering.py",
                                                                                          *sys.argv[1:]])}
    config = TrainConfig(epochs=args.epochs, lr=args.lr, seed=args.seed, threads=args.threads)
    for name in args.networks:
        preprocess = PREPROCESS[name]
        loaded = time.perf_counter()
        frames = read_frames([*train_roots, *val_roots], preprocess, cache=args.cache)
        is_val = frames.groups >= len(train_roots)
        train, val = frames.subset(~is_val), frames.subset(is_val)
        figures["data"].update(train=describe(train), val=describe(val))
        log(f"{name}: {len(train)} training and {len(val)} validation frames at {preprocess.height}×"
            f"{preprocess.width} in {time.perf_counter() - loaded:.0f} s")
        net = NETWORKS[name]()
        history = train_network(net, preprocess, train, config, val, log=lambda text, n=name: log(f"{n}: {text}"))
        path = save_network(net, name, args.out_dir / f"{name}.pt",
                            {"preprocess": preprocess.model_dump(mode="json"), "train": config.to_json()})
        net, _ = load_network(name, path)  # what users load: the float32 file
        val_mse = mse(predict(net, preprocess, val.images), val.labels)
        train_mse = mse(predict(net, preprocess, train.images), train.labels)
        baseline = mse(np.full(len(val), train.labels.mean()), val.labels)
        zero = mse(np.zeros(len(val)), val.labels)
        turning = np.abs(val.labels) > 1e-3
        turning_mse = mse(predict(net, preprocess, val.images[turning]), val.labels[turning]) if turning.any() else None
        profile_rows = np.random.default_rng(0).permutation(len(train))[:PROFILE_FRAMES]
        batches = [torch.from_numpy(np.ascontiguousarray(preprocess.scaled(train.images[np.sort(chunk)])
                                                         .transpose(0, 3, 1, 2)))
                   for chunk in np.array_split(profile_rows, max(1, len(profile_rows) // 200))]
        profile = build_profile(net, batches)
        fingerprint = module_fingerprint(net)
        profile.save(args.out_dir / f"{fingerprint}.npz")
        figures["networks"][name] = {
            "parameters": net.parameter_count(), "file_bytes": path.stat().st_size,
            "input": f"{preprocess.height}x{preprocess.width} {preprocess.color}", "epochs": config.epochs,
            "train_seconds": history["seconds"], "train_mse": train_mse, "val_mse": val_mse,
            "val_mse_turning_frames": turning_mse, "baseline_mean_mse": baseline, "baseline_zero_mse": zero,
            "profile": f"{fingerprint}.npz", "history": history["epochs"],
            "command": " ".join(["scripts/train_steering.py", *sys.argv[1:]]),
        }
        log(f"{name}: val MSE {val_mse:.5f} (predicting the mean {baseline:.5f}, zero {zero:.5f}); train MSE "
            f"{train_mse:.5f}; {net.parameter_count():,} parameters, {path.stat().st_size / 1e6:.2f} MB; "
            f"{history['seconds']:.0f} s of training")
        figures["config"] = config.to_json()
        write_figures(args.out_dir / "steering.json", figures, name)
    log(f"done in {time.perf_counter() - start:.0f} s")
    return 0


def write_figures(path: Path, figures: dict[str, Any], name: str) -> None:
    """Write the figures with network ``name``'s row, keeping other networks' rows already in the
    file (runs training different networks at once, ``--networks``, share one file)."""
    merged = json.loads(path.read_text()) if path.is_file() else {}
    rows = {**merged.get("networks", {}), name: figures["networks"][name]}
    path.write_text(json.dumps({**figures, "networks": rows}, indent=2) + "\n")


if __name__ == "__main__":
    raise SystemExit(main())
