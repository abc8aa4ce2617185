"""The run tracker's API: the task list sorted, searched and filtered in SQL (SQLite and
PostgreSQL), headline figures, tags and notes (PATCH), and two or more tasks compared."""

from __future__ import annotations

import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from lidarfuzz.campaign.headline import headline
from lidarfuzz.store import Store
from lidarfuzz.store.contracts import TaskSummary
from lidarfuzz.store.inventory import add_dataset, add_model
from lidarfuzz.store.models import Status, Task
from tests.web.conftest import TURN, register, wait_for


def ids(reply: Any) -> list[int]:
    assert reply.status_code == 200, reply.text
    return [t["id"] for t in reply.json()["items"]]


# -- headline figures --------------------------------------------------------------------------
def _summary() -> TaskSummary:
    """Originals with 3D moderate mAP 60 % (from one frame: a warning), two mutants (ΔmAP -5 and -20.5;
    a BEV row of -40 that the headline must ignore), violations 3/10 and 4/10 over two relations,
    failures 1 + 2."""
    info = {"id": 1, "status": "done", "dataset": {"name": "d", "path": "/p", "format": "kitti"},
            "model": {"name": "m", "spec": "classic", "fingerprint": "f"}}
    original_ap = {"ap": {}, "map": {"3d": {"moderate": {"R40": 60.0, "R11": 61.0}},
                                     "bev": {"moderate": {"R40": 70.0}}}}
    delta = [{"label": label, "operator": "fog", "severity": sev, "metric": metric, "class": cls,
              "difficulty": "moderate", "clean": 60.0, "corrupted": 60.0 + d, "delta": d}
             for label, sev, metric, cls, d in [("fog@1", 1, "3d", "mAP", -5.0), ("fog@5", 5, "3d", "mAP", -20.5),
                                                ("fog@5", 5, "bev", "mAP", -40.0), ("fog@5", 5, "3d", "Car", -50.0)]]
    return TaskSummary.model_validate({
        "task": info, "classes": ["Car"], "delta_ap": delta, "ap_warnings": ["AP from a single frame"],
        "subtasks": [{"id": 1, "label": "original", "operator": "original", "ap": original_ap, "failures": 0},
                     {"id": 2, "label": "fog@1", "operator": "fog", "severity": 1, "failures": 1},
                     {"id": 3, "label": "fog@5", "operator": "fog", "severity": 5, "failures": 2}],
        "violations": {"relation": [{"relation": "gt_recall", "checked": 10, "violated": 3},
                                    {"relation": "equivariance", "checked": 10, "violated": 4}]}})


def test_headline_reads_the_summary() -> None:
    # by hand: map = the originals' 3D moderate R40 = 60.0; worst 3D mAP Δ = min(-5, -20.5) = -20.5 (the
    # BEV -40 and the Car-only -50 are other rows); violations 3 + 4 = 7 of 20 = 0.35; failures 0 + 1 + 2 = 3
    assert headline(_summary()) == {"map": 60.0, "delta_map": -20.5, "violations": 7, "checked": 20,
                                    "violation_rate": 0.35, "failures": 3, "ap_warnings": 1}
    assert headline(None) == dict.fromkeys(("map", "delta_map", "violations", "checked", "violation_rate",
                                            "failures", "ap_warnings"))


