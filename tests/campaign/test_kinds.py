"""The table of task kinds and the lifecycle they share: a kind is one module and one row.

This module is itself a task kind (``probe``): the tests add its row to the table and run it
through the same ``create_task`` / ``run_task`` as the built-in kinds.
"""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Any

import pytest

from lidarfuzz.campaign import coverage_search, kinds, mutation
from lidarfuzz.campaign.lifecycle import CancelledError, KindImplementation, RunOptions, RunStats, Watch
from lidarfuzz.campaign.plan import KindPlan, SubtaskPlan, relations_for, relations_for_kind
from lidarfuzz.campaign.results import summarise
from lidarfuzz.campaign.runner import describe_plan, run_task
from lidarfuzz.campaign.spec import CampaignSpec, parse_campaign
from lidarfuzz.campaign.tasks import cancel_task, create_task, delete_task, get_task
from lidarfuzz.errors import DataFormatError
from lidarfuzz.operators.base import Relation
from lidarfuzz.operators.registry import get as get_operator
from lidarfuzz.store import Status, Store, Task
from lidarfuzz.store.contracts import TaskSummary
from lidarfuzz.store.errors import ConflictError, NotFoundError
from lidarfuzz.store.models import Model

#: mypy checks that every built-in kind's module provides the hooks.
BUILT_IN: list[KindImplementation] = [mutation, coverage_search]

# -- the probe kind: what a test sets it to do ------------------------------------------
counted_below: int | None = None
BEHAVIOUR: dict[str, Any] = {}


def check_spec(spec: CampaignSpec) -> None:
    if spec.search:
        raise ValueError("search: the probe takes no search section")


def plan(spec: CampaignSpec, model: Model, frame_ids: list[str]) -> KindPlan:
    return KindPlan([SubtaskPlan("probe", {"name": "probe"}, units=2)], {"probe": {"frames": len(frame_ids)}})


class _ProbeRun:
    def __init__(self, store: Store, task: Task, options: RunOptions) -> None:
        self.stats = RunStats()
        self.store, self.task_id = store, task.id
        self.watch = Watch(store, task.id, options.stop)
        self.closed = False
        BEHAVIOUR["run"] = self

    def execute(self) -> None:
        action = BEHAVIOUR.get("execute")
        if action == "fail":
            raise RuntimeError("the probe broke")
        if action == "cancel":
            raise CancelledError
        self.watch.check()
        self.stats.units = 2

    def summary(self) -> TaskSummary:
        return summarise(self.store, self.task_id).model_copy(update={"kind_summary": {"probe": "summarised"}})

    def close(self) -> None:
        self.watch.close()
        self.closed = True


def start(store: Store, task: Task, options: RunOptions) -> _ProbeRun:
    return _ProbeRun(store, task, options)


def describe(task: Task) -> str:
    return f"a probe of {task.options.kind_options['probe']['frames']} frame(s)"



@pytest.fixture
def with_probe(monkeypatch: pytest.MonkeyPatch) -> None:
    BEHAVIOUR.clear()
    monkeypatch.setattr(kinds, "TASK_KINDS", (*kinds.TASK_KINDS, kinds.TaskKind("probe", "a test kind", __name__)))


# -- the table ---------------------------------------------------------------------------
def test_every_row_names_a_module_with_the_hooks() -> None:
    assert kinds.kind_names() == ("mutation", "guided", "fuzz", "structural", "camera")
    for row in kinds.TASK_KINDS:
        module = row.implementation()
        for hook in ("check_spec", "plan", "start", "describe"):
            assert callable(getattr(module, hook)), (row.name, hook)
        assert module.counted_below is None or isinstance(module.counted_below, int)
    assert kinds.task_kind("fuzz").implementation() is coverage_search
    assert kinds.find_kind("bogus") is None


def test_an_unknown_kind_is_refused_naming_those_there_are(world: Path) -> None:
    with pytest.raises(DataFormatError,
                       match="unknown task kind 'bogus'; choose one of mutation, guided, fuzz, structural"):
        parse_campaign({"dataset": str(world), "sut": "classic", "kind": "bogus", "operators": [{"name": "fog"}]})
    with pytest.raises(kinds.UnknownKindError):
        kinds.task_kind("bogus")


