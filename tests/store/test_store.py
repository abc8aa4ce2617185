"""The campaign store on SQLite (WAL, the default) and on a real PostgreSQL server."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from sqlalchemy import select, text
from sqlalchemy.exc import IntegrityError

from lidarfuzz.store import Dataset, Finding, FrameResult, Model, Status, Store, StoreError, Subtask, Task


@pytest.fixture(params=["sqlite", "postgresql"])
def store(request: pytest.FixtureRequest, tmp_path: Path) -> Store:
    if request.param == "sqlite":
        opened = Store(tmp_path / "workspace")
    else:
        opened = Store(request.getfixturevalue("fresh_postgres_url"))  # a database of its own
    yield opened
    opened.close()


def test_schema_is_migrated_once_and_idempotently(store: Store) -> None:
    assert store.revision() == "0009"
    store.migrate()
    assert store.revision() == "0009"
    assert {"datasets", "models", "tasks", "subtasks", "frame_results", "findings"} <= set(store.tables())


def test_sqlite_lives_in_the_workspace_in_wal_mode(tmp_path: Path) -> None:
    store = Store(tmp_path / "ws")
    assert (tmp_path / "ws" / "lidarfuzz.db").exists()
    with store.engine.connect() as connection:
        assert connection.execute(text("PRAGMA journal_mode")).scalar() == "wal"
        assert connection.execute(text("PRAGMA foreign_keys")).scalar() == 1


def seed(store: Store) -> int:
    with store.session() as s:
        ds = Dataset(name="sim", path="/data/sim", format="kitti", frame_count=3)
        model = Model(name="classic", spec="classic", fingerprint="abc123")
        task = Task(name="t", dataset=ds, model=model, seed=7, operators=[{"spec": {"name": "fog"}, "severities": [1]}],
                    relations=["preservation"], total=6)
        task.subtasks = [
            Subtask(operator_key="original", operator={}, severity=0, total=3),
            Subtask(operator_key="fog-1", operator={"name": "fog", "config": {}}, severity=1, total=3),
        ]
        s.add(task)
        s.flush()
        boxes = np.array([[10, 0, -0.9, 4, 1.7, 1.5, 0.1, 0.9]], dtype=np.float32)
        result = FrameResult(subtask_id=task.subtasks[1].id, frame_id="000001", params={"mor": 120.5},
                             boxes=boxes.tobytes(), labels=["Car"], seconds=0.04,
                             relations=[{"relation": "preservation", "holds": True}])
        s.add(result)
        s.flush()
        s.add(Finding(task_id=task.id, frame_result_id=result.id, kind="preservation", cls="Car", magnitude=0.2,
                      message="Car #0 lost", replay={"seed": 7, "frame_id": "000001", "params": {"mor": 120.5},
                                              "dataset": "/data/sim", "sut": "classic", "fingerprint": "abc123"}))
        return task.id


def test_round_trip_of_every_entity(store: Store) -> None:
    task_id = seed(store)
    with store.session() as s:
        task = s.get(Task, task_id)
        assert task is not None and task.status is Status.PENDING and task.dataset.name == "sim"
        assert task.operators[0]["severities"] == [1] and task.model.fingerprint == "abc123"
        assert [st.operator_key for st in task.subtasks] == ["original", "fog-1"]
        result = s.scalars(select(FrameResult)).one()
        boxes = np.frombuffer(result.boxes, dtype=np.float32).reshape(-1, 8)
        assert boxes[0, 0] == 10 and result.params == {"mor": 120.5} and result.labels == ["Car"]
        finding = s.scalars(select(Finding)).one()
        assert finding.replay.frame_id == "000001" and finding.magnitude == pytest.approx(0.2)
        task.status = Status.DONE
    with store.session() as s:
        assert s.get(Task, task_id).status is Status.DONE


def test_a_work_unit_is_stored_once(store: Store) -> None:
    seed(store)
    with store.session() as s:
        subtask_id = s.scalars(select(Subtask).where(Subtask.severity == 1)).one().id
    with pytest.raises(IntegrityError), store.session() as s:
        s.add(FrameResult(subtask_id=subtask_id, frame_id="000001", trial=0))
    with store.session() as s:
        assert len(s.scalars(select(FrameResult)).all()) == 1  # the failed unit of work left nothing behind


def test_deleting_a_task_deletes_what_belongs_to_it(store: Store) -> None:
    task_id = seed(store)
    with store.session() as s:
        s.delete(s.get(Task, task_id))
    with store.session() as s:
        assert s.scalars(select(Subtask)).all() == [] and s.scalars(select(FrameResult)).all() == []
        assert s.scalars(select(Finding)).all() == [] and len(s.scalars(select(Dataset)).all()) == 1


def test_a_bad_url_is_a_clear_error(tmp_path: Path) -> None:
    with pytest.raises(StoreError, match="cannot"):
        Store("nosuchdialect://x")
    with pytest.raises(StoreError, match="cannot migrate"):
        Store("postgresql+psycopg://nobody@/nodb?host=/nonexistent&connect_timeout=1")


def test_a_postgresql_url_without_its_driver_names_the_extra(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "psycopg", None)  # import psycopg now raises ImportError
    with pytest.raises(StoreError, match=r"pip install 'lidarfuzz\[postgres\]'"):
        Store("postgresql+psycopg://user@localhost/none", migrate=False)