def test_a_finished_task_has_its_headline_and_an_older_one_gets_it(
        make_client: Callable[..., TestClient], tmp_path: Path, world: Path) -> None:
    register(tmp_path / "ws", world)
    client = make_client()
    task_id = client.post("/api/tasks", json={"dataset": "world", "sut": "classic", "operators": TURN}).json()["id"]
    detail = wait_for(client, task_id)
    assert detail["status"] == "done"
    # expected from the task's own detail: the originals' 3D mAP, the mutant's ΔmAP, its frame-level
    # violations summed over relations, failures summed over subtasks
    original, mutant = detail["subtasks"]
    expected = {"map": original["ap_moderate"]["3d"]["mAP"],
                "delta_map": mutant["ap_moderate"]["3d"]["mAP"] - original["ap_moderate"]["3d"]["mAP"],
                "violations": sum(r["violated"] for r in mutant["violations"]),
                "checked": sum(r["checked"] for r in mutant["violations"]),
                "failures": original["failures"] + mutant["failures"],
                "ap_warnings": len(detail["summary"]["ap_warnings"])}
    expected["violation_rate"] = expected["violations"] / expected["checked"]
    assert expected["checked"] > 0 and detail["headline"] == pytest.approx(expected)
    store = Store(tmp_path / "ws")
    with store.session() as s:  # as a task finished before the column existed
        s.get(Task, task_id).headline = None
    store.close()
    reopened = make_client(workers=0)  # the workspace opened by this version: filled from the summary
    row = reopened.get("/api/tasks").json()["items"][0]
    assert row["headline"] == pytest.approx(expected)


# -- sorting, searching, filtering -------------------------------------------------------------
def _tracker_tasks(client: TestClient, workspace: str | Path) -> list[int]:
    """Four tasks with hand-set states, headlines, tags and notes (see the table in the test)."""
    made = [client.post("/api/tasks", json={"dataset": "world", "sut": sut, "operators": TURN}).json()["id"]
            for sut in ("classic", "classic", "classic", "good")]
    rows = [("fog baseline", Status.DONE, {"map": 70.0, "delta_map": -12.5, "violations": 3, "failures": 0},
             ["fog", "v1"], "fogx2 looked fine"),
            ("Rain check", Status.DONE, {"map": 55.5, "delta_map": -30.0, "violations": 10, "failures": 2},
             ["rain"], "retrained on fog_2"),
            ("alpha", Status.FAILED, None, [], ""),
            ("fog sweep", Status.DONE, {"map": None, "delta_map": None, "violations": 0, "failures": 1}, ["fog"], "")]
    store = Store(workspace)
    with store.session() as s:
        for task_id, (name, state, figures, tags, notes) in zip(made, rows, strict=True):
            task = s.get(Task, task_id)
            task.name, task.status, task.headline, task.tags, task.notes = name, state, figures, tags, notes
    store.close()
    return made


@pytest.fixture(params=["sqlite", "postgresql"])
def tracker(request: pytest.FixtureRequest, make_client: Callable[..., TestClient], tmp_path: Path,
            world: Path) -> tuple[TestClient, list[int]]:
    workspace: str | Path = tmp_path / "ws"
    if request.param == "postgresql":
        workspace = request.getfixturevalue("fresh_postgres_url")
    register(workspace, world)  # type: ignore[arg-type]
    store = Store(workspace)
    add_model(store, "good", "classic")
    store.close()
    client = make_client(workspace, workers=0, files=tmp_path / "files")
    return client, _tracker_tasks(client, workspace)


@pytest.mark.parametrize(("params", "order"), [
    # ids by the table's rows: 1 fog baseline, 2 Rain check, 3 alpha, 4 fog sweep; a task without the figure
    # last either way, ties newest first
    ({}, [4, 3, 2, 1]),
    ({"sort": "map"}, [2, 1, 4, 3]),  # 55.5 < 70.0, then no mAP (4) and no headline (3)
    ({"sort": "-map"}, [1, 2, 4, 3]),
    ({"sort": "delta_map"}, [2, 1, 4, 3]),  # -30 < -12.5
    ({"sort": "-violations"}, [2, 1, 4, 3]),  # 10, 3, 0, none
    ({"sort": "-failures"}, [2, 4, 1, 3]),  # 2, 1, 0, none
    ({"sort": "name"}, [3, 1, 4, 2]),  # alpha, fog baseline, fog sweep, rain check (any case)
    ({"sort": "model"}, [3, 2, 1, 4]),  # classic (ties newest first), then good
    ({"sort": "id"}, [1, 2, 3, 4]),
    ({"q": "fog"}, [4, 2, 1]),  # names 1 and 4, and 2's notes
    ({"q": "FOG_2"}, [2]),  # the underscore is a character, not LIKE's wildcard (1's notes say fogx2)
    ({"q": "good"}, [4]),  # the model's name
    ({"q": "failed"}, [3]),  # the status
    ({"q": "v1"}, [1]),  # a tag
    ({"tag": "fog"}, [4, 1]),  # whole tags: not 2, whose notes say fog
    ({"tag": ["fog", "v1"]}, [1]),
    ({"tag": "fo"}, []),
    ({"status": "done", "q": "fog", "sort": "-map"}, [1, 2, 4]),
    ({"status": "failed"}, [3]),
])
def test_the_list_sorts_searches_and_filters(tracker: tuple[TestClient, list[int]], params: dict[str, Any],
                                             order: list[int]) -> None:
    client, made = tracker
    reply = client.get("/api/tasks", params=params)
    assert ids(reply) == [made[i - 1] for i in order]
    assert reply.json()["total"] == len(order)
    first = client.get("/api/tasks", params={**params, "limit": 1, "offset": 1})
    assert ids(first) == [made[i - 1] for i in order[1:2]] and first.json()["total"] == len(order)


