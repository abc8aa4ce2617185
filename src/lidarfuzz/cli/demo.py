"""``lidarfuzz demo``: the main job on the built-in default data.

It builds (or reuses) the simulator's world — independent labelled street scenes in KITTI
layout, as KITTI's object benchmark has them — records it and the classic obstacle pipeline
in the workspace's store, and runs a campaign: every operator family at severities 1, 3 and
5, every relation that applies to each operator. It prints the thesis's AP table and the
violation summary, writes the HTML report (with JSON, CSV and JUnit XML beside it) and says
where. A second run reuses the world and, through the SUT output cache, every output.
"""

import time
from pathlib import Path
from typing import Annotated

import typer

from lidarfuzz.cli.common import console
from lidarfuzz.settings import settings

DEFAULT_WORKSPACE = Path(settings().workspace)


def build_world(root: Path, frames: int, seed: int, *, sequence: bool = False) -> tuple[Path, bool]:
    """The simulator's world — ``frames`` frames — under ``root``, generated on first use and
    reused while complete; returns the folder and whether it was generated now."""
    from lidarfuzz.sim.dataset import GenerationConfig, generate_dataset, is_complete

    config = GenerationConfig(frames=frames, seed=seed, sequence=sequence)
    if is_complete(root, config):
        return root, False
    with console.status(f"generating the simulator's world ({frames} frames, seed {seed}) ..."):
        generate_dataset(root, config, overwrite=True)
    return root, True


def demo(
    workspace: Annotated[Path, typer.Option(help="Folder for the demo's data, store and report "
                                            "(env LIDARFUZZ_WORKSPACE).")] = DEFAULT_WORKSPACE,
    frames: Annotated[int, typer.Option(min=1, max=1000, help="Frames of the simulated world.")] = 40,
    seed: Annotated[int, typer.Option(help="Seed of the world and of the campaign.")] = 0,
    workers: Annotated[int | None, typer.Option(min=1, help="Worker processes (default: the CPU count).")] = None,
) -> None:
    """Run the main job on the built-in data: the classic pipeline against every operator family.

    Simulates the world (first run only), runs originals and mutants (the default operator set
    × severities 1, 3, 5) through the classic pipeline, checks every applicable metamorphic relation,
    prints the AP table and the violation summary and writes the HTML report.
    """
    from sqlalchemy import select

    from lidarfuzz.campaign.defaults import DEFAULT_OPERATORS, DEFAULT_SEVERITIES
    from lidarfuzz.campaign.spec import parse_campaign
    from lidarfuzz.campaign.tasks import create_task
    from lidarfuzz.cli.campaign import execute
    from lidarfuzz.store import Dataset, Model, Store
    from lidarfuzz.store.inventory import add_dataset, add_model

    started = time.perf_counter()
    name = f"sim-world-s{seed}-n{frames}"
    dataset_dir, fresh = build_world(workspace / "datasets" / name, frames, seed)
    state = "generated now" if fresh else "reused from an earlier run"
    console.rule(f"[bold]the simulator's world: {frames} labelled frames in KITTI layout ({state})")
    store = Store(workspace)
    with store.session() as s:
        have_data = s.scalar(select(Dataset).where(Dataset.name == name)) is not None
        have_model = s.scalar(select(Model).where(Model.name == "classic")) is not None
    if not have_data:
        add_dataset(store, name, dataset_dir, notes="the demo's simulated world")
    if not have_model:
        add_model(store, "classic", "classic", notes="the classic Apollo-style obstacle pipeline")
    spec = parse_campaign({"name": "demo", "dataset": name, "sut": "classic", "seed": seed,
                           "operators": "auto"})
    task_id = create_task(store, spec)
    console.rule(f"[bold]campaign: classic pipeline × the default set ({len(DEFAULT_OPERATORS)} operators) × "
                 f"severities {', '.join(map(str, DEFAULT_SEVERITIES))}")
    code = execute(str(workspace), task_id, workers=workers, inline=False)
    console.print(f"store: [bold]{(workspace / 'lidarfuzz.db').resolve()}[/]   world: [bold]{dataset_dir}[/]")
    console.print(f"next: [cyan]lidarfuzz status {task_id} --workspace {workspace}[/]   "
                  f"[cyan]lidarfuzz replay FINDING --workspace {workspace}[/]   "
                  f"[cyan]lidarfuzz run --help[/]")
    console.print(f"done in {time.perf_counter() - started:.1f} s")
    raise typer.Exit(code)
