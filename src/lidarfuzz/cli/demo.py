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


#: The camera demo's image size (DeepTest's networks read far smaller inputs; 640×480 is a common camera).
CAMERA_SIZE = (640, 480)
#: The camera demo's guided search: Algorithm 1's tests after the transformations.
CAMERA_BUDGET = 100


def build_world(root: Path, frames: int, seed: int, *, sequence: bool = False,
                camera: tuple[int, int] | None = None, workers: int | None = None) -> tuple[Path, bool]:
    """The simulator's world — ``frames`` frames, with camera images of ``camera``'s size when
    given — under ``root``, generated on first use and reused while complete; returns the folder
    and whether it was generated now."""
    from lidarfuzz.sim.dataset import GenerationConfig, generate_dataset, is_complete

    config = GenerationConfig(frames=frames, seed=seed, sequence=sequence, camera=camera)
    if is_complete(root, config):
        return root, False
    what = "world and its camera images" if camera else "world"
    with console.status(f"generating the simulator's {what} ({frames} frames, seed {seed}) ..."):
        generate_dataset(root, config, overwrite=True, workers=workers)
    return root, True


def demo(
    workspace: Annotated[Path, typer.Option(help="Folder for the demo's data, store and report "
                                            "(env LIDARFUZZ_WORKSPACE).")] = DEFAULT_WORKSPACE,
    frames: Annotated[int, typer.Option(min=1, max=1000, help="Frames of the simulated world.")] = 40,
    seed: Annotated[int, typer.Option(help="Seed of the world and of the campaign.")] = 0,
    workers: Annotated[int | None, typer.Option(min=1, help="Worker processes (default: the CPU count).")] = None,
    camera: Annotated[bool, typer.Option("--camera", help="DeepTest's job instead: the world's camera images, the "
                                         "built-in DAVE-2-like steering network, the nine image transformations "
                                         "and a guided search.")] = False,
) -> None:
    """Run the main job on the built-in data: the classic pipeline against every operator family.

    Simulates the world (first run only), runs originals and mutants (the default operator set
    × severities 1, 3, 5) through the classic pipeline, checks every applicable metamorphic relation,
    prints the AP table and the violation summary and writes the HTML report.

    With --camera: renders the same world by its camera too, and tests the built-in steering network
    dave2 as DeepTest does (the nine transformations × severities 1, 3, 5 judged by Eq. 2 and 3,
    then Algorithm 1's coverage-guided search), printing Table 7 and writing the report.
    """
    if camera:
        raise typer.Exit(camera_demo(workspace, frames, seed, workers))
    from sqlalchemy import select

    from lidarfuzz.campaign.defaults import DEFAULT_OPERATORS, DEFAULT_SEVERITIES
    from lidarfuzz.campaign.spec import parse_campaign
    from lidarfuzz.campaign.tasks import create_task
    from lidarfuzz.cli.campaign import Placement, execute
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
    code = execute(str(workspace), task_id, placement=Placement("pool", workers))
    console.print(f"store: [bold]{(workspace / 'lidarfuzz.db').resolve()}[/]   world: [bold]{dataset_dir}[/]")
    console.print(f"next: [cyan]lidarfuzz status {task_id} --workspace {workspace}[/]   "
                  f"[cyan]lidarfuzz replay FINDING --workspace {workspace}[/]   "
                  f"[cyan]lidarfuzz run --help[/]")
    console.print(f"done in {time.perf_counter() - started:.1f} s")
    raise typer.Exit(code)


def camera_demo(workspace: Path, frames: int, seed: int, workers: int | None) -> int:
    """``lidarfuzz demo --camera``: DeepTest on the built-in world's camera; returns the exit code."""
    from sqlalchemy import select

    from lidarfuzz.campaign.camera import DEFAULT_TRANSFORMATIONS
    from lidarfuzz.campaign.spec import parse_campaign
    from lidarfuzz.campaign.tasks import create_task
    from lidarfuzz.cli.campaign import Placement, execute
    from lidarfuzz.io.options import DatasetOptions
    from lidarfuzz.store import Dataset, Model, Store
    from lidarfuzz.store.inventory import add_dataset, add_model

    started = time.perf_counter()
    name, model = f"sim-camera-s{seed}-n{frames}", "dave2"
    dataset_dir, fresh = build_world(workspace / "datasets" / name, frames, seed, camera=CAMERA_SIZE,
                                     workers=workers)
    state = "generated now" if fresh else "reused from an earlier run"
    console.rule(f"[bold]the simulator's world by its camera: {frames} images of {CAMERA_SIZE[0]}×{CAMERA_SIZE[1]} "
                 f"with steering labels ({state})")
    store = Store(workspace)
    with store.session() as s:
        have_data = s.scalar(select(Dataset).where(Dataset.name == name)) is not None
        have_model = s.scalar(select(Model).where(Model.name == model)) is not None
    if not have_data:
        add_dataset(store, name, dataset_dir, notes="the camera demo's simulated world",
                    options=DatasetOptions(modality="camera"))
    if not have_model:
        add_model(store, model, model, notes="the built-in DAVE-2-like steering network", modality="camera")
    spec = parse_campaign({"name": "camera demo", "kind": "camera", "dataset": name, "sut": model, "seed": seed,
                           "operators": [{"name": op, "severities": [1, 3, 5]} for op in DEFAULT_TRANSFORMATIONS],
                           "search": {"budget": CAMERA_BUDGET}})
    task_id = create_task(store, spec)
    console.rule(f"[bold]DeepTest: {model} × {len(DEFAULT_TRANSFORMATIONS)} transformations × severities 1, 3, 5, "
                 f"then a guided search of {CAMERA_BUDGET} tests")
    code = execute(str(workspace), task_id, placement=Placement("inline", workers))
    console.print(f"store: [bold]{(workspace / 'lidarfuzz.db').resolve()}[/]   world: [bold]{dataset_dir}[/]")
    console.print(f"next: [cyan]lidarfuzz status {task_id} --workspace {workspace}[/]   "
                  f"[cyan]lidarfuzz serve --workspace {workspace}[/]")
    console.print(f"done in {time.perf_counter() - started:.1f} s")
    return code