def test_a_new_kind_is_a_module_and_a_row(with_probe: None, world: Path, tmp_path: Path) -> None:
    spec = parse_campaign({"dataset": str(world), "sut": "classic", "kind": "probe"})
    with pytest.raises(DataFormatError, match="the probe takes no search section"):
        parse_campaign({"dataset": str(world), "sut": "classic", "kind": "probe", "search": {"budget": 2}})
    store = Store(tmp_path / "ws")
    try:
        task_id = create_task(store, spec)
        task = get_task(store, task_id)
        assert [(s.name, s.total) for s in task.subtasks] == [("original", 3), ("probe", 2)]
        assert task.total == 5 and task.options.kind == "probe"
        assert task.options.kind_options == {"probe": {"frames": 3}}
        assert describe_plan(task) == "a probe of 3 frame(s)"

        BEHAVIOUR["execute"] = "fail"
        with pytest.raises(RuntimeError, match="the probe broke"):
            run_task(store, task_id)
        task = get_task(store, task_id)
        assert (task.status, task.error) == (Status.FAILED, "RuntimeError: the probe broke")
        assert BEHAVIOUR["run"].closed

        BEHAVIOUR["execute"] = "cancel"
        assert run_task(store, task_id).status == Status.CANCELLED
        assert get_task(store, task_id).status == Status.CANCELLED

        BEHAVIOUR["execute"] = "finish"
        outcome = run_task(store, task_id)
        task = get_task(store, task_id)
        assert outcome.status == task.status == Status.DONE and outcome.stats.units == 2
        assert task.summary is not None and task.summary.kind_summary == {"probe": "summarised"}
        assert task.summary.run is not None and task.summary.run.units == 2
        assert task.finished_at is not None and task.worker and task.error == ""

        BEHAVIOUR.clear()  # a done task is left alone: the kind is not started again
        assert run_task(store, task_id).status == Status.DONE and "run" not in BEHAVIOUR
    finally:
        store.close()


def test_a_stop_event_cancels_through_the_watch(with_probe: None, world: Path, tmp_path: Path) -> None:
    store = Store(tmp_path / "ws")
    try:
        task_id = create_task(store, parse_campaign({"dataset": str(world), "sut": "classic", "kind": "probe"}))
        stop = threading.Event()
        stop.set()
        assert run_task(store, task_id, stop=stop).status == Status.CANCELLED
    finally:
        store.close()


# -- what the engine no longer needs to know -----------------------------------------------
@pytest.mark.parametrize("choice", ["auto", ["preservation", "equivariance", "gt_recall"], ["invariance"]])
def test_a_search_finds_its_relations_by_relation_kind(choice: Any) -> None:
    stand_in = get_operator("outside_roi_scatter")()  # an invariant operator, harmless at every severity
    assert relations_for_kind(Relation.INVARIANT, choice) == relations_for(stand_in, choice)


def test_profile_folders_come_from_the_sut() -> None:
    class Plain:
        pass

    class Shipping:
        def profile_dirs(self) -> list[str]:
            return ["/somewhere/profiles"]

    assert coverage_search.profile_dirs(Plain()) == []
    assert coverage_search.profile_dirs(Shipping()) == [Path("/somewhere/profiles")]
    from lidarfuzz.suts.learned.sut import WEIGHTS_DIR
    from lidarfuzz.suts.registry import create

    assert coverage_search.profile_dirs(create("pillars")) == [WEIGHTS_DIR]


# -- errors by type ------------------------------------------------------------------------
def test_store_errors_say_what_happened_by_their_type(world: Path, tmp_path: Path) -> None:
    store = Store(tmp_path / "ws")
    try:
        for call in (get_task, cancel_task, delete_task):
            with pytest.raises(NotFoundError, match=r"^no task 7$"):
                call(store, 7)
        task_id = create_task(store, parse_campaign({"dataset": str(world), "sut": "classic",
                                                     "operators": [{"name": "fog", "severities": [1]}]}))
        with store.session() as s:
            row = s.get(Task, task_id)
            assert row is not None
            row.status = Status.RUNNING
        with pytest.raises(ConflictError, match=f"task {task_id} is running; stop it first"):
            delete_task(store, task_id)
    finally:
        store.close()
