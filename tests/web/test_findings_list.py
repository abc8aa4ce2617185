"""The findings list (``GET /api/tasks/{id}/findings``): counts, the severity, kind and subtask filters,
sorting, grouping of the same object at several severities, and the thumbnails
(``GET /api/findings/{id}/thumb.png``).

The task turns the scene by three severities of ``rotate_z`` on two frames with the classic
pipeline's bug-zoo variant whose ROI does not turn (conftest's ``classic``): it loses cars at some
severities, so the same car is flagged at several of them.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from fastapi.testclient import TestClient

from lidarfuzz.web import create_app
from lidarfuzz.web.routes.findings import group_rows, object_key
from tests.web.conftest import BASE, ORIGIN, register, wait_for


@pytest.fixture(scope="module")
def turned(tmp_path_factory: pytest.TempPathFactory, world: Path) -> Iterator[tuple[TestClient, int, Path]]:
    """A client, a task of rotate_z at severities 1, 3 and 5 run to the end, and its workspace."""
    workspace = tmp_path_factory.mktemp("web-findings-list") / "ws"
    register(workspace, world)
    with TestClient(create_app(workspace, inline=True), base_url=BASE, headers=ORIGIN) as client:
        reply = client.post("/api/tasks", json={"name": "turn", "dataset": "world", "sut": "classic",
                                                "operators": [{"name": "rotate_z", "severities": [1, 3, 5]}]})
        assert reply.status_code == 201, reply.text
        task_id = reply.json()["id"]
        assert wait_for(client, task_id)["status"] == "done"
        yield client, task_id, workspace


def listing(client: TestClient, task_id: int, **params: Any) -> dict[str, Any]:
    reply = client.get(f"/api/tasks/{task_id}/findings", params={"limit": 1000, **params})
    assert reply.status_code == 200, reply.text
    return dict(reply.json())


# -- the grouping rule, on rows written by hand -------------------------------------------------
def _row(id_: int, severity: int, objects: tuple[str, ...], frame: str = "000000", kind: str = "equivariance",
         cls: str = "Car") -> dict[str, Any]:
    return {"id": id_, "frame_id": frame, "operator": "rotate_z", "kind": kind, "class": cls, "severity": severity,
            "trial": 0, "label": f"rotate_z@{severity}", "magnitude": 1.0, "message": "", "objects": objects}


def test_object_key_names_the_originals_objects() -> None:
    # gt_index wins over source_index; -1 (none) and the follow-up's indices are not objects
    assert object_key({"violations": [{"gt_index": 3, "source_index": 7}, {"gt_index": -1, "source_index": 2}]}) \
        == ("gt3",)
    assert object_key({"violations": [{"gt_index": -1, "source_index": 9, "follow_index": 4},
                                      {"gt_index": -1, "source_index": 1}]}) == ("det1", "det9")
    assert object_key({"detail": "crashed"}) == () and object_key(None) == ()


def test_the_same_object_at_several_severities_is_one_group() -> None:
    rows = [_row(1, 3, ("det1", "det9")), _row(2, 3, ("det9",), kind="gt_recall"), _row(3, 3, ("det0",), "000001"),
            _row(4, 5, ("det1",)), _row(5, 5, ("det0", "det2"), "000001"), _row(6, 5, ("det4",)),
            _row(7, 1, ("det2",), "000001"), _row(8, 5, (), "000001", kind="crash", cls=""),
            _row(9, 3, (), "000001", kind="crash", cls="")]
    groups = group_rows(rows)
    # by hand: {1, 4} share det1; 2 is another relation; {3, 5, 7}: 3-5 share det0, 5-7 share det2;
    # 6 names det4 alone; the two crashes of frame 000001 name no object: one group
    assert [(g["id"], g["group"]["severities"], [m["id"] for m in g["group"]["members"]]) for g in groups] == [
        (1, [3, 5], [1, 4]), (2, [3], [2]), (3, [1, 3, 5], [7, 3, 5]), (6, [5], [6]), (8, [3, 5], [9, 8])]
    assert all("objects" not in g for g in groups) and groups[2]["group"]["size"] == 3


# -- the API ------------------------------------------------------------------------------------
def test_counts_and_the_severity_kind_and_subtask_filters(turned: tuple[TestClient, int, Path]) -> None:
    client, task_id, _ = turned
    everything = listing(client, task_id)
    items = everything["items"]
    assert everything["total"] == everything["total_all"] == len(items) > 0
    assert everything["groups"] is None and {"id", "subtask_id", "failure"} <= set(items[0])
    severities = sorted({f["severity"] for f in items})
    assert everything["facets"]["severity"] == severities and everything["facets"]["kind"] == ["violation"]
    for severity in severities:
        some = listing(client, task_id, severity=severity)
        assert some["total"] == sum(f["severity"] == severity for f in items) > 0
        assert some["total_all"] == len(items) and {f["severity"] for f in some["items"]} == {severity}
    # no failures here: the system held (every finding is a relation violated)
    assert listing(client, task_id, kind="violation")["total"] == len(items)
    assert listing(client, task_id, kind="failure")["total"] == 0
    subtasks = {s["label"]: s["id"] for s in client.get(f"/api/tasks/{task_id}").json()["subtasks"]}
    for label, subtask_id in subtasks.items():
        some = listing(client, task_id, subtask=subtask_id)
        assert some["total"] == sum(f["label"] == label for f in items)
        assert all(f["subtask_id"] == subtask_id for f in some["items"])
    assert client.get(f"/api/tasks/{task_id}/findings", params={"subtask": 99999}).status_code == 404
    wrong = client.get(f"/api/tasks/{task_id}/findings", params={"kind": "crashes"})
    assert wrong.status_code == 422 and "kind" in wrong.text


def test_sorting(turned: tuple[TestClient, int, Path]) -> None:
    client, task_id, _ = turned
    items = listing(client, task_id)["items"]
    ids = [f["id"] for f in items]
    assert ids == sorted(ids)  # the default: id order
    by = {key: [f["id"] for f in listing(client, task_id, sort=key)["items"]]
          for key in ("-magnitude", "magnitude", "-severity", "frame", "operator", "-id")}
    magnitude = {f["id"]: f["magnitude"] for f in items}
    # ties keep id order; a finding without a magnitude comes last either way
    assert by["-magnitude"] == sorted(ids, key=lambda i: (magnitude[i] is None, -(magnitude[i] or 0.0), i))
    assert by["magnitude"] == sorted(ids, key=lambda i: (magnitude[i] is None, magnitude[i] or 0.0, i))
    severity = {f["id"]: f["severity"] for f in items}
    assert by["-severity"] == sorted(ids, key=lambda i: (-severity[i], i))
    frame = {f["id"]: (f["frame_id"], f["trial"]) for f in items}
    assert by["frame"] == sorted(ids, key=lambda i: (frame[i], i))
    assert by["operator"] == sorted(ids, key=lambda i: (severity[i], i))  # one operator: then by severity
    assert by["-id"] == ids[::-1]
    wrong = client.get(f"/api/tasks/{task_id}/findings", params={"sort": "colour"})
    assert wrong.status_code == 422 and "sort" in wrong.text


def test_grouped_findings_page_over_groups(turned: tuple[TestClient, int, Path]) -> None:
    client, task_id, _ = turned
    items = listing(client, task_id)["items"]
    details = {f["id"]: client.get(f"/api/findings/{f['id']}").json()["detail"] for f in items}

    def objects(finding_id: int) -> set[int]:  # the original's objects a finding names, as the rule says
        violations = details[finding_id].get("violations", [])
        gt = {v["gt_index"] for v in violations if v.get("gt_index", -1) >= 0}
        return {("gt", i) for i in gt} or {("det", v["source_index"]) for v in violations
                                           if v.get("source_index", -1) >= 0}

    # the groups worked out again, naively: merge until no two groups share a scope and an object
    groups = [[f] for f in items]
    merged = True
    while merged:
        merged = False
        for a in range(len(groups)):
            for b in range(a + 1, len(groups)):
                if any((x["frame_id"], x["operator"], x["kind"], x["class"]) ==
                       (y["frame_id"], y["operator"], y["kind"], y["class"]) and objects(x["id"]) & objects(y["id"])
                       for x in groups[a] for y in groups[b]):
                    groups[a] += groups.pop(b)
                    merged = True
                    break
            if merged:
                break
    expected = sorted(sorted(f["id"] for f in g) for g in groups)
    grouped = listing(client, task_id, group=True)
    assert grouped["total"] == len(items) and grouped["groups"] == len(expected)
    assert sorted(sorted(m["id"] for m in g["group"]["members"]) for g in grouped["items"]) == expected
    assert any(g["group"]["size"] > 1 for g in grouped["items"]), "the turn should flag a car at two severities"
    for g in grouped["items"]:
        assert g["group"]["severities"] == sorted({m["severity"] for m in g["group"]["members"]})
        assert g["id"] == min(m["id"] for m in g["group"]["members"])  # id order: a group is its first finding
    second = listing(client, task_id, group=True, limit=1, offset=1)
    assert [g["id"] for g in second["items"]] == [grouped["items"][1]["id"]] and second["groups"] == len(expected)


def test_a_kept_grouping_follows_new_findings(turned: tuple[TestClient, int, Path]) -> None:
    """Groupings are kept with the app while the findings are the same: a finding added (as a running
    task adds them) shows at once."""
    from sqlalchemy import delete, insert, select

    from lidarfuzz.store import Store
    from lidarfuzz.store.models import Finding

    client, task_id, workspace = turned
    before = listing(client, task_id, group=True)
    store = Store(workspace)
    try:
        with store.session() as s:
            model = s.execute(select(Finding).where(Finding.task_id == task_id).order_by(Finding.id)).scalars().first()
            # the same frame result and relation, about an object no other finding names: a group of its own
            s.execute(insert(Finding), [{"task_id": task_id, "frame_result_id": model.frame_result_id,
                                         "kind": model.kind, "cls": model.cls, "magnitude": 9.0, "message": "added",
                                         "detail": {"violations": [{"source_index": 77, "gt_index": -1}]},
                                         "replay": model.replay}])
            s.commit()
        after = listing(client, task_id, group=True)
        assert (after["total"], after["groups"]) == (before["total"] + 1, before["groups"] + 1)
        assert after["items"][-1]["message"] == "added" and after["items"][-1]["group"]["size"] == 1
    finally:
        with store.session() as s:
            s.execute(delete(Finding).where(Finding.message == "added"))
            s.commit()
        store.close()
    assert listing(client, task_id, group=True)["groups"] == before["groups"]


def test_a_findings_thumbnail_is_small_and_cached(turned: tuple[TestClient, int, Path]) -> None:
    client, task_id, workspace = turned
    finding_id = listing(client, task_id)["items"][0]["id"]
    reply = client.get(f"/api/findings/{finding_id}/thumb.png")
    assert reply.status_code == 200 and reply.headers["content-type"] == "image/png"
    image = cv2.imdecode(np.frombuffer(reply.content, np.uint8), cv2.IMREAD_COLOR)
    assert image.shape == (120, 160, 3)
    # the dashed red box of the lost car (bev's HIGHLIGHT_COLOUR #d7191c; BGR here), near enough after the palette
    red = (np.abs(image.astype(int) - [28, 25, 215]).max(axis=-1) < 40).sum()
    assert red > 10, f"no highlighted box in the thumbnail ({red} red pixels)"
    cached = list((workspace / "cache" / "web" / "thumbs").glob(f"{finding_id}-*.png"))
    assert len(cached) == 1 and cached[0].read_bytes() == reply.content
    assert client.get(f"/api/findings/{finding_id}/thumb.png").content == reply.content
    assert client.get("/api/findings/99999/thumb.png").status_code == 404


@pytest.fixture(scope="module")
def camera_task(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[TestClient, int]]:
    """A finished camera task (fog @5 on tests/web/test_camera.py's road images and steering net)."""
    pytest.importorskip("torch")
    from lidarfuzz.store import Store
    from lidarfuzz.store.inventory import add_model
    from tests.web.test_camera import NET, camera_files, upload

    root = tmp_path_factory.mktemp("web-findings-camera")
    paths = camera_files(root / "files")
    store = Store(root / "ws")
    add_model(store, "net", NET, modality="camera")
    store.close()
    with TestClient(create_app(root / "ws", inline=True), base_url=BASE, headers=ORIGIN) as client:
        assert upload(client, "road", paths).status_code == 201
        reply = client.post("/api/tasks", json={"kind": "camera", "dataset": "road", "sut": "net",
                                                "operators": [{"name": "image_fog", "severities": [5]}]})
        assert reply.status_code == 201, reply.text
        assert wait_for(client, reply.json()["id"], timeout=120)["status"] == "done"
        yield client, reply.json()["id"]


def test_a_camera_findings_thumbnail_is_its_transformed_image(camera_task: tuple[TestClient, int]) -> None:
    client, task_id = camera_task
    items = listing(client, task_id)["items"]
    assert items, "fog @5 should make the net miss a label"
    reply = client.get(f"/api/findings/{items[0]['id']}/thumb.png")
    assert reply.status_code == 200
    image = cv2.imdecode(np.frombuffer(reply.content, np.uint8), cv2.IMREAD_COLOR)
    # the road images are 200 × 66: 160 wide keeps the ratio, 66 × 160 / 200 = 52.8 → 53 rows
    assert image.shape == (53, 160, 3)
