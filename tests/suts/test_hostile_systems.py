"""Hostile systems under test cannot fool or harm lidarfuzz.

Every system here is ``tests/suts/hostile_worker.py`` (or a Python SUT below) misbehaving in one
way on frame ``000001`` and answering correctly elsewhere. Its correct answer is one Car at
``x = 10 + int(frame_id)``, a function of the frame id alone, so the expected value of every
frame is known without running anything: a frame given another frame's answer shows at once.
Each case asserts the failure recorded for the hostile frame, that every other frame got its
own answer (as the correct system, kind ``none``, gives), that no process of the system's
groups survives ``close()``, and — for the answers that are too big — that lidarfuzz's own
allocations stayed bounded (tracemalloc's peak).
"""

from __future__ import annotations

import os
import sys
import time
import tracemalloc
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from lidarfuzz.scene.points import PointCloud
from lidarfuzz.scene.scene import Scene
from lidarfuzz.suts.base import FailureKind, SutResult, SystemUnderTest
from lidarfuzz.suts.external import SubprocessSut, WorkerSut
from lidarfuzz.suts.guard import IsolatedSut, run_guarded
from lidarfuzz.suts.processes import group_members, parse_size

HOSTILE = Path(__file__).with_name("hostile_worker.py")
TAG = f"test-{os.getpid()}"  # on the hostile programs' command lines: ours, not another run's
PY = sys.executable
FRAMES = [Scene(PointCloud(np.zeros((8, 4), np.float32)), frame_id=f"{i:06d}") for i in range(4)]
BAD = "000001"
TIMEOUT = 1.0
CRASH, TIMED_OUT, INVALID = FailureKind.CRASH, FailureKind.TIMEOUT, FailureKind.INVALID_OUTPUT

# kind: (failure on frame 000001, a fragment of its message, whether the worker is restarted)
WORKER_CASES: dict[str, tuple[FailureKind | None, str, bool]] = {
    "none": (None, "", False),
    "crash": (CRASH, "exit code 3", True),
    "segfault": (CRASH, "killed by signal 11 (SIGSEGV)", True),
    "abort": (CRASH, "killed by signal 6 (SIGABRT)", True),
    "exit0": (CRASH, "exit code 0 before answering", True),
    "hang": (TIMED_OUT, "no answer within 1 s", True),
    "slow": (TIMED_OUT, "no answer within 1 s", True),  # its late answer dies with it: frame 2 gets 12, not 11
    "leak": (CRASH, "out of memory (exit code 1; memory_limit 256 MiB)", True),
    "fork-linger": (None, "", False),
    "fork-holds-pipe": (CRASH, "exit code 3 before answering", True),  # not a timeout: the child holds stdout
    "stray": (INVALID, "answered a line that is not JSON", True),
    "garbage": (INVALID, "answered a line that is not JSON", True),
    "huge": (INVALID, "answered a line longer than max_answer_bytes (4 MiB)", True),
    "boxes100k": (INVALID, "answered a line longer than max_answer_bytes (4 MiB)", True),
    "nan": (INVALID, "NaN or infinite geometry", False),
    "inf": (INVALID, "NaN or infinite geometry", False),
    "negative": (INVALID, "negative size", False),
    "wrong-id": (INVALID, "answered id 'someone-else#0' to request '000001#2'", True),
    "no-id": (INVALID, 'answered without an "id" to request \'000001#2\': every answer must echo', True),
    "no-newline": (TIMED_OUT, "bytes of an answer without its newline", True),
}


def x_of(result: SutResult[Any]) -> float | None:
    """The first box's x of a result (None for a failure)."""
    return None if result.output is None else float(result.output.centers[0][0])


def own_answers() -> list[float]:
    """What the correct system answers on FRAMES: x = 10 + the frame's number."""
    return [10.0 + i for i in range(len(FRAMES))]


def run_all(sut: Any) -> tuple[list[SutResult[Any]], set[int]]:
    """Every frame through the guard (as a campaign calls the system), and the process groups seen."""
    results, groups = [], set()
    for frame in FRAMES:
        results.append(run_guarded(sut, frame))
        process = getattr(sut, "_process", None)
        if process is not None and getattr(process, "pid", None):
            groups.add(process.pid)
    return results, groups


