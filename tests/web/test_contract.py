"""The front end reads the task's JSON Schema rather than guessing shapes: the API serves the
summary's schema (the store's :class:`~lidarfuzz.store.contracts.TaskSummary`) and the task
detail's, whose statuses are an enum; and every task, subtask and AP field the front-end pages read
is one those schemas declare (read from the JavaScript sources, so a guessed field fails here)."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from lidarfuzz.store.contracts import summary_schema
from lidarfuzz.web.routes.tasks import TaskRow, task_schema

SOURCES = Path(__file__).resolve().parents[2] / "web" / "frontend" / "src"
STATUSES = ["pending", "running", "done", "failed", "cancelled"]

# source file -> variable -> the schema definition it holds (the pages' naming convention)
READS = {
    "pages/tasks.js": {"task": "TaskRow"},
    "pages/taskdetail.js": {"task": "TaskDetail", "s": "SubtaskRow", "sub": "SubtaskRow", "mine": "SubtaskRow",
                            "now": "RunningSubtask"},
    "chart.js": {"subtask": "SubtaskRow", "ap": "APRecord"},
}


def definitions() -> dict[str, dict[str, Any]]:
    """The task schema's definitions by name, the task detail and the task list's rows among them."""
    task = task_schema()
    return {**task["$defs"], "TaskDetail": task, "TaskRow": TaskRow.model_json_schema(mode="serialization")}


def declared(schema: dict[str, Any], name: str) -> set[str]:
    node = schema if schema.get("title") == name else schema["$defs"][name]
    return set(node["properties"])


def fields_read(source: str, variable: str) -> set[str]:
    """Properties read as ``variable.x`` or ``variable?.x``."""
    return set(re.findall(rf"(?<![\w.$]){re.escape(variable)}\??\.([A-Za-z_]\w*)", source))


def status_enum(schema: dict[str, Any], name: str) -> list[str]:
    prop = (schema if schema.get("title") == name else schema["$defs"][name])["properties"]["status"]
    target = schema["$defs"][prop["$ref"].split("/")[-1]] if "$ref" in prop else prop
    return list(target["enum"])


def test_the_api_serves_the_schemas(client: TestClient) -> None:
    summary = client.get("/api/schemas/summary")
    assert summary.status_code == 200 and summary.json() == summary_schema()
    assert summary.json()["title"] == "TaskSummary"
    task = client.get("/api/schemas/task").json()
    assert task == task_schema() and task["title"] == "TaskDetail"
    assert task["x-final-statuses"] == ["done", "failed", "cancelled"]
    # the detail's summary is the store's contract, not a copy of it
    assert task["properties"]["summary"]["anyOf"][0] == {"$ref": "#/$defs/TaskSummary"}
    assert declared(task, "TaskSummary") == declared(summary_schema(), "TaskSummary")


@pytest.mark.parametrize(("schema", "definition"), [(summary_schema(), "TaskInfo"),
                                                    (summary_schema(), "SubtaskSummary"),
                                                    (task_schema(), "TaskDetail"), (task_schema(), "SubtaskRow")])
def test_statuses_are_an_enum_of_the_stores_values(schema: dict[str, Any], definition: str) -> None:
    assert status_enum(schema, definition) == STATUSES


def test_the_detail_reply_is_what_its_schema_declares(finished: tuple[TestClient, int]) -> None:
    client, task_id = finished
    schema = task_schema()
    detail = client.get(f"/api/tasks/{task_id}").json()
    assert set(detail) == declared(schema, "TaskDetail")
    assert all(set(sub) == declared(schema, "SubtaskRow") for sub in detail["subtasks"])
    row = next(item for item in client.get("/api/tasks").json()["items"] if item["id"] == task_id)
    assert set(row) == set(definitions()["TaskRow"]["properties"])


@pytest.mark.parametrize("path", sorted(READS))
def test_the_front_end_reads_only_declared_fields(path: str) -> None:
    source = (SOURCES / path).read_text(encoding="utf-8")
    schemas = definitions()
    for variable, definition in READS[path].items():
        read = fields_read(source, variable)
        assert read, f"{path} reads nothing from {variable}: the naming convention changed"
        unknown = read - set(schemas[definition]["properties"])
        assert not unknown, f"{path} reads {sorted(unknown)} from {variable}, which {definition} does not declare"


def test_the_fields_read_are_found() -> None:
    # the scanner itself: what the task list reads from a task
    source = (SOURCES / "pages/tasks.js").read_text(encoding="utf-8")
    assert fields_read(source, "task") == {"id", "name", "kind", "status", "dataset", "model", "headline", "tags",
                                           "notes", "started_at", "finished_at", "done", "total"}
    assert fields_read("a.task.x; task?.y; subtask.z; task.w.v", "task") == {"y", "w"}


@pytest.mark.parametrize("path", ["pages/tasks.js", "pages/taskdetail.js", "contract.js"])
def test_the_pages_take_statuses_from_the_schema(path: str) -> None:
    source = (SOURCES / path).read_text(encoding="utf-8")
    status = "|".join([*STATUSES, "completed", "succeeded", "queued", "cancelling"])
    compared = re.findall(rf'[=!]==?\s*"({status})"|"({status})"\s*[=!]==?', source)
    listed = [items for items in re.findall(r"\[([^\[\]]*)\]", source)
              if len(re.findall(rf'"({status})"', items)) >= 2]
    assert not compared and not listed, f"{path} hard-codes statuses: {compared or listed}"
    assert "statusesOf(" in source


def test_the_status_check_finds_hard_coded_statuses() -> None:
    old = 'const FINISHED = new Set(["done", "failed"]); if (s.status === "running") go();'
    status = "|".join(STATUSES)
    assert re.findall(rf'[=!]==?\s*"({status})"', old) == ["running"]
    assert re.findall(r"\[([^\[\]]*)\]", old) == ['"done", "failed"']
