"""``lidarfuzz train``: train or fine-tune the built-in learned detector (``pillars``) on your own KITTI-layout data."""

import platform
import sys
import time
from pathlib import Path
from typing import Annotated, Any

import typer

from lidarfuzz.cli.common import console, print_table


def train_command(
    data: Annotated[Path, typer.Argument(help="A labelled KITTI-layout data set (velodyne/, label_2/, calib/).")],
    out: Annotated[Path, typer.Option("--out", "-o", help="Weights file to write (.pt).")],
    split: Annotated[str, typer.Option(help="Frames to train on: ImageSets/SPLIT.txt, or 'all'.")] = "train",
    val_split: Annotated[str, typer.Option(help="Frames to evaluate on at the end (ImageSets/SPLIT.txt); "
                                           "'none' to skip.")] = "val",
    init: Annotated[str, typer.Option(help="Start from: builtin (fine-tune the committed weights), scratch, "
                                      "or a weights file.")] = "builtin",
    epochs: Annotated[int, typer.Option(min=1, help="Passes over the training frames.")] = 10,
    batch: Annotated[int, typer.Option(min=1, help="Frames per step.")] = 8,
    lr: Annotated[float | None, typer.Option(min=0.0, help="Peak learning rate (default: 3e-3 from scratch, "
                                             "1e-3 when fine-tuning).")] = None,
    device: Annotated[str, typer.Option(help="auto (a GPU when PyTorch sees one), cpu or cuda.")] = "auto",
    seed: Annotated[int, typer.Option(help="Seeds the initial weights, frame order and augmentations.")] = 0,
    augment: Annotated[str, typer.Option(help="default (domain randomisation: ground, intensity, drop-outs, "
                                         "flip/rotate/scale), walls (that, and walls beside objects: the "
                                         "built-in weights' recipe), geometric (flip/rotate/scale) or none.")]
    = "default",
    allow_unlabelled: Annotated[bool, typer.Option(help="Leave frames without a label file out instead of "
                                                   "refusing the data set.")] = False,
    workers: Annotated[int, typer.Option(min=1, help="Processes loading frames.")] = 2,
    overwrite: Annotated[bool, typer.Option(help="Replace an existing weights file at --out.")] = False,
) -> None:
    """Train or fine-tune the built-in detector on your labelled data; writes weights that `pillars` loads.

    Checks the data first (labels needed; frames without them are named and refused unless
    --allow-unlabelled), trains with a progress bar, writes the weights with their metadata
    (classes, point range, data, seed, history) and evaluates them on the val split (KITTI
    AP|R40, moderate). Use them with `lidarfuzz models add NAME pillars --option weights=OUT`
    or `lidarfuzz detect 'pillars?weights=OUT' ...`.
    """
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
    from rich.table import Table

    from lidarfuzz.errors import LidarfuzzError
    from lidarfuzz.suts.learned.augment import Augmentation
    from lidarfuzz.suts.learned.sut import import_torch
    from lidarfuzz.suts.learned.training import (
        TrainConfig,
        initial_weights,
        load_frames,
        open_training_data,
        save_weights,
        train,
    )

    if out.exists() and not overwrite:
        raise LidarfuzzError(f"{out}: already exists; pass --overwrite to replace it")
    if device not in ("auto", "cpu", "cuda"):
        raise typer.BadParameter(f"{device!r} is not one of auto, cpu, cuda", param_hint="--device")
    try:
        Augmentation.preset(augment)
    except ValueError as exc:
        raise typer.BadParameter(str(exc), param_hint="--augment") from None
    torch = import_torch()
    if device == "cuda" and not torch.cuda.is_available():
        raise LidarfuzzError("--device cuda: PyTorch sees no CUDA device here (use --device cpu or auto)")

    start = time.perf_counter()
    chosen = open_training_data(data, split, allow_unlabelled=allow_unlabelled)
    if chosen.skipped:
        console.print(f"left out {len(chosen.skipped)} frame(s) without labels (--allow-unlabelled): "
                      f"{', '.join(chosen.skipped[:5])}{' …' if len(chosen.skipped) > 5 else ''}")
    network_config, state, init_path = initial_weights(init)
    classes = tuple(network_config.classes)
    columns = (TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
               TextColumn("{task.fields[note]}"), TimeElapsedColumn())
    with Progress(*columns, console=console, transient=True) as progress:
        task = progress.add_task("loading", total=len(chosen.frame_ids), note="frames")
        frames = load_frames(chosen.root, chosen.frame_ids, classes, workers=workers,
                             on_frame=lambda: progress.advance(task))
    objects = {c: 0 for c in classes}
    for _, _, labels in frames:
        for index in labels.tolist():
            objects[classes[index]] += 1
    if not any(objects.values()):
        raise LidarfuzzError(f"{chosen.root / 'label_2'}: no {', '.join(classes)} labels in the "
                             f"{len(frames)} frame(s) of the {split!r} split: nothing to learn")
    console.print(f"training on {len(frames)} frame(s) of {chosen.root} ({split}): "
                  + ", ".join(f"{n} {c}" for c, n in objects.items())
                  + f"; from {init}" + (f" ({init_path})" if init_path else ""))
    config = TrainConfig(epochs=epochs, batch_size=min(batch, len(frames)), seed=seed, augment=augment,
                         lr=lr if lr is not None else (3e-3 if state is None else 1e-3))
    with Progress(*columns, console=console) as progress:
        task = progress.add_task("training", total=epochs * max(1, len(frames) // config.batch_size), note="")

        def step(done: int, total: int, loss: float) -> None:
            progress.update(task, completed=done, total=total, note=f"loss {loss:.3f}")

        net, history = train(frames, config=config, network_config=network_config, initial=state, device=device,
                             log=lambda text: progress.console.print(text), on_step=step)
    cfg = net.config
    meta: dict[str, Any] = {
        "classes": list(classes),
        "point_range": {"x": list(cfg.x_range), "y": list(cfg.y_range), "z": list(cfg.z_range)},
        "data": {"path": str(chosen.root.resolve()), "split": split, "frames": len(frames),
                 "left_out_unlabelled": len(chosen.skipped), "objects": objects},
        "init": init if init_path is None else str(init_path),
        "seed": seed,
        "train": {**config.to_json(), "device": history["device"], "seconds": history["seconds"]},
        "history": history,
        "torch": torch.__version__,
        "python": platform.python_version(),
        "command": " ".join(["lidarfuzz", *sys.argv[1:]]),
    }
    save_weights(net, out, meta)
    console.print(f"wrote [bold]{out}[/] after {time.perf_counter() - start:.0f} s "
                  f"(loss {history['epochs'][0]['loss']:.3f} → {history['epochs'][-1]['loss']:.3f})")
    if val_split == "none":
        return
    val_file = [p / "ImageSets" / f"{val_split}.txt" for p in (chosen.root, data)]
    if not any(p.is_file() for p in val_file):
        console.print(f"no {val_file[0]}: not evaluated (name a split with --val-split)")
        return
    figures = _evaluate(out, data, val_split, workers)
    meta["val"] = {"split": val_split, **figures}
    save_weights(net, out, meta)
    table = Table("class", "BEV AP", "3D AP", title=f"{val_split} split, KITTI AP|R40 moderate "
                  f"({figures['frames']} frames)")
    for name, values in figures["ap_r40_moderate"].items():
        table.add_row(name, f"{values['bev']:.1f}", f"{values['3d']:.1f}")
    print_table(table)
    for warning in figures["warnings"]:
        console.print(f"[yellow]warning:[/] {warning}")
    console.print(f"use it: lidarfuzz models add NAME pillars --option weights={out}")


def _evaluate(weights: Path, data: Path, split: str, workers: int) -> dict[str, Any]:
    """AP of the new weights on a split's labelled frames (unlabelled ones are left out and counted)."""
    from lidarfuzz.io.kitti import open_kitti
    from lidarfuzz.suts.learned.evaluation import split_ap
    from lidarfuzz.suts.learned.sut import PillarsDetector
    from lidarfuzz.suts.learned.training import labelled_ids

    dataset = open_kitti(data, subset=split)
    labelled, unlabelled = labelled_ids(dataset)
    with PillarsDetector(weights=str(weights), threads=max(1, workers)) as sut:
        figures = split_ap(sut, (dataset.load(f) for f in labelled))
    if unlabelled:
        figures["warnings"] = [f"{len(unlabelled)} unlabelled frame(s) of the split left out", *figures["warnings"]]
    return figures
