"""The campaign engine: plan, run, commit, cache, cancel, resume, crash isolation."""

from __future__ import annotations

import hashlib
import sys
import threading
from pathlib import Path

import pytest
from sqlalchemy import Engine, event, func, select

from lidarfuzz.campaign.executor import InlineExecutor, ProcessExecutor
from lidarfuzz.campaign.replay import replay_finding
from lidarfuzz.campaign.results import summarise
from lidarfuzz.campaign.runner import ProgressEvent, run_task
from lidarfuzz.campaign.spec import parse_campaign
from lidarfuzz.campaign.tasks import cancel_task, create_task, get_task
from lidarfuzz.store import Finding, FrameResult, Status, Store, Subtask, Task
from lidarfuzz.store.boxes import StoredBoxes, decode_boxes, encode_boxes

# uniform_noise_addition is meant to be harmless up to severity 2: checked by preservation at 2, not at 5
OPERATORS = [{"name": "uniform_noise_addition", "severities": [2, 5]}, {"name": "rotate_z", "severities": [3]}]


def campaign(data: Path, sut: str = "classic", **extra: object):
    return parse_campaign({"dataset": str(data), "sut": sut, "operators": OPERATORS, **extra})


def digest(folder: Path) -> str:
    h = hashlib.sha256()
    for path in sorted(folder.rglob("*")):
        if path.is_file():
            h.update(path.name.encode() + path.read_bytes())
    return h.hexdigest()


def outputs(store: Store, task_id: int) -> dict[tuple[str, int, str, int], bytes | None]:
    with store.session() as s:
        rows = s.execute(select(Subtask.name, Subtask.severity, FrameResult.frame_id, FrameResult.trial,
                                FrameResult.boxes).join(Subtask).where(Subtask.task_id == task_id))
        return {(a, b, c, d): e for a, b, c, d, e in rows}


@pytest.fixture(params=["sqlite", "postgresql"])
def store(request: pytest.FixtureRequest, tmp_path: Path):
    target = tmp_path / "ws" if request.param == "sqlite" else request.getfixturevalue("fresh_postgres_url")
    opened = Store(target)
    yield opened
    opened.close()


@pytest.fixture(scope="module")
def reference(tmp_path_factory: pytest.TempPathFactory, world: Path):
    """One uninterrupted inline run: what every other way of running must reproduce."""
    store = Store(tmp_path_factory.mktemp("reference"))
    task_id = create_task(store, campaign(world))
    run_task(store, task_id, executor=InlineExecutor())
    return store, task_id


@pytest.fixture(scope="module")
def buggy(tmp_path_factory: pytest.TempPathFactory, world: Path):
    """The same campaign on a bug-zoo variant whose ROI does not turn with the scene: findings to replay (the
    correct pipeline raises none on these harmless mutants)."""
    store = Store(tmp_path_factory.mktemp("buggy"))
    task_id = create_task(store, campaign(world, sut="classic-bug-roi-cache"))
    run_task(store, task_id, executor=InlineExecutor())
    return store, task_id


def test_codec_round_trip(sample_scenes) -> None:
    boxes = sample_scenes[0].boxes
    back = decode_boxes(*encode_boxes(boxes))
    assert back.allclose(boxes, atol=1e-4) and list(back.labels) == list(boxes.labels)
    assert len(decode_boxes(None, [])) == 0
    stored = StoredBoxes.of(boxes)  # the one value the store's composites and the work units carry
    assert stored.labels == tuple(boxes.labels) and stored.boxes().allclose(boxes, atol=1e-4)
    assert StoredBoxes.of(None).missing and len(StoredBoxes.of(None).boxes()) == 0