def test_an_unknown_sort_is_a_422_naming_it(client: TestClient) -> None:
    reply = client.get("/api/tasks", params={"sort": "-speed"})
    assert reply.status_code == 422 and "'sort'" in reply.json()["detail"] and "delta_map" in reply.json()["detail"]


# -- tags and notes -----------------------------------------------------------------------------
def test_tags_and_notes_are_edited_and_checked(make_client: Callable[..., TestClient], tmp_path: Path,
                                               world: Path) -> None:
    register(tmp_path / "ws", world)
    client = make_client(workers=0)
    task_id = client.post("/api/tasks", json={"dataset": "world", "sut": "classic", "operators": TURN}).json()["id"]
    reply = client.patch(f"/api/tasks/{task_id}", json={"tags": ["Fog", "v1.2", "Fog"], "notes": "before retraining"})
    assert reply.status_code == 200, reply.text
    assert reply.json()["tags"] == ["Fog", "v1.2"] and reply.json()["notes"] == "before retraining"
    assert client.patch(f"/api/tasks/{task_id}", json={"notes": ""}).json()["tags"] == ["Fog", "v1.2"]  # tags kept
    row = client.get("/api/tasks").json()["items"][0]
    assert row["tags"] == ["Fog", "v1.2"] and row["notes"] == ""
    assert client.get(f"/api/tasks/{task_id}").json()["tags"] == ["Fog", "v1.2"]

    bad = client.patch(f"/api/tasks/{task_id}", json={"tags": ["ok", "two words"]})
    assert bad.status_code == 422 and "'tags.1'" in bad.json()["detail"], bad.text
    assert "'tags.0'" in client.patch(f"/api/tasks/{task_id}", json={"tags": ["x" * 33]}).json()["detail"]
    too_many = client.patch(f"/api/tasks/{task_id}", json={"tags": [f"t{i}" for i in range(21)]})
    assert too_many.status_code == 422 and too_many.json()["detail"][0]["loc"] == ["body", "tags"]
    long_notes = client.patch(f"/api/tasks/{task_id}", json={"notes": "n" * 10_001})
    assert long_notes.status_code == 422 and long_notes.json()["detail"][0]["loc"] == ["body", "notes"]
    extra = client.patch(f"/api/tasks/{task_id}", json={"name": "renamed"})
    assert extra.status_code == 422 and extra.json()["detail"][0]["loc"] == ["body", "name"]
    assert client.patch("/api/tasks/999", json={"notes": "x"}).status_code == 404
    assert client.get(f"/api/tasks/{task_id}").json()["tags"] == ["Fog", "v1.2"]  # nothing refused was kept


