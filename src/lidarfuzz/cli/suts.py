"""``lidarfuzz suts`` (what can be tested) and ``lidarfuzz detect`` (run one on data)."""

from pathlib import Path
from typing import Annotated, Any

import typer

from lidarfuzz.cli.common import Column, JsonOption, LayoutOption, PlainOption, console, print_listing, print_table


def suts_command(as_json: JsonOption = False, plain: PlainOption = False) -> None:
    """List the built-in and plugin systems under test and the spec forms that name others: systems
    that detect frame by frame, systems that consume logs in order (controllers), and steering
    systems that answer camera images (the camera task's)."""
    from lidarfuzz.suts.registry import available, available_camera, available_sequences

    rows: list[list[str]] = []
    records: list[dict[str, Any]] = []
    kinds: list[tuple[str, dict[str, Any]]] = [("frames", available()), ("logs", available_sequences()),
                                               ("images", available_camera())]
    for kind, systems in kinds:
        for name, cls in sorted(systems.items()):
            doc = (cls.__doc__ or "").strip().splitlines()
            rows.append([name, doc[0] if doc else "", cls.version, kind])
            records.append({"spec": name, "system": doc[0] if doc else "", "version": cls.version, "consumes": kind})
    print_listing([Column("spec", name=True), Column("system"), Column("version"), Column("consumes")], rows, records,
                  as_json=as_json, plain=plain, footer=(
                      "Other systems: [cyan]package.module:callable[/] (a detector function or SUT class), "
                      "[cyan]subprocess:'COMMAND {points} {output}'[/], [cyan]worker:COMMAND[/], "
                      "[cyan]onnx:PATH[/]; options as [cyan]NAME?key=value&…[/]. Protocol: docs/suts.md. Systems that "
                      "consume logs: a registered name, [cyan]module:callable[/] or [cyan]worker:COMMAND[/] "
                      "answering resets (docs/structural.md). Steering systems (images): a registered name, "
                      "[cyan]onnx:PATH[/], [cyan]worker:COMMAND[/] or [cyan]module:name[/] (a torch module or "
                      "SteeringSystem; docs/camera.md)"))


def detect_command(
    sut: Annotated[str, typer.Argument(help="The system under test (see lidarfuzz suts).")],
    src: Annotated[Path, typer.Argument(help="Frame file, data set folder or log (never modified).")],
    out: Annotated[Path, typer.Option("--out", help="Folder for one KITTI detection file per frame.")],
    timeout: Annotated[float, typer.Option(help="Seconds per frame before the system is restarted.")] = 60.0,
    isolate: Annotated[bool, typer.Option(help="Run the system in a worker process (enforces --timeout "
                                            "for in-process Python systems).")] = False,
    limit: Annotated[int | None, typer.Option(help="Only the first N frames.")] = None,
    overwrite: Annotated[bool, typer.Option(help="Replace existing detection files.")] = False,
    all_boxes: Annotated[bool, typer.Option("--all", help="Keep detections outside the camera's field of "
                                            "view (by default they are left out, as KITTI results and "
                                            "OpenPCDet's are).")] = False,
    layout: LayoutOption = None,
) -> None:
    """Run a system under test on every frame and write its detections as KITTI label files with
    scores (``OUT/<frame id>.txt``), ready for ``lidarfuzz eval``. Failures are listed, not fatal."""
    from rich.progress import Progress
    from rich.table import Table

    from lidarfuzz.io.atomic import write_text
    from lidarfuzz.io.kitti import format_labels
    from lidarfuzz.io.open import open_dataset
    from lidarfuzz.io.options import options_from_flags
    from lidarfuzz.scene.calib import KittiCalibration
    from lidarfuzz.suts.guard import IsolatedSut, run_guarded
    from lidarfuzz.suts.registry import create

    dataset = open_dataset(src, options=options_from_flags(layout))
    ids = list(dataset.frame_ids())[:limit]
    existing = [frame_id for frame_id in ids if (out / f"{frame_id}.txt").exists()]
    if existing and not overwrite:
        raise typer.BadParameter(f"{out / existing[0]}.txt exists (and {len(existing) - 1} more); add --overwrite",
                                 param_hint="--out")
    out.mkdir(parents=True, exist_ok=True)
    system = IsolatedSut(sut, timeout=timeout) if isolate else create(sut)
    if not isolate and hasattr(system, "timeout"):
        system.timeout = timeout  # type: ignore[attr-defined]
    failures: list[tuple[str, str, str]] = []
    times: list[float] = []
    with system, Progress(console=console, transient=True) as progress:
        task = progress.add_task(f"detecting ({system.name})", total=len(ids))
        for frame_id in ids:
            target = out / f"{frame_id}.txt"
            scene = dataset.load(frame_id)
            result = run_guarded(system, scene)
            times.append(result.seconds)
            if result.failure is not None:
                failures.append((frame_id, result.failure.kind.value, result.failure.message))
            else:
                calib = scene.calib or KittiCalibration.default()
                boxes = result.output
                assert boxes is not None  # run_guarded gives an output whenever it gives no failure
                if not all_boxes and len(boxes):
                    boxes = boxes.select(calib.in_view(boxes.centers))
                text = format_labels(boxes, calib, complete=True)
                write_text(target, text, overwrite=overwrite)
            progress.advance(task)
    ok = len(ids) - len(failures)
    median = sorted(times)[len(times) // 2] * 1000 if times else 0.0
    console.print(f"{system.name}: {ok}/{len(ids)} frame(s) → {out} (median {median:.1f} ms per frame)")
    if failures:
        table = Table("frame", "failure", "message", title="failures")
        for row in failures:
            table.add_row(*row)
        print_table(table)
