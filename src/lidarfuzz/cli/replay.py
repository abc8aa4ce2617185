"""``lidarfuzz replay FINDING``: re-run one finding and show what differs from the record."""

import time
from typing import Any

from rich.markup import escape

from lidarfuzz.cli.common import WORKSPACE, WorkspaceOption, console, open_store, print_table


def replay(finding: int, workspace: WorkspaceOption = WORKSPACE) -> None:
    """Re-run one finding (same frame, operator params and system) and show what differs."""
    from rich.table import Table

    from lidarfuzz.campaign.replay import replay_finding

    start = time.perf_counter()
    store = open_store(workspace)
    if _is_camera(store, finding):
        _replay_camera(store, finding, start)
        return
    result = replay_finding(store, finding)
    f = result.finding
    console.print(f"finding {f['id']} of task {f['task_id']}: [bold]{f['kind']}[/] {f['class']} on frame "
                  f"{f['frame_id']} under {f['subtask']}@{f['severity']}\n  recorded: {escape(f['message'])}")
    if result.same_system:
        console.print(f"system: the same (fingerprint {result.fingerprint_now[:12]})")
    else:
        console.print(f"[yellow]system: changed since (fingerprint {result.fingerprint_now[:12]}, recorded "
                      f"{result.fingerprint_recorded[:12]})[/]")
    table = Table("output", "recorded", "now", "against the record", "answered again")
    repeated = result.repeated()
    for what, comparison in result.against_record().items():
        again = repeated[what]
        table.add_row(what, describe(comparison.before), describe(comparison.after),
                      "same" if comparison.same else f"[yellow]{escape(comparison.describe())}[/]",
                      "same" if again.same else f"[yellow]{escape(again.describe('first', 'second'))}[/]")
    print_table(table)
    if not result.deterministic:
        console.print("[yellow]the system answered the same frame differently the second time: it is "
                      "non-deterministic or stateful, so its findings cannot be trusted to reproduce[/]")
    if result.failure_now is not None:
        console.print(f"system failure now: {result.failure_now.kind}: {escape(result.failure_now.message)}")
    for outcome in result.outcomes_now:
        state = "holds" if outcome.holds else f"violated ({len(outcome.violations)})"
        console.print(f"  {outcome.relation}: {state}")
        for v in outcome.violations[:10]:
            console.print(f"    - {escape(v.message)}")
    console.print(f"verdict now: {'violated again' if result.violated_now else 'not violated'}")
    colour = "red" if result.reproduced else "green"
    console.print(f"[{colour}]{escape(result.verdict)}[/] in {time.perf_counter() - start:.1f} s")


def describe(boxes: Any) -> str:
    """``3 Car, 1 Pedestrian``; ``no boxes``; ``(failed)`` for a run that produced none."""
    if boxes is None:
        return "(failed)"
    if len(boxes) == 0:
        return "no boxes"
    import numpy as np

    labels, counts = np.unique(boxes.labels, return_counts=True)
    return ", ".join(f"{n} {label}" for label, n in zip(labels, counts, strict=True))


def _is_camera(store: Any, finding: int) -> bool:
    from lidarfuzz.store.models import Finding, Task

    with store.session() as s:
        row = s.get(Finding, finding)
        task = s.get(Task, row.task_id) if row is not None else None
        return task is not None and task.options.kind == "camera"


def _replay_camera(store: Any, finding: int, start: float) -> None:
    """A camera finding: the steering on the original and transformed image, recorded and now."""
    from rich.table import Table

    from lidarfuzz.campaign.camera import replay_camera

    result = replay_camera(store, finding)
    f = result.finding
    console.print(f"finding {f['id']} of task {f['task_id']}: [bold]{f['kind']}[/] on image {f['frame_id']} under "
                  f"{f['subtask']}@{f['severity']}\n  recorded: {escape(f['message'])}")
    console.print("system: the same" if result.same_system else
                  f"[yellow]system: changed since (fingerprint {result.fingerprint_now[:12]}, recorded "
                  f"{result.fingerprint_recorded[:12]})[/]")
    console.print(f"label: {'none' if result.label is None else f'{result.label:+.6f}'}")
    table = Table("steering on", "recorded", "now", "answered again")
    for k, what in enumerate(("the original image", "the transformed image")):
        table.add_row(what, *[("–" if v[k] is None else f"{v[k]:+.6f}") for v in
                              (result.recorded, result.now, result.again)])
    print_table(table)
    if result.failure_now is not None:
        console.print(f"system failure now: {result.failure_now.kind}: {escape(result.failure_now.message)}")
    for outcome in result.outcomes_now:
        console.print(f"  {outcome.relation}: {'holds' if outcome.holds else 'violated'}")
        for v in outcome.violations:
            console.print(f"    - {escape(v.message)}")
    colour = "red" if result.reproduced else "green"
    console.print(f"[{colour}]{escape(result.verdict)}[/] in {time.perf_counter() - start:.1f} s")
