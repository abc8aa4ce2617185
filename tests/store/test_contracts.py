"""The store's JSON columns hold typed contracts: a wrong shape is refused where it is written,
NaN is stored as null and read back as NaN, and migration 0004 moves what older versions stored
(a subtask's inputs inside its results, a search's config under ``search``, bare NaN tokens)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
import sqlalchemy as sa
from sqlalchemy.exc import StatementError

from lidarfuzz.store.contracts import FailureRecord, OutcomeRecord, SubtaskInputs, TaskOptions, TaskSummary
from lidarfuzz.store.models import Dataset, FrameResult, Model, Subtask, Task
from lidarfuzz.store.store import Store


@pytest.fixture(params=["sqlite", "postgresql"])
def store(request: pytest.FixtureRequest, tmp_path: Path) -> Store:
    url = tmp_path / "ws" if request.param == "sqlite" else request.getfixturevalue("fresh_postgres_url")
    opened = Store(url)
    yield opened
    opened.close()


def _task(store: Store) -> tuple[int, int]:
    with store.session() as s:
        task = Task(dataset=Dataset(name="d", path="/d", format="kitti", frame_count=1),
                    model=Model(name="m", spec="classic", fingerprint="f"), options=TaskOptions(frame_ids=["000001"]))
        task.subtasks = [Subtask(operator_key="original", severity=0, total=1),
                         Subtask(operator_key="fog-1", name="fog", severity=1, total=1,
                                 plan=SubtaskInputs(relation_specs=[{"name": "preservation", "config": {}}]))]
        s.add(task)
        s.flush()
        return task.id, task.subtasks[1].id


def test_nan_is_stored_as_null_and_read_back_as_nan(store: Store) -> None:
    _, sub_id = _task(store)
    outcome = {"relation": "preservation", "holds": False, "checked": {"Car": 1},
               "violations": [{"relation": "preservation", "kind": "missing", "cls": "Car",
                               "magnitude": float("nan"), "range_m": 12.5}]}
    with store.session() as s:
        s.add(FrameResult(subtask_id=sub_id, frame_id="000001", relations=[outcome], params={"x": float("inf")}))
    with store.engine.connect() as connection:
        raw = connection.execute(sa.text("SELECT relations, params FROM frame_results")).one()
    relations = raw[0] if isinstance(raw[0], list) else json.loads(raw[0])  # PostgreSQL's driver parses JSON
    params = raw[1] if isinstance(raw[1], dict) else json.loads(raw[1])
    assert relations[0]["violations"][0]["magnitude"] is None and params == {"x": None}
    with store.session() as s:
        row = s.scalars(sa.select(FrameResult)).one()
        violation = row.relations[0].violations[0]
        assert isinstance(row.relations[0], OutcomeRecord)
        assert math.isnan(violation.magnitude) and violation.range_m == 12.5 and violation.cls == "Car"


def test_a_wrong_shape_is_refused_where_it_is_written(store: Store) -> None:
    _, sub_id = _task(store)
    with pytest.raises(StatementError, match="kind"), store.session() as s:
        s.add(FrameResult(subtask_id=sub_id, frame_id="000001", failure={"message": "no kind"}))
    with pytest.raises(StatementError, match="holds"), store.session() as s:
        s.add(FrameResult(subtask_id=sub_id, frame_id="000001", relations=[{"relation": "preservation"}]))
    with store.session() as s:
        s.add(FrameResult(subtask_id=sub_id, frame_id="000001", failure=FailureRecord(kind="crash", message="boom")))
    with store.session() as s:
        assert s.scalars(sa.select(FrameResult)).one().failure == FailureRecord(kind="crash", message="boom")


def test_a_task_has_no_summary_until_it_is_done_and_its_columns_come_back_typed(store: Store) -> None:
    task_id, _ = _task(store)
    with store.session() as s:
        task = s.get(Task, task_id)
        assert task.summary is None and task.options.frame_ids == ["000001"] and task.options.kind == "mutation"
        assert task.subtasks[1].plan.relation_names == ["preservation"] and task.subtasks[0].results.ap is None
        assert task.subtasks[1].state is None


def test_migration_0004_moves_what_older_versions_stored(tmp_path: Path) -> None:
    store = Store(tmp_path / "ws", migrate=False)
    store.migrate("0003")
    old_options = {"frame_ids": ["000001"], "trials": 1, "kind": "fuzz", "relations": "auto",
                   "search": {"kind": "fuzz", "budget": 8}}
    with store.engine.begin() as c:
        c.execute(sa.text("INSERT INTO datasets (id, name, path, format, frame_count, notes, added_at, options) "
                          "VALUES (1, 'd', '/d', 'kitti', 1, '', '2026-01-01', '{}')"))
        c.execute(sa.text("INSERT INTO models (id, name, spec, options, fingerprint, notes, added_at) "
                          "VALUES (1, 'm', 'pillars', '{}', 'f', '', '2026-01-01')"))
        for task_id, summary in ((1, "{}"), (2, '{"classes": ["Car"], "x": NaN}')):
            c.execute(sa.text(
                "INSERT INTO tasks (id, name, dataset_id, model_id, operators, relations, seed, status, done, total, "
                "created_at, summary, options, error, worker) VALUES (:id, '', 1, 1, '[]', '[\"auto\"]', 0, "
                "'pending', 0, 0, '2026-01-01', :summary, :options, '', '')"),
                {"id": task_id, "summary": summary, "options": json.dumps(old_options)})
        c.execute(sa.text(
            "INSERT INTO subtasks (id, task_id, operator_key, operator, name, op_index, severity, status, done, "
            "total, results) VALUES (1, 1, 'k', '{}', 'fuzz', 0, 0, 'running', 0, 8, :results)"),
            {"results": '{"relation_specs": [{"name": "preservation", "config": {}}], "state": {"next_index": 3}, '
                        '"search": {"coverage": {"nc": NaN}, "stats": {"tests": 3}}}'})
        c.execute(sa.text(
            "INSERT INTO frame_results (id, subtask_id, frame_id, trial, params, labels, gt_labels, cached, "
            "relations, seconds, created_at) VALUES (1, 1, '000001', 0, '{\"a\": NaN}', '[]', '[]', 0, :relations, "
            "0.1, '2026-01-01')"),
            {"relations": '[{"relation": "preservation", "holds": false, "applicable": true, "checked": {}, '
                          '"stats": {}, "violations": [{"relation": "preservation", "kind": "missing", '
                          '"magnitude": NaN, "range_m": Infinity}]}]'})
    store.migrate()
    assert store.revision() == "0009"
    with store.engine.connect() as c:
        raw = " ".join(str(v) for row in c.execute(sa.text(
            "SELECT t.summary, t.options, s.results, f.params, f.relations FROM tasks t, subtasks s, "
            "frame_results f")) for v in row)
    assert "NaN" not in raw and "Infinity" not in raw
    with store.session() as s:
        first, second = s.get(Task, 1), s.get(Task, 2)
        assert first.summary is None and second.summary is None  # an older shape: computed again
        assert first.options == TaskOptions(frame_ids=["000001"], kind="fuzz",
                                            kind_options={"kind": "fuzz", "budget": 8})
        sub = s.get(Subtask, 1)
        assert sub.plan.relation_names == ["preservation"] and sub.state == {"next_index": 3}
        assert sub.results.search is not None and math.isnan(sub.results.search.coverage["nc"])
        assert sub.results.search.stats == {"tests": 3}
        violation = s.get(FrameResult, 1).relations[0].violations[0]
        assert math.isnan(violation.magnitude) and math.isnan(violation.range_m)
        assert s.get(FrameResult, 1).params == {"a": None}
    with store.engine.connect() as c:  # the second task's summary keeps its (untyped, older) content, NaN as null
        stored = c.execute(sa.text("SELECT summary FROM tasks WHERE id = 2")).scalar_one()
    assert json.loads(stored) == {"classes": ["Car"], "x": None}
    assert isinstance(second, Task)
    store.close()


def test_the_summary_schema_names_every_field_the_summary_has() -> None:
    schema = TaskSummary.model_json_schema(mode="serialization", by_alias=True)
    assert set(schema["properties"]) == {"task", "classes", "subtasks", "delta_ap", "ap_warnings", "robustness",
                                         "violations", "findings", "run", "search", "deeptest", "kind_summary"}
    assert "class" in schema["$defs"]["DeltaRow"]["properties"]


def test_migration_0004_goes_back_down(tmp_path: Path) -> None:
    from alembic import command

    store = Store(tmp_path / "ws")
    _task(store)
    with store.engine.begin() as connection:
        command.downgrade(store._alembic(connection), "0003")
    with store.engine.connect() as c:
        results = c.execute(sa.text("SELECT results FROM subtasks WHERE name = 'fog'")).scalar_one()
        options = c.execute(sa.text("SELECT options FROM tasks")).scalar_one()
        columns = {row[1] for row in c.execute(sa.text("PRAGMA table_info(subtasks)"))}
    assert json.loads(results)["relation_specs"] == [{"name": "preservation", "config": {}}]
    assert json.loads(options)["relations"] == [] and "kind_options" not in json.loads(options)
    assert not {"plan", "state"} & columns
    store.migrate()
    assert store.revision() == "0009"
    store.close()