def survivors(groups: set[int], wait: float = 3.0) -> list[int]:
    """Live processes of ``groups``, given ``wait`` s for the killed ones to finish dying (a
    process sent SIGKILL still shows as running for a moment)."""
    deadline = time.monotonic() + wait
    while True:
        alive = [pid for group in groups for pid in group_members(group)]
        if not alive or time.monotonic() > deadline:
            return alive
        time.sleep(0.02)


@pytest.mark.parametrize("kind", list(WORKER_CASES))
def test_a_hostile_worker_fails_its_frame_only_and_leaves_nothing(kind: str) -> None:
    failure, fragment, restarted = WORKER_CASES[kind]
    timeout = 5.0 if kind == "boxes100k" else TIMEOUT  # writing 8 MB of JSON takes the program a while
    sut = WorkerSut(f"{PY} {HOSTILE} {kind} --on {BAD}", timeout=timeout, memory_limit="256MiB")
    tracemalloc.start()
    try:
        results, groups = run_all(sut)
        _, peak = tracemalloc.get_traced_memory()
        if kind == "fork-linger":  # its children are alive until close()
            assert len(survivors(groups, wait=0)) >= 2
    finally:
        tracemalloc.stop()
        sut.close()
    bad = results[1].failure
    if failure is None:
        assert bad is None
    else:
        assert bad is not None and bad.kind is failure and fragment in bad.message, bad
    expected = own_answers()
    if failure is not None:
        expected[1] = None  # type: ignore[call-overload]
    assert [x_of(r) for r in results] == expected  # every other frame its own answer, none shifted
    assert sut.restarts == (1 if restarted else 0)
    assert survivors(groups) == []  # no process of the system's groups outlives close()
    # a 64 MiB line and 100,000 boxes (8 MB of JSON) are refused after reading at most 4 MiB + one read
    assert peak < 16 << 20, f"lidarfuzz held {peak / 2**20:.1f} MiB"


def test_a_worker_past_its_cpu_limit_is_stopped_by_the_kernel() -> None:
    # a busy loop on frame 1 with a 10 s timeout but cpu_limit=1: SIGXCPU after about one CPU second
    start = time.perf_counter()
    with WorkerSut(f"{PY} {HOSTILE} spin --on {BAD}", timeout=10, cpu_limit=1) as sut:
        results, groups = run_all(sut)
    assert time.perf_counter() - start < 8  # well before the wall-clock timeout
    failure = results[1].failure
    assert failure is not None and failure.kind is TIMED_OUT
    assert "used more than its cpu_limit of 1 CPU seconds (killed by signal 24 (SIGXCPU))" in failure.message
    assert [x_of(r) for r in results] == [10.0, None, 12.0, 13.0]
    assert survivors(groups) == []


def test_the_protocol_failure_names_what_to_echo() -> None:
    with WorkerSut(f"{PY} {HOSTILE} no-id", timeout=TIMEOUT) as sut:
        failure = run_guarded(sut, FRAMES[0]).failure
    assert failure is not None and failure.kind is INVALID
    assert 'every answer must echo the request\'s "id" field (worker protocol, docs/suts.md)' in failure.message
    assert failure.detail.startswith("answer line (")  # the line shown, for the author


def test_max_boxes_is_a_worker_option_checked_before_building_arrays() -> None:
    # (100,000 boxes under the default limits hit max_answer_bytes first, above; the benchmark shows
    # them under a 16 MiB line limit.) The correct answer's one box against max_boxes=0:
    with WorkerSut(f"{PY} {HOSTILE} none", name="hostile", timeout=5, max_boxes=0) as sut:
        failure = run_guarded(sut, FRAMES[0]).failure
        assert sut.restarts == 0  # a well-framed answer: the worker lives on
    assert failure is not None and failure.kind is INVALID
    assert failure.message == "hostile answer: 1 detections, more than max_boxes=0 (a SUT option)"


