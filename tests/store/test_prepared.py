"""Prepared statements (the campaign's hot path): the rows they write read back exactly as the
rows SQLAlchemy Core writes, on SQLite and PostgreSQL, inside the connection's transaction."""

from __future__ import annotations

from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import pytest
from sqlalchemy import bindparam, func, insert, select, update
from sqlalchemy.exc import IntegrityError

from lidarfuzz.store import Finding, FrameResult, Status, Store, Subtask
from lidarfuzz.store.contracts import FailureRecord, OutcomeRecord, ViolationRecord
from lidarfuzz.store.errors import StoreError
from lidarfuzz.store.prepared import Prepared
from tests.store.test_store import seed

COLUMNS = ("subtask_id", "frame_id", "trial", "params", "boxes", "labels", "gt_boxes", "gt_labels", "failure",
           "relations", "seconds", "cached", "created_at")


@pytest.fixture(params=["sqlite", "postgresql"])
def store(request: pytest.FixtureRequest, tmp_path: Path) -> Store:
    opened = Store(tmp_path / "ws" if request.param == "sqlite" else request.getfixturevalue("fresh_postgres_url"))
    yield opened
    opened.close()


def row(subtask_id: int, frame_id: str) -> dict[str, object]:
    """A result with a value of every kind the table stores: JSON with nested floats and a NaN-free
    contract, bytes, a bool, a timestamp with a time zone, SQL NULL."""
    boxes = np.array([[10, 0, -0.9, 4, 1.7, 1.5, 0.1, 0.9]], dtype=np.float32).tobytes()
    relation = OutcomeRecord(relation="preservation", holds=False, violations=[
        ViolationRecord(relation="preservation", kind="lost", cls="Car", source_index=0, magnitude=0.5,
                        range_m=12.25, message="Car #0 lost", evidence={"iou": 0.125})])
    return {"subtask_id": subtask_id, "frame_id": frame_id, "trial": 2, "params": {"mor": 120.5, "k": [1, 2]},
            "boxes": boxes, "labels": ["Car"], "gt_boxes": None, "gt_labels": [],
            "failure": FailureRecord(kind="crash", message="boom"), "relations": [relation],
            "seconds": 0.25, "cached": True, "created_at": datetime(2026, 11, 24, 13, 5, 7, 250000, tzinfo=UTC)}


def stored(store: Store, frame_id: str) -> dict[str, object]:
    with store.session() as s:
        result = s.scalars(select(FrameResult).where(FrameResult.frame_id == frame_id)).one()
        return {c: getattr(result, c) for c in COLUMNS if c not in ("subtask_id", "frame_id")}


def subtask_of(store: Store) -> int:
    with store.session() as s:
        return s.scalars(select(Subtask).where(Subtask.severity == 1)).one().id


def test_an_insert_reads_back_as_sqlalchemys_own(store: Store) -> None:
    seed(store)
    sub = subtask_of(store)
    prepared = Prepared(insert(FrameResult).returning(FrameResult.id), store.engine.dialect, COLUMNS)
    assert prepared.returning
    with store.engine.connect() as connection, connection.begin():
        connection.execute(insert(FrameResult), row(sub, "core"))
        new_id = prepared.execute(connection, row(sub, "prepared"))
    core, mine = stored(store, "core"), stored(store, "prepared")
    assert mine == core
    assert mine["failure"] == FailureRecord(kind="crash", message="boom") and mine["gt_boxes"] is None
    assert mine["created_at"].replace(tzinfo=UTC) == datetime(2026, 11, 24, 13, 5, 7, 250000, tzinfo=UTC)
    with store.session() as s:
        assert s.scalar(select(FrameResult.id).where(FrameResult.frame_id == "prepared")) == new_id


def test_an_update_keeps_the_statements_own_values_and_runs_in_the_transaction(store: Store) -> None:
    seed(store)
    sub = subtask_of(store)
    bump = Prepared(update(Subtask).where(Subtask.id == bindparam("subtask")).values(
        done=Subtask.done + bindparam("n"), status=Status.RUNNING,
        started_at=func.coalesce(Subtask.started_at, bindparam("now"))), store.engine.dialect, ("subtask", "n", "now"))
    first, later = datetime(2026, 1, 2, 3, 4, 5, tzinfo=UTC), datetime(2027, 1, 1, tzinfo=UTC)
    with store.engine.connect() as connection:
        with connection.begin():
            bump.execute(connection, {"subtask": sub, "n": 2, "now": first})
            bump.execute(connection, {"subtask": sub, "n": 3, "now": later})
        with pytest.raises(RuntimeError), connection.begin():  # rolled back with its transaction
            bump.execute(connection, {"subtask": sub, "n": 100, "now": later})
            raise RuntimeError
    with store.session() as s:
        subtask = s.get(Subtask, sub)
        assert subtask.done == 5 and subtask.status is Status.RUNNING
        assert subtask.started_at.replace(tzinfo=UTC) == first  # set by the first bump only


def test_a_duplicate_unit_is_sqlalchemys_integrity_error_and_leaves_nothing(store: Store) -> None:
    seed(store)  # stores (fog-1, 000001, trial 0)
    sub = subtask_of(store)
    prepared = Prepared(insert(FrameResult).returning(FrameResult.id), store.engine.dialect, COLUMNS)
    findings = Prepared(insert(Finding), store.engine.dialect, ("task_id", "frame_result_id", "kind", "cls",
                                                                 "magnitude", "message", "detail", "replay"))
    with store.engine.connect() as connection:
        with pytest.raises(IntegrityError), connection.begin():
            prepared.execute(connection, {**row(sub, "000002"), "trial": 0})
            prepared.execute(connection, {**row(sub, "000001"), "trial": 0})
        with connection.begin():  # the connection is usable again
            findings.execute_many(connection, [])
    with store.session() as s:
        assert s.scalars(select(FrameResult.frame_id)).all() == ["000001"]


def test_a_column_sqlalchemy_would_fill_in_python_must_be_given(tmp_path: Path) -> None:
    store = Store(tmp_path / "ws")
    try:
        with pytest.raises(StoreError, match="explicit values for") as raised:
            Prepared(insert(Finding), store.engine.dialect, ("task_id", "frame_result_id", "kind", "replay"))
        assert {"cls", "message", "detail"} <= set(str(raised.value).split(" for ")[1].split(" (")[0].split(", "))
    finally:
        store.close()