# -- comparing tasks ----------------------------------------------------------------------------
@pytest.fixture(scope="module")
def compared(tmp_path_factory: pytest.TempPathFactory, world: Path) -> Any:
    """Four finished tasks of the turn at severity 3, six trials per frame (12 mutants): 1 the bug-zoo
    pipeline (its ROI does not turn with the scene), 2 the correct pipeline (same campaign: comparable),
    3 the correct pipeline with another seed, 4 on a copy of the world (another data set)."""
    from lidarfuzz.web import create_app
    from tests.web.conftest import BASE, ORIGIN

    root = tmp_path_factory.mktemp("compare")
    copy = shutil.copytree(world, root / "copy")
    register(root / "ws", world)
    store = Store(root / "ws")
    add_model(store, "good", "classic")
    add_dataset(store, "copy", copy)
    store.close()
    with TestClient(create_app(root / "ws", inline=True), base_url=BASE, headers=ORIGIN) as client:
        made = []
        for sut, seed, dataset in (("classic", 0, "world"), ("good", 0, "world"), ("good", 1, "world"),
                                   ("good", 0, "copy")):
            made.append(client.post("/api/tasks", json={"dataset": dataset, "sut": sut, "operators": TURN,
                                                        "trials": 6, "seed": seed}).json()["id"])
        for task_id in made:
            assert wait_for(client, task_id, timeout=120)["status"] == "done"
        yield client, made


def _row(pair: dict[str, Any], relation: str) -> dict[str, Any]:
    return next(r for r in pair["rows"] if r["label"] == "rotate_z@3" and r["relation"] == relation)


def test_two_systems_on_the_same_mutants_are_tested(compared: Any) -> None:
    client, (bug, good, _, _) = compared
    reply = client.get("/api/compare", params={"tasks": f"{bug},{good}"})
    assert reply.status_code == 200, reply.text
    body = reply.json()
    assert [t["id"] for t in body["tasks"]] == [bug, good] and body["baseline"] == bug
    (pair,) = body["pairs"]
    assert pair["comparable"] and pair["reason"] is None and pair["task"] == good
    row = _row(pair, "equivariance")
    # the bug's ROI stays put while the scene turns: every one of the 12 turned frames violates; the correct
    # pipeline none. One-sided Fisher, 0/12 below 12/12: p = 1 / C(24, 12) = 1 / 2,704,156 = 3.7e-7, far below
    # α/2 = 0.025 after any correction over the handful of rows
    assert (row["violated"], row["checked"], row["violated_baseline"], row["checked_baseline"]) == (0, 12, 12, 12)
    assert row["difference"] == -1.0 and row["significant"] == "better"
    assert 1 / 2_704_156 * 0.999 <= row["p_better"] < 0.025 and row["p_worse"] == 1.0
    # the same pair the other way round: the bug is significantly worse than the correct baseline
    flipped = _row(client.get("/api/compare", params={"tasks": f"{good},{bug}"}).json()["pairs"][0], "equivariance")
    assert flipped["significant"] == "worse" and flipped["p_worse"] == row["p_better"]


def test_the_ap_table_has_each_task_and_its_delta(compared: Any) -> None:
    client, (bug, good, _, _) = compared
    body = client.get("/api/compare", params={"tasks": f"{bug},{good}"}).json()
    assert [r["label"] for r in body["rows"]] == ["original", "rotate_z@3"]
    for index, task_id in enumerate((bug, good)):
        original, mutant = client.get(f"/api/tasks/{task_id}").json()["subtasks"]
        cells = [row["cells"][index] for row in body["rows"]]
        assert cells[0]["ap"] == original["ap_moderate"] and cells[0]["delta"] is None
        assert cells[1]["ap"] == mutant["ap_moderate"]
        for metric in ("bbox", "bev", "3d"):  # Δ = the mutant's AP − this task's originals'
            assert cells[1]["delta"][metric]["mAP"] == pytest.approx(
                mutant["ap_moderate"][metric]["mAP"] - original["ap_moderate"][metric]["mAP"])
        assert cells[1]["violations"] == mutant["violations"]
    assert "not tested" in body["tested"]