def test_a_task_is_planned_and_run_to_the_end(store: Store, world: Path) -> None:
    before = digest(world)
    task_id = create_task(store, campaign(world))
    task = get_task(store, task_id)
    assert [(s.name, s.severity) for s in task.subtasks] == [
        ("original", 0), ("uniform_noise_addition", 2), ("uniform_noise_addition", 5), ("rotate_z", 3)]
    assert task.total == 4 * 3
    events: list[ProgressEvent] = []
    outcome = run_task(store, task_id, executor=InlineExecutor(), progress=events.append)
    assert outcome.status == Status.DONE and outcome.stats.units == 12
    assert [e.task_done for e in events] == list(range(1, 13))
    task = get_task(store, task_id)
    assert task.status == Status.DONE and task.done == task.total and task.finished_at is not None
    assert all(s.status == Status.DONE and s.done == s.total and s.results.ap for s in task.subtasks)
    with store.session() as s:
        assert s.scalar(select(func.count()).select_from(FrameResult)) == 12
        # rotate_z is equivariant: its subtask checked equivariance on every frame
        rotated = next(r for r in s.scalars(select(FrameResult).join(Subtask).where(Subtask.name == "rotate_z")))
        assert {o.relation for o in rotated.relations} >= {"equivariance"}
        assert rotated.params and rotated.ground_truth.data  # concrete params and the moved ground truth
        plans = {(sub.name, sub.severity): sub.plan for sub in s.scalars(select(Subtask))}
        assert "preservation" in plans["uniform_noise_addition", 2].relation_names
        assert "preservation" not in plans["uniform_noise_addition", 5].relation_names
        assert plans["uniform_noise_addition", 5].unchecked["preservation"].startswith(
            "uniform_noise_addition is meant to be harmless only up to severity 2")
    summary = summarise(store, task_id)
    assert summary.subtasks[0].label == "original" and summary.delta_ap
    assert {r.relation for r in summary.violations.relation} >= {"equivariance", "preservation"}
    assert digest(world) == before  # the original data set is never modified


def test_results_do_not_depend_on_the_executor(reference, tmp_path: Path, world: Path) -> None:
    ref_store, ref_id = reference
    store = Store(tmp_path / "pool")
    task_id = create_task(store, campaign(world))
    run_task(store, task_id, executor=ProcessExecutor(2))
    assert outputs(store, task_id) == outputs(ref_store, ref_id)


def test_unchanged_inputs_come_from_the_cache(tmp_path: Path, world: Path) -> None:
    """Each frame's cached outputs are read in one query; a system with nothing cached yet is
    asked about once per run, not once per frame."""
    reads: list[str] = []

    def count(_conn, _cursor, statement: str, *_: object) -> None:
        if statement.lstrip().upper().startswith("SELECT") and "FROM sut_outputs" in statement:
            reads.append(statement)

    event.listen(Engine, "before_cursor_execute", count)
    try:
        store = Store(tmp_path / "ws")
        first = create_task(store, campaign(world))
        assert run_task(store, first, executor=InlineExecutor()).stats.cached == 0
        assert len(reads) == 1  # nothing cached for the system: no frame is read
        reads.clear()
        second = create_task(store, campaign(world))
        outcome = run_task(store, second, executor=InlineExecutor())
        assert len(reads) == 1 + 3  # the same question, then the 3 frames' outputs, one query each
    finally:
        event.remove(Engine, "before_cursor_execute", count)
    assert outcome.stats.cached == outcome.stats.units == 12 and outcome.stats.sut == 0
    assert outputs(store, second) == outputs(store, first)
    # another seed: originals cached, mutants new
    third = create_task(store, campaign(world, seed=1))
    assert run_task(store, third, executor=InlineExecutor()).stats.cached == 3


ONE_CAR = """
from lidarfuzz.scene.boxes import Boxes3D
from lidarfuzz.suts.base import SystemUnderTest


class OneCar(SystemUnderTest):
    name = "one-car"
    version = "1"

    def detect(self, sample):
        return Boxes3D.create([[{x}, 0.0, -0.9]], [[3.9, 1.6, 1.5]], [0.0], ["Car"], scores=[0.9])
"""


