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
    result = replay_finding(open_store(workspace), finding)
    f = result.finding
    console.print(f"finding {f['id']} of task {f['task_id']}: [bold]{f['kind']}[/] {f['class']} on frame "
                  f"{f['frame_id']} under {f['subtask']}@{f['severity']}\n  recorded: {escape(f['message'])}")
    if not result.same_system:
        console.print(f"[yellow]the system changed since: fingerprint {result.fingerprint_now[:12]} "
                      f"(recorded {result.fingerprint_recorded[:12]})[/]")
    table = Table("output", "recorded", "now", "same")
    for what, recorded, now in (("source (original)", result.source_recorded, result.source_now),
                                ("follow-up (mutant)", result.follow_recorded, result.follow_now)):
        same = now is not None and len(now) == len(recorded) and (len(now) == 0 or now.allclose(recorded, 1e-3))
        table.add_row(what, describe(recorded), describe(now), "yes" if same else "[yellow]no[/]")
    print_table(table)
    if result.failure_now is not None:
        console.print(f"system failure now: {result.failure_now.kind}: {escape(result.failure_now.message)}")
    for outcome in result.outcomes_now:
        state = "holds" if outcome.holds else f"violated ({len(outcome.violations)})"
        console.print(f"  {outcome.relation}: {state}")
        for v in outcome.violations[:10]:
            console.print(f"    - {escape(v.message)}")
    verdict = "[red]reproduced[/]" if result.reproduced else "[green]not reproduced[/]"
    console.print(f"{verdict} in {time.perf_counter() - start:.1f} s")


def describe(boxes: Any) -> str:
    """``3 Car, 1 Pedestrian``; ``no boxes``; ``(failed)`` for a run that produced none."""
    if boxes is None:
        return "(failed)"
    if len(boxes) == 0:
        return "no boxes"
    import numpy as np

    labels, counts = np.unique(boxes.labels, return_counts=True)
    return ", ".join(f"{n} {label}" for label, n in zip(labels, counts, strict=True))
