"""``lidarfuzz profile``: the training-set profile KMNC, NBC and SNAC need."""

from pathlib import Path
from typing import Annotated

import typer

from lidarfuzz.cli.common import console


def profile(
    sut: Annotated[str, typer.Argument(help="A SUT built on a torch module (e.g. pillars).")],
    data: Annotated[Path, typer.Argument(help="Its training data (any data set lidarfuzz reads).")],
    split: Annotated[str, typer.Option(help="KITTI split to use (ImageSets/SPLIT.txt); all frames if absent.")
                     ] = "train",
    frames: Annotated[int | None, typer.Option(min=1, help="Only the first N frames of the split.")] = None,
    batch: Annotated[int, typer.Option(min=1, help="Frames per forward pass.")] = 4,
    out: Annotated[Path | None, typer.Option(help="Write here instead of the profile cache.")] = None,
    option: Annotated[list[str] | None, typer.Option(help="SUT option k=v (repeatable).")] = None,
) -> None:
    """Profile every watched neuron (min, max, mean, std) over training data, keyed by the model's
    fingerprint, for the KMNC / NBC / SNAC criteria of `lidarfuzz run --kind guided|fuzz`."""
    from rich.progress import Progress

    from lidarfuzz.campaign.coverage_search import torch_module
    from lidarfuzz.coverage import ActivationRecorder, NeuronProfile, ProfileStore, module_fingerprint
    from lidarfuzz.io.open import open_dataset
    from lidarfuzz.operators.mutate import parse_assignments
    from lidarfuzz.suts.learned.sut import import_torch
    from lidarfuzz.suts.registry import create

    torch = import_torch()
    system = create(sut, **parse_assignments(option or []))
    system.load()
    module = torch_module(system)
    dataset = open_dataset(str(data))
    ids = list(dataset.frame_ids())
    split_file = data / "ImageSets" / f"{split}.txt"
    if split_file.exists():
        wanted = set(split_file.read_text().split())
        ids = [f for f in ids if f in wanted]
    ids = ids[:frames] if frames else ids
    fingerprint = module_fingerprint(module)
    recorder = ActivationRecorder(module)
    result = NeuronProfile(fingerprint)
    with Progress(console=console) as bars, torch.inference_mode():
        bar = bars.add_task("profiling", total=len(ids))
        for start in range(0, len(ids), batch):
            scenes = [dataset.load(f) for f in ids[start:start + batch]]
            recorder.clear()
            with recorder:
                system.detect_batch(scenes)
            result.update(recorder.values())
            bars.update(bar, advance=len(scenes))
    path = result.save(out) if out else ProfileStore().put(fingerprint, result)
    console.print(f"profile of {result.total_neurons} neurons in {len(result.layers)} layers over "
                  f"{result.inputs} frames → {path} (model {fingerprint})")