def test_tasks_that_are_not_comparable_say_why(compared: Any, make_client: Callable[..., TestClient]) -> None:
    client, (bug, good, other_seed, other_data) = compared
    body = client.get("/api/compare", params={"tasks": f"{good},{bug},{other_seed},{other_data}"}).json()
    assert [p["baseline"] for p in body["pairs"]] == [good] * 3
    bug_pair, seed_pair, data_pair = body["pairs"]
    assert bug_pair["comparable"] and _row(bug_pair, "equivariance")["significant"] == "worse"
    assert not seed_pair["comparable"] and seed_pair["rows"] == []
    assert seed_pair["reason"] == f"seed 1 (task {other_seed}) against 0 (task {good}); the mutants differ"
    assert data_pair["reason"] == f"different data sets: task {other_data} ran 'copy', task {good} 'world'"
    assert "/" not in data_pair["reason"].split("sets:")[1]  # names, not server paths
    assert all(len(r["cells"]) == 4 for r in body["rows"])  # the AP table still has every task


@pytest.mark.parametrize(("tasks", "code", "named"), [
    ("1", 422, "'tasks'"), ("1,1", 422, "'tasks'"), ("a,b", 422, "'tasks'"), ("1,2,3,4,5,6,7", 422, "'tasks'"),
    ("1,999", 404, "999")])
def test_a_bad_comparison_names_the_field(compared: Any, tasks: str, code: int, named: str) -> None:
    client, _ = compared
    reply = client.get("/api/compare", params={"tasks": tasks})
    assert reply.status_code == code and named in reply.json()["detail"], reply.text


def test_an_unfinished_task_is_not_tested(make_client: Callable[..., TestClient], tmp_path: Path,
                                          world: Path) -> None:
    register(tmp_path / "ws", world)
    client = make_client(workers=0)
    a, b = (client.post("/api/tasks", json={"dataset": "world", "sut": "classic", "operators": TURN}).json()["id"]
            for _ in range(2))
    (pair,) = client.get("/api/compare", params={"tasks": f"{a},{b}"}).json()["pairs"]
    # the tested task (the second) is named first: TURN on two frames is 2 originals + 2 turned = 4 units
    assert pair["reason"] == f"task {b} is pending (0/4 units): only finished tasks are tested"


def test_only_detection_campaigns_are_tested(make_client: Callable[..., TestClient], tmp_path: Path,
                                            world: Path) -> None:
    register(tmp_path / "ws", world)
    client = make_client(workers=0)
    a, b = (client.post("/api/tasks", json={"dataset": "world", "sut": "classic", "operators": TURN}).json()["id"]
            for _ in range(2))
    store = Store(tmp_path / "ws")
    with store.session() as s:  # both finished; b as a guided search (its tests are its own: no shared mutants)
        for task_id in (a, b):
            s.get(Task, task_id).status = Status.DONE
        task = s.get(Task, b)
        task.options = task.options.model_copy(update={"kind": "guided"})
    store.close()
    (pair,) = client.get("/api/compare", params={"tasks": f"{a},{b}"}).json()["pairs"]
    assert pair["reason"] == (f"task {b} is a guided task: violation rates are tested between detection campaigns "
                              "(operators × severities)")


def test_the_cli_list_shows_the_tags_set_in_the_web_app(make_client: Callable[..., TestClient], tmp_path: Path,
                                                        world: Path) -> None:
    import json

    from typer.testing import CliRunner

    from lidarfuzz.cli.app import app

    register(tmp_path / "ws", world)
    client = make_client(workers=0)
    task_id = client.post("/api/tasks", json={"dataset": "world", "sut": "classic", "operators": TURN}).json()["id"]
    client.patch(f"/api/tasks/{task_id}", json={"tags": ["fog", "v2"]})
    result = CliRunner().invoke(app, ["list", "--json", "--workspace", str(tmp_path / "ws")])
    assert result.exit_code == 0, result.output
    assert json.loads(result.output)[0]["tags"] == ["fog", "v2"]
    plain = CliRunner().invoke(app, ["list", "--plain", "--workspace", str(tmp_path / "ws")]).output
    assert "fog, v2" in plain