@pytest.mark.parametrize(("kind", "failure", "fragment"), [
    ("none", None, ""),
    ("crash", CRASH, "exit code 3"),
    ("hang", TIMED_OUT, "no answer within 1 s"),
    ("leak", CRASH, "out of memory"),
    ("fork-linger", None, ""),
    ("fork-holds-pipe", None, ""),  # it answers and exits 0; its child keeps stderr: no false timeout
    ("garbage", INVALID, "is not JSON"),
    ("huge", INVALID, "more than max_answer_bytes (4 MiB)"),
])
def test_a_hostile_one_shot_program(kind: str, failure: FailureKind | None, fragment: str) -> None:
    sut = SubprocessSut(f"{PY} {HOSTILE} {kind} --on {BAD} --tag {TAG} --oneshot {{points}} {{output}} {{frame_id}}",
                        timeout=TIMEOUT, memory_limit="256MiB")
    results = [run_guarded(sut, frame) for frame in FRAMES]
    bad = results[1].failure
    if failure is None:
        assert bad is None
    else:
        assert bad is not None and bad.kind is failure and fragment in bad.message, bad
    expected = own_answers()
    if failure is not None:
        expected[1] = None  # type: ignore[call-overload]
    assert [x_of(r) for r in results] == expected
    assert _children_named(TAG) == []  # every run's group was killed after it


def _children_named(fragment: str, wait: float = 3.0) -> list[int]:
    """Live processes whose command line holds ``fragment``, given ``wait`` s to finish dying."""
    deadline = time.monotonic() + wait
    while True:
        found = _named(fragment)
        if not found or time.monotonic() > deadline:
            return found
        time.sleep(0.02)


def _named(fragment: str) -> list[int]:
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            cmdline = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode("utf-8", "replace")
            state = (entry / "stat").read_text().rpartition(")")[2].split()[0]
        except OSError:
            continue
        if fragment in cmdline and state != "Z":
            found.append(int(entry.name))
    return found


# -- an in-process Python system, hosted by IsolatedSut -------------------------------------
class LeaksThenForksAndHangs(SystemUnderTest[Scene, Any]):
    """On frame 000001 allocates 32 MiB blocks until its memory runs out; on frame 000003 starts
    a program of its own (``sleep``), then hangs."""

    name = "leaks-then-forks-and-hangs"

    def __init__(self) -> None:
        self.kept: list[bytearray] = []

    def detect(self, sample: Scene) -> Any:
        import subprocess

        from lidarfuzz.scene.boxes import Boxes3D

        if sample.frame_id == BAD:
            while len(self.kept) < 64:  # 2 GiB at most, should the limit fail to stop it
                self.kept.append(bytearray(32 << 20))
        if sample.frame_id == "000003":
            subprocess.Popen(["sleep", "3600"])
            time.sleep(3600)
        index = int(sample.frame_id)
        return Boxes3D.create([[10.0 + index, 0, -1]], [[4, 1.8, 1.5]], [0.0], ["Car"], scores=[0.9])


def test_an_isolated_python_system_out_of_memory_then_hanging_with_a_child() -> None:
    sut = IsolatedSut(f"{__name__}:LeaksThenForksAndHangs", timeout=2, memory_limit="1GiB")
    try:
        results, groups = run_all(sut)
    finally:
        sut.close()
    leak, hang = results[1].failure, results[3].failure
    assert leak is not None and leak.kind is CRASH and leak.message.startswith("out of memory"), leak
    assert hang is not None and hang.kind is TIMED_OUT, hang
    assert [x_of(r) for r in results] == [10.0, None, 12.0, None]  # the worker lived on after its MemoryError
    assert survivors(groups) == []  # the hung worker's `sleep 3600` was killed with it


def test_an_isolated_worker_program_goes_with_its_host() -> None:
    # a worker: system inside an IsolatedSut, hanging on frame 1 past the host's timeout (the
    # worker's own timeout is longer): the host is stopped, and the program it started with it
    options = {"timeout": 60}
    sut = IsolatedSut(f"worker:{PY} {HOSTILE} hang --on {BAD} --tag {TAG}", timeout=2, options=options)
    program = f"hang --on {BAD} --tag {TAG}"
    try:
        results = [run_guarded(sut, FRAMES[0])]
        assert _named(program)  # the program runs (so the check below can fail)
        results.append(run_guarded(sut, FRAMES[1]))
    finally:
        sut.close()
    assert [x_of(results[0]), results[1].failure and results[1].failure.kind] == [10.0, TIMED_OUT]
    assert _children_named(program) == []