def test_a_system_whose_code_changed_is_not_served_the_old_outputs(tmp_path: Path, world: Path,
                                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    """Same name, version and configuration, other code: its outputs are computed, not read
    from the cache; so are those of a task created before the change and run after it."""
    import importlib

    from lidarfuzz.store.models import SutOutput

    monkeypatch.syspath_prepend(str(tmp_path))
    source = tmp_path / "one_car_system.py"
    source.write_text(ONE_CAR.format(x="10.0"))
    module = importlib.import_module("one_car_system")
    try:
        store = Store(tmp_path / "ws")
        spec = campaign(world, sut="one_car_system:OneCar", frames=2)  # 2 frames x 4 subtasks = 8 units
        first = create_task(store, spec)
        assert run_task(store, first, executor=InlineExecutor()).stats.cached == 0
        unchanged = create_task(store, spec)
        assert run_task(store, unchanged, executor=InlineExecutor()).stats.cached == 8  # the cache works
        created_before = create_task(store, spec)  # recorded with the old code's fingerprint
        source.write_text(ONE_CAR.format(x="20.0"))
        importlib.reload(module)
        changed = create_task(store, spec)
        old, new = get_task(store, first).model, get_task(store, changed).model
        assert new.fingerprint != old.fingerprint and new.spec == old.spec
        for task_id in (changed, created_before):
            outcome = run_task(store, task_id, executor=InlineExecutor())
            assert outcome.stats.units == 8 and outcome.stats.cached == 0
            with store.session() as s:
                rows = s.scalars(select(FrameResult).join(Subtask).where(Subtask.task_id == task_id)).all()
                # the new code puts its one car at x = 20 on every frame (the old code at 10)
                assert len(rows) == 8 and all(r.detections.boxes().centers[:, 0].tolist() == [20.0] for r in rows)
        with store.session() as s:  # the old fingerprint's 8 cached outputs, none of the new code's among them
            cached = s.scalars(select(SutOutput).where(SutOutput.fingerprint == old.fingerprint)).all()
            assert len(cached) == 8 and all(c.output.boxes().centers[0, 0] == 10.0 for c in cached)
    finally:
        sys.modules.pop("one_car_system", None)


def test_a_stopped_task_resumes_with_nothing_lost_or_counted_twice(store: Store, reference, world: Path) -> None:
    task_id = create_task(store, campaign(world))
    stop = threading.Event()

    def halt_after_five(event: ProgressEvent) -> None:
        if event.task_done == 5:
            stop.set()

    first = run_task(store, task_id, executor=InlineExecutor(), progress=halt_after_five, stop=stop)
    assert first.status == Status.CANCELLED and get_task(store, task_id).done == 5
    second = run_task(store, task_id, executor=InlineExecutor())
    assert second.status == Status.DONE and second.stats.units == 7
    task = get_task(store, task_id)
    assert task.done == task.total == 12 and sum(s.done for s in task.subtasks) == 12
    ref_store, ref_id = reference
    assert outputs(store, task_id) == outputs(ref_store, ref_id)


def test_cancel_from_outside_stops_a_running_task(tmp_path: Path, world: Path) -> None:
    store = Store(tmp_path / "ws")
    task_id = create_task(store, campaign(world, sut="tests.campaign.systems:SlowClassic"))

    def cancel_when_started(event: ProgressEvent) -> None:
        if event.task_done == 2:
            cancel_task(store, task_id)  # what lidarfuzz cancel does from another process

    outcome = run_task(store, task_id, executor=InlineExecutor(), progress=cancel_when_started)
    assert outcome.status == Status.CANCELLED
    assert 2 <= get_task(store, task_id).done < 12


def test_a_system_that_kills_its_process_is_a_crash_of_that_frame_only(tmp_path: Path, world: Path) -> None:
    store = Store(tmp_path / "ws")
    task_id = create_task(store, campaign(world, sut="tests.campaign.systems:DiesOnFrame"))
    outcome = run_task(store, task_id, executor=ProcessExecutor(2))
    assert outcome.status == Status.DONE
    with store.session() as s:
        crashed = s.execute(select(FrameResult.frame_id).where(FrameResult.failure.is_not(None))).scalars().all()
        kinds = s.scalars(select(Finding.kind)).all()
    assert set(crashed) == {"000001"} and len(crashed) == 4  # the original and its three mutants
    assert kinds.count("crash") == 4


def test_a_finding_replays_exactly(buggy) -> None:
    store, task_id = buggy
    with store.session() as s:
        finding = s.scalar(select(Finding).where(Finding.task_id == task_id, Finding.kind != "crash").order_by(
            Finding.id))
    assert finding is not None, "the reference campaign should find something"
    replay = replay_finding(store, finding.id)
    assert replay.same_system and replay.reproduced and replay.verdict == "reproduced"
    assert replay.outputs_match and replay.violated_now and replay.deterministic
    assert replay.follow_now is not None and replay.follow_now.allclose(replay.follow_recorded, atol=1e-3)


def test_a_replay_whose_record_was_altered_says_the_outputs_differ(buggy) -> None:
    """The record's follow-up boxes moved 0.5 m along x: the relation is violated again, but
    the outputs differ from the record (by 0.5 m, each box from its moved copy), so it is not
    reproduced."""
    from lidarfuzz.scene.boxes import Boxes3D

    store, task_id = buggy
    with store.session() as s:
        finding = next(f for f in s.scalars(select(Finding).where(Finding.task_id == task_id,
                                                                   Finding.kind != "crash").order_by(Finding.id))
                       if len(s.get(FrameResult, f.frame_result_id).detections.boxes()) > 0)
        row = s.get(FrameResult, finding.frame_result_id)
        recorded = row.detections
        boxes = recorded.boxes()
        moved = boxes.centers.copy()
        moved[:, 0] += 0.5
        row.detections = StoredBoxes.of(Boxes3D.create(moved, boxes.sizes, boxes.yaw, boxes.labels,
                                                       scores=boxes.scores))
        s.commit()
        finding_id, row_id = finding.id, row.id
    try:
        replay = replay_finding(store, finding_id)
    finally:
        with store.session() as s:
            s.get(FrameResult, row_id).detections = recorded
            s.commit()
    assert replay.same_system and replay.violated_now and replay.deterministic
    assert not replay.outputs_match and not replay.reproduced
    compared = replay.against_record()
    assert compared["source"].same and not compared["follow-up"].same
    assert compared["follow-up"].centre_shift == pytest.approx(0.5, abs=1e-3)
    assert replay.verdict.startswith("not reproduced: outputs differ from the record: follow-up (")
    assert "centres moved up to 0.5 m" in replay.verdict


def test_replay_reports_a_non_deterministic_system(tmp_path: Path, world: Path) -> None:
    store = Store(tmp_path / "ws")
    task_id = create_task(store, campaign(world, sut="tests.campaign.systems:RandomBoxes", frames=2))
    run_task(store, task_id, executor=InlineExecutor())
    with store.session() as s:
        finding_id = s.scalar(select(Finding.id).where(Finding.kind != "crash").order_by(Finding.id))
    assert finding_id is not None, "random boxes break the relations"
    replay = replay_finding(store, finding_id)
    # a fresh draw of 1-4 random cars each call: neither the record nor the first answer comes back
    assert replay.same_system and not replay.deterministic and not replay.outputs_match
    assert not replay.repeated()["source"].same and not replay.reproduced
    assert "non-deterministic or stateful" in replay.verdict


def test_a_bad_campaign_names_the_key(world: Path) -> None:
    from lidarfuzz.errors import DataFormatError

    with pytest.raises(DataFormatError, match=r"operators\.0\.severities"):
        parse_campaign({"dataset": str(world), "sut": "classic", "operators": [{"name": "fog", "severities": [9]}]})


def test_deleting_a_task_leaves_the_catalogue(tmp_path: Path, world: Path) -> None:
    from lidarfuzz.campaign.tasks import delete_task

    store = Store(tmp_path / "ws")
    task_id = create_task(store, campaign(world))
    run_task(store, task_id, executor=InlineExecutor())
    delete_task(store, task_id)
    with store.session() as s:
        assert s.scalar(select(func.count()).select_from(Task)) == 0
        assert s.scalar(select(func.count()).select_from(FrameResult)) == 0
        assert s.scalar(select(func.count()).select_from(Finding)) == 0


def test_a_moved_scene_is_scored_only_where_the_source_had_labels(tmp_path: Path, world: Path) -> None:
    """Labels cover the camera's view only: a half turn brings unlabelled ground into view and
    carries every labelled object out of it, so the subtask has no AP (not an AP of 0); a small
    turn is scored, without the detections that came from the unlabelled region."""
    import numpy as np

    from lidarfuzz.campaign.results import labelled_region
    from lidarfuzz.io.kitti import open_kitti
    from lidarfuzz.report import write_report

    store = Store(tmp_path / "ws")
    spec = parse_campaign({"dataset": str(world), "sut": "classic", "relations": ["equivariance"], "operators": [
        {"name": "rotate_z", "config": {"angle_range": [180.0, 180.0], "both_directions": False}},
        {"name": "rotate_z", "config": {"angle_range": [10.0, 10.0], "both_directions": False}}]})
    task_id = create_task(store, spec)
    run_task(store, task_id, executor=InlineExecutor())
    with store.session() as s:
        results = {sub.operator.get("config", {}).get("angle_range", [None])[0]: sub.results
                   for sub in s.scalars(select(Subtask).where(Subtask.task_id == task_id))}
    assert results[None].ap is not None  # the originals
    assert results[180.0].ap is None
    assert "out of the camera's view" in (results[180.0].ap_note or "")
    assert results[10.0].ap is not None
    html = write_report(store, task_id, tmp_path / "report").html.read_text()
    assert "moved every labelled object out of the camera" in html

    data = open_kitti(world)
    scene = data.load(data.frame_ids()[0])
    half_turn = np.diag([-1.0, -1.0, 1.0, 1.0])
    ahead = scene.boxes.select(scene.calib.in_view(scene.boxes.centers))
    assert len(ahead) > 0
    assert len(labelled_region(ahead, scene.calib, None)) == len(ahead)
    assert len(labelled_region(ahead, scene.calib, np.eye(4))) == len(ahead)
    assert len(labelled_region(ahead, scene.calib, half_turn)) == 0  # mapped back, they lie behind the car


class _FlakyPool:
    """A stand-in for ProcessPoolExecutor's submit/shutdown: the units listed in ``dies_with`` fail
    as a killed worker's do, and the pool refuses the ``refuse_at``-th submit as a broken one does."""

    def __init__(self, dies_with: tuple[str, ...] = (), refuse_at: int | None = None) -> None:
        self.dies_with, self.refuse_at, self.calls = dies_with, refuse_at, 0

    def submit(self, fn: object, unit: str) -> object:
        from concurrent.futures import Future
        from concurrent.futures.process import BrokenProcessPool

        self.calls += 1
        if self.calls == self.refuse_at:
            raise BrokenProcessPool("a child process terminated abruptly")
        future: Future = Future()
        if unit in self.dies_with:
            future.set_exception(BrokenProcessPool("a child process terminated abruptly"))
        else:
            future.set_result(f"ran {unit}")
        return future

    def shutdown(self, wait: bool = True, cancel_futures: bool = False) -> None:
        pass


@pytest.mark.parametrize("first", [_FlakyPool(refuse_at=1), _FlakyPool(dies_with=("a",), refuse_at=2)],
                         ids=["refused-with-nothing-in-flight", "refused-while-a-worker-dies"])
def test_a_pool_that_breaks_between_waits_loses_no_unit(first: _FlakyPool) -> None:
    """A worker can die after the executor last waited: the next submit is refused. The refused
    unit never ran, so it runs on the new pool; the one with the dead worker is re-run alone."""
    executor = ProcessExecutor(2)
    pools = [first, _FlakyPool(), _FlakyPool()]
    executor._new_pool = lambda: pools.pop(0)  # type: ignore[method-assign]
    executor._pool = executor._new_pool()  # type: ignore[assignment]
    assert sorted(executor.run(iter(["a", "b", "c"]))) == ["ran a", "ran b", "ran c"]  # type: ignore[arg-type]


@pytest.mark.parametrize("every", [0.0, 1e9])
def test_counters_agree_with_the_results_at_every_commit_and_the_cache_is_written_by_the_end(
        tmp_path: Path, world: Path, monkeypatch: pytest.MonkeyPatch, every: float) -> None:
    """Every result is committed with its counters (a kill at any instant leaves them agreeing);
    the outputs waiting for the cache go in with a subtask's first and last result and at most every
    CACHE_EVERY seconds between: after a subtask's second result, none of its cache rows lag when
    due each time (0 s), one does when never due by time (1e9 s); all 12 are there at the end."""
    import lidarfuzz.campaign.mutation as mutation
    from lidarfuzz.store import SutOutput

    monkeypatch.setattr(mutation, "CACHE_EVERY", every)
    store = Store(tmp_path / "ws")
    task_id = create_task(store, campaign(world))
    seen: list[tuple[int, int, int]] = []

    def look(event: ProgressEvent) -> None:
        with store.session() as s:
            stored = s.scalar(select(func.count()).select_from(FrameResult).join(Subtask).where(
                Subtask.task_id == task_id))
            seen.append((s.scalar(select(Task.done).where(Task.id == task_id)), stored,
                         s.scalar(select(func.count()).select_from(SutOutput))))

    run_task(store, task_id, executor=InlineExecutor(), progress=look)
    assert [(counted, stored) for counted, stored, _ in seen] == [(n, n) for n in range(1, 13)]
    lag = [stored - cached for _, stored, cached in seen]
    assert lag == ([0] * 12 if every == 0.0 else [0, 1, 0] * 4)  # 4 subtasks of 3 frames
    task = get_task(store, task_id)
    assert task.done == task.total == 12 and all(sub.done == sub.total == 3 for sub in task.subtasks)
    with store.session() as s:
        assert s.scalar(select(func.count()).select_from(SutOutput)) == 12
