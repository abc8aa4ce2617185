"""``lidarfuzz demo``: the main job on the built-in default data.

Until the operators and campaign engine land, the demo generates the simulator's
world (a labelled log in KITTI layout, cached in the workspace and reused), inspects
it, and carries its frames through every supported format and log type, reading
each back and checking that nothing changed — the ground everything else stands on.
"""

from __future__ import annotations

import os
import shutil
import statistics
import time
import warnings
from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from lidarfuzz.io import open_dataset, read_frame, write_frame
from lidarfuzz.io.inspect import inspect_source
from lidarfuzz.scene.scene import Scene

DEFAULT_WORKSPACE = Path(os.environ.get("LIDARFUZZ_WORKSPACE", "lidarfuzz-workspace"))
FRAME_SUFFIXES = (".bin", ".pcd", ".ply", ".las", ".laz", ".npy", ".npz")
LOG_KINDS = (("ros1", "log.bag"), ("mcap", "log.mcap"), ("ros2", "log-ros2"))


def build_world(root: Path, frames: int, seed: int) -> tuple[Path, bool]:
    """The simulator's world — a sequence of ``frames`` frames — under ``root``, generated on
    first use and reused while complete; returns the folder and whether it was generated now."""
    from lidarfuzz.cli.app import console
    from lidarfuzz.sim.dataset import GenerationConfig, generate_dataset, is_complete

    config = GenerationConfig(frames=frames, seed=seed, sequence=True)
    if is_complete(root, config):
        return root, False
    with console.status(f"generating the simulator's world ({frames} frames, seed {seed}) ..."):
        generate_dataset(root, config, overwrite=True)
    return root, True


def _median_ms(fn: object, repeat: int = 5) -> float:
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        fn()  # type: ignore[operator]
        times.append((time.perf_counter() - start) * 1e3)
    return statistics.median(times)


def _same(a: Scene, b: Scene, channels_kept: int | None = None) -> bool:
    if channels_kept is not None:
        return bool((a.points.data[:, :channels_kept] == b.points.data[:, :channels_kept]).all())
    return a.points == b.points


def register(app: typer.Typer) -> None:
    @app.command()
    def demo(
        workspace: Annotated[Path, typer.Option(help="Folder for the demo's data and outputs "
                                                "(env LIDARFUZZ_WORKSPACE).")] = DEFAULT_WORKSPACE,
        frames: Annotated[int, typer.Option(min=2, max=1000, help="Frames in the simulated log.")] = 10,
        seed: Annotated[int, typer.Option(help="Seed of the simulated world.")] = 0,
    ) -> None:
        """Run the main job on the built-in data: simulate the world, inspect it, carry it through every format.

        Every frame format and log type is written, read back and compared with the original.
        """
        from lidarfuzz.cli.app import console
        from lidarfuzz.cli.info import render

        started = time.perf_counter()
        dataset_dir, fresh = build_world(workspace / "datasets" / f"sim-world-s{seed}-n{frames}", frames, seed)
        state = "generated now" if fresh else "cached from an earlier run"
        console.rule(f"[bold]1. the simulator's world ({state}; KITTI layout, a log with timestamps and poses)")
        report = inspect_source(dataset_dir)
        render(report)

        console.rule("[bold]2. every format: write, read back, compare")
        out = workspace / "demo-formats"
        if out.exists():
            shutil.rmtree(out)
        out.mkdir(parents=True)
        source = open_dataset(dataset_dir)
        first = source[0]
        # Logs store time as integer nanoseconds: timestamps are compared to 1 ns.
        table = Table("format", "file", "size", "read (ms)", "exact")
        for suffix in FRAME_SUFFIXES:
            path = out / f"{first.frame_id}{suffix}"
            write_frame(path, first)
            with warnings.catch_warnings():
                warnings.simplefilter("error")
                back = read_frame(path)
            ms = _median_ms(lambda p=path: read_frame(p))
            exact = _same(first, back, 4 if suffix == ".bin" else None)
            if suffix == ".npz":
                exact = exact and back.boxes == first.boxes and back.calib == first.calib
            table.add_row(suffix[1:], path.name, f"{path.stat().st_size / 1e6:.2f} MB", f"{ms:.2f}",
                          "[green]yes[/]" if exact else "[red]NO[/]")
        scenes = list(source)
        for kind, name in LOG_KINDS:
            from lidarfuzz.io.logs.bags import write_log

            path = out / name
            write_log(path, scenes, kind=kind)  # type: ignore[arg-type]
            start = time.perf_counter()
            back_scenes = list(open_dataset(path))
            ms = (time.perf_counter() - start) * 1e3 / len(back_scenes)
            exact = len(back_scenes) == len(scenes) and all(
                _same(a, b) and abs((a.timestamp or 0.0) - (b.timestamp or 0.0)) <= 1e-9
                for a, b in zip(scenes, back_scenes, strict=True)
            )
            size = sum(p.stat().st_size for p in path.rglob("*")) if path.is_dir() else path.stat().st_size
            table.add_row(kind, f"{name} ({len(scenes)} frames)", f"{size / 1e6:.2f} MB", f"{ms:.2f}/frame",
                          "[green]yes[/]" if exact else "[red]NO[/]")
        console.print(table)
        console.print(f"\nsimulated world: [bold]{dataset_dir}[/]\nconverted files: [bold]{out}[/]")
        console.print("try: [cyan]lidarfuzz info " + str(out / "log.bag") + "[/]   "
                      "[cyan]lidarfuzz convert " + str(dataset_dir) + " /tmp/sample.mcap[/]")
        console.print(f"done in {time.perf_counter() - started:.1f} s")