def test_a_stray_line_in_a_campaign_is_one_finding_and_no_result_shifts(tmp_path: Path) -> None:
    # the escape: one extra stdout line shifted every later answer onto the wrong frame.
    # Here frame 000001 prints one (original and mutant); each stored result holds its own frame's box
    from sqlalchemy import select

    from lidarfuzz.campaign.executor import InlineExecutor
    from lidarfuzz.campaign.runner import run_task
    from lidarfuzz.campaign.spec import parse_campaign
    from lidarfuzz.campaign.tasks import create_task
    from lidarfuzz.store import Finding, FrameResult, Status, Store
    from lidarfuzz.store.boxes import StoredBoxes

    data = tmp_path / "data"
    (data / "velodyne").mkdir(parents=True)
    for i in range(3):
        np.random.default_rng(i).normal(size=(200, 4)).astype(np.float32).tofile(data / "velodyne" / f"{i:06d}.bin")
    store = Store(tmp_path / "ws")
    spec = parse_campaign({"dataset": str(data), "sut": f"worker:{PY} {HOSTILE} stray --on {BAD} --tag {TAG}",
                           "operators": [{"name": "rotate_z", "severities": [3]}]})
    task_id = create_task(store, spec, sut_options={"timeout": 10})
    assert run_task(store, task_id, executor=InlineExecutor()).status == Status.DONE
    with store.session() as s:
        rows = s.execute(select(FrameResult.frame_id, FrameResult.boxes, FrameResult.labels,
                                FrameResult.failure)).all()
        kinds = s.scalars(select(Finding.kind)).all()
    assert len(rows) == 6  # 3 frames x (original, rotate_z)
    for frame_id, boxes, labels, failure in rows:
        if frame_id == BAD:
            assert boxes is None and failure is not None and failure.kind == "invalid_output"
        else:
            assert failure is None and StoredBoxes(boxes, labels).boxes().centers[0][0] == 10 + int(frame_id)
    assert kinds.count("invalid_output") == 2  # (the fixed box also breaks rotate_z's equivariance)
    store.close()
    assert _children_named(TAG) == []  # the campaign closed the system: nothing outlives it


def test_an_in_process_detector_answering_too_many_boxes_is_an_invalid_output() -> None:
    from lidarfuzz.scene.boxes import Boxes3D
    from lidarfuzz.suts.python import PythonSut

    def flood(scene: Scene) -> Boxes3D:  # 20,000 valid boxes: twice the default max_boxes (10,000)
        n = 20_000
        return Boxes3D.create(np.tile([10.0, 0, -1], (n, 1)), np.tile([4, 1.8, 1.5], (n, 1)), np.zeros(n),
                              ["Car"] * n, scores=np.full(n, 0.9))

    refused = run_guarded(PythonSut(flood), FRAMES[0]).failure
    assert refused is not None and refused.kind is INVALID
    assert refused.message == "20000 detections, more than max_boxes=10000 (a SUT option)"
    assert run_guarded(PythonSut(flood, max_boxes=20_000), FRAMES[0]).ok  # the limit is the system's option


def test_limits_are_options_with_one_line_errors() -> None:
    assert parse_size("256MiB", "memory_limit") == 256 << 20
    assert parse_size("1.5k", "memory_limit") == 1536
    assert parse_size(0, "memory_limit") is None and parse_size("none", "memory_limit") is None
    with pytest.raises(ValueError, match="memory_limit: expected a size such as 8GiB"):
        WorkerSut("prog", memory_limit="lots")
    with pytest.raises(ValueError, match="max_answer_bytes: must be greater than 0"):
        WorkerSut("prog", max_answer_bytes=0)
    with pytest.raises(ValueError, match="max_boxes: expected a whole number"):
        SubprocessSut("prog {points} {output}", max_boxes=-1)
    with pytest.raises(ValueError, match="cpu_limit: expected seconds > 0"):
        WorkerSut("prog", cpu_limit=0)
