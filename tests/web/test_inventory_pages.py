"""The data-set and model pages' API: notes (given at upload or registration, changed by PATCH),
each model's type and modality, how many uploaded frames have labels (with the warning the page
shows), refusals to forget what a task uses (naming the tasks), and upload errors that name the
user's files, never the server's folders."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from tests.web.conftest import TURN, wait_for


def world_files(world: Path, *, labels: tuple[str, ...] = ("000000", "000001")) -> list[tuple[str, bytes]]:
    """The world's two scans and calibrations, with the label files of the frames in ``labels``."""
    files = [(f"{stem}.bin", (world / "velodyne" / f"{stem}.bin").read_bytes()) for stem in ("000000", "000001")]
    files += [(f"{stem}.txt", (world / "calib" / f"{stem}.txt").read_bytes()) for stem in ("000000", "000001")]
    return files + [(f"{stem}.txt", (world / "label_2" / f"{stem}.txt").read_bytes()) for stem in labels]


def upload(client: TestClient, name: str, files: list[tuple[str, bytes]], **fields: str) -> Any:
    return client.post("/api/datasets/upload", data={"name": name, **fields},
                       files=[("files", (filename, data)) for filename, data in files])


# -- notes ---------------------------------------------------------------------------------------
def test_a_data_sets_notes_are_kept_shown_and_changed(client: TestClient, world: Path) -> None:
    reply = upload(client, "scans", world_files(world), notes="two HDL-64E frames, seed 0")
    assert reply.status_code == 201, reply.text
    assert reply.json()["notes"] == "two HDL-64E frames, seed 0"
    listed = {d["name"]: d for d in client.get("/api/datasets").json()["items"]}
    assert listed["scans"]["notes"] == "two HDL-64E frames, seed 0"
    changed = client.patch("/api/datasets/scans", json={"notes": "for the fog study"})
    assert changed.status_code == 200 and changed.json()["notes"] == "for the fog study"
    assert client.get("/api/datasets/scans").json()["notes"] == "for the fog study"
    # without notes an upload says what was uploaded (4 files of 6, then how many more)
    plain = upload(client, "plain", world_files(world))
    assert plain.json()["notes"] == "uploaded: 000000.bin, 000001.bin, 000000.txt, 000001.txt, 000000.txt and 1 more"


@pytest.mark.parametrize(("body", "field"), [({"notes": 3}, "notes"), ({"notes": "x" * 10_001}, "notes"),
                                              ({"notes": "ok", "path": "/etc"}, "path"), ({}, "notes")])
def test_bad_notes_are_a_422_naming_the_field(client: TestClient, body: dict[str, Any], field: str) -> None:
    for url in ("/api/datasets/world", "/api/models/classic"):
        reply = client.patch(url, json=body)
        assert reply.status_code == 422, reply.text
        assert [e["loc"][-1] for e in reply.json()["detail"]] == [field]


def test_notes_longer_than_the_limit_are_refused_at_upload(client: TestClient, world: Path, tmp_path: Path) -> None:
    reply = upload(client, "long", world_files(world), notes="x" * 10_001)
    assert reply.status_code == 422 and reply.json()["detail"] == "notes: 10001 characters; at most 10000"
    assert not (tmp_path / "ws" / "uploads").exists() or not any((tmp_path / "ws" / "uploads").iterdir())


def test_notes_of_what_does_not_exist_are_a_404(client: TestClient) -> None:
    for url in ("/api/datasets/nothing", "/api/models/nothing"):
        reply = client.patch(url, json={"notes": "x"})
        assert reply.status_code == 404 and "lidarfuzz" not in reply.json()["detail"]
        assert client.get(url).status_code == 404


def test_a_models_notes_are_kept_shown_and_changed(client: TestClient) -> None:
    reply = client.post("/api/models", json={"name": "strict", "spec": "classic", "notes": "min_points 8 for fog"})
    assert reply.status_code == 201 and reply.json()["notes"] == "min_points 8 for fog"
    assert client.patch("/api/models/strict", json={"notes": "retired"}).json()["notes"] == "retired"
    assert {m["name"]: m["notes"] for m in client.get("/api/models").json()["items"]}["strict"] == "retired"
    too_long = client.post("/api/models", json={"name": "long", "spec": "classic", "notes": "x" * 10_001})
    assert too_long.status_code == 422 and too_long.json()["detail"][0]["loc"] == ["body", "notes"]


# -- the model type and modality -------------------------------------------------------------------
@pytest.mark.parametrize(("spec", "modality", "expected"), [
    ("classic", "lidar", ("classic", "classic pipeline", "lidar")),
    ("classic-bug-roi-cache", "lidar", ("bugzoo", "bug-zoo variant of the classic pipeline", "lidar")),
    ("lidarfuzz.suts.classic:ClassicPipeline", "lidar", ("classic", "classic pipeline", "lidar")),
    ("pillars", "lidar", ("pillars", "learned PointPillars", "lidar")),
    ("dave2", "camera", ("steering", "built-in steering network", "camera")),
])
def test_each_model_says_its_type_and_modality(client: TestClient, spec: str, modality: str,
                                               expected: tuple[str, str, str]) -> None:
    reply = client.post("/api/models", json={"name": "m", "spec": spec, "modality": modality})
    assert reply.status_code == 201, reply.text
    for row in (reply.json(), {m["name"]: m for m in client.get("/api/models").json()["items"]}["m"],
                client.get("/api/models/m").json()):
        assert (row["type"], row["type_label"], row["modality"]) == expected


def test_an_uploaded_onnx_model_is_of_type_onnx(client: TestClient, tmp_path: Path) -> None:
    pytest.importorskip("onnxruntime")
    from tests.web.test_api import _tiny_onnx

    model = _tiny_onnx(tmp_path / "detector.onnx")
    reply = client.post("/api/models/upload", data={"name": "net", "notes": "exported from mmdet3d"},
                        files={"file": ("detector.onnx", model.read_bytes())})
    assert reply.status_code == 201, reply.text
    assert (reply.json()["type"], reply.json()["modality"], reply.json()["notes"]) == \
        ("onnx", "lidar", "exported from mmdet3d")


def test_a_model_the_registry_cannot_build_any_more_says_so(client: TestClient, tmp_path: Path) -> None:
    from lidarfuzz.store import Store
    from lidarfuzz.store.models import Model

    store = Store(tmp_path / "ws")  # a plugin registered from the CLI, uninstalled since
    with store.session() as s:
        s.add(Model(name="gone", spec="not_installed.module:Detector", options={}, fingerprint="0" * 16, notes=""))
    store.close()
    row = client.get("/api/models/gone").json()
    assert row["type"] == "unavailable" and row["type_label"].startswith("cannot be built here: ")
    assert "not_installed.module" in row["type_label"]


# -- labels ----------------------------------------------------------------------------------------
def test_an_upload_with_every_label_has_no_warning(client: TestClient, world: Path) -> None:
    labels = upload(client, "full", world_files(world)).json()["labels"]
    assert labels == {"frames": 2, "checked": 2, "labelled": 2, "unit": "frames", "label_files": True,
                      "warning": None}


def test_an_upload_without_label_files_warns_that_ap_needs_them(client: TestClient, world: Path) -> None:
    reply = upload(client, "bare", world_files(world, labels=()))
    assert reply.status_code == 201, reply.text
    labels = reply.json()["labels"]
    assert (labels["labelled"], labels["checked"], labels["frames"]) == (0, 2, 2)
    assert labels["warning"] == ("No frame has labels (0 of 2 frames): AP needs labels and will be shown as — "
                                 "(no labels); the metamorphic relations still run")
    assert client.get("/api/datasets/bare").json()["labels"]["warning"] == labels["warning"]


def test_an_upload_with_some_labels_counts_them(client: TestClient, world: Path) -> None:
    # 000001 has no label file: 1 of 2 frames labelled; without "allow unlabelled" tasks are refused
    strict = upload(client, "half", world_files(world, labels=("000000",))).json()["labels"]
    assert (strict["labelled"], strict["frames"], strict["label_files"]) == (1, 2, True)
    assert strict["warning"].startswith("Only 1 of 2 frames have a label file: AP needs labels, and tasks on this "
                                        "data set are refused")
    allowed = upload(client, "half-ok", world_files(world, labels=("000000",)), allow_unlabelled="true").json()
    assert allowed["labels"]["warning"] == ("Only 1 of 2 frames have labels: AP is scored on the labelled frames; "
                                            "the relations run on all")


def test_a_registered_data_set_without_labels_is_counted_by_the_detail(client: TestClient, tmp_path: Path,
                                                                      world: Path) -> None:
    import shutil

    from lidarfuzz.store import Store
    from lidarfuzz.store.inventory import add_dataset

    scans = tmp_path / "scans"  # a folder of frames: no label files anywhere, so each frame is loaded
    scans.mkdir()
    for stem in ("000000", "000001"):
        shutil.copy(world / "velodyne" / f"{stem}.bin", scans / f"{stem}.bin")
    store = Store(tmp_path / "ws")
    add_dataset(store, "scans", scans)
    store.close()
    labels = client.get("/api/datasets/scans").json()["labels"]
    assert (labels["labelled"], labels["checked"], labels["label_files"]) == (0, 2, False)
    assert labels["warning"].startswith("No frame has labels (0 of 2 frames)")


# -- refusals and errors ---------------------------------------------------------------------------
def test_forgetting_what_a_task_uses_names_the_tasks(client: TestClient) -> None:
    task = client.post("/api/tasks", json={"name": "noise", "dataset": "world", "sut": "classic",
                                           "operators": TURN}).json()
    wait_for(client, task["id"])
    expected_detail = f"is used by 1 task (#{task['id']} noise); delete it first"
    reply = client.delete("/api/datasets/world")
    assert reply.status_code == 409 and reply.json()["detail"] == f"data set 'world' {expected_detail}"
    reply = client.delete("/api/models/classic")
    assert reply.status_code == 409 and reply.json()["detail"] == f"model 'classic' {expected_detail}"
    assert client.get("/api/datasets/world").json()["used_by"] == [{"id": task["id"], "name": "noise"}]
    assert client.get("/api/models/classic").json()["used_by"] == [{"id": task["id"], "name": "noise"}]


def test_refusals_name_at_most_five_tasks_and_count_the_rest(client: TestClient) -> None:
    ids = [client.post("/api/tasks", json={"name": f"t{i}", "dataset": "world", "sut": "classic",
                                           "operators": TURN}).json()["id"] for i in range(7)]
    for task_id in ids:
        wait_for(client, task_id)
    shown = ", ".join(f"#{task_id} t{i}" for i, task_id in enumerate(ids[:5]))
    assert client.delete("/api/datasets/world").json()["detail"] == \
        f"data set 'world' is used by 7 tasks ({shown} and 2 more); delete them first"


def test_upload_errors_name_the_users_files_not_the_servers(client: TestClient, world: Path, tmp_path: Path) -> None:
    bad = [(name, data + b"Car 0.00 0\n" if name == "000001.txt" and b"Car" in data else data)
           for name, data in world_files(world)]
    reply = upload(client, "broken", bad)
    assert reply.status_code == 422
    detail = reply.json()["detail"]
    lines = (world / "label_2" / "000001.txt").read_text().count("\n")
    assert detail.startswith(f"label_2/000001.txt:{lines + 1}: ")  # the line after the label file's last
    assert str(tmp_path) not in json.dumps(reply.json()) and "uploads" not in detail


def test_a_model_upload_that_is_refused_names_the_users_file(client: TestClient, tmp_path: Path) -> None:
    pytest.importorskip("onnxruntime")
    reply = client.post("/api/models/upload", data={"name": "junk"}, files={"file": ("my-detector.onnx", b"junk")})
    assert reply.status_code == 422
    detail = reply.json()["detail"]
    assert detail.startswith("my-detector.onnx: ONNX Runtime cannot load the model")
    assert str(tmp_path) not in detail and "model.onnx" not in detail and "uploads" not in detail


def test_camera_images_without_steering_labels_are_counted(client: TestClient, tmp_path: Path) -> None:
    pytest.importorskip("cv2")
    import io
    import zipfile

    from tests.web.test_camera import camera_files

    labelled = upload(client, "road", [(p.name, p.read_bytes()) for p in camera_files(tmp_path / "road")])
    assert labelled.status_code == 201, labelled.text
    assert labelled.json()["labels"]["warning"] is None  # the CSV labels all 3 images
    buffer = io.BytesIO()  # KITTI's image_2/ alone, without a steering.csv: 0 of 3 images labelled
    with zipfile.ZipFile(buffer, "w") as archive:
        for path in sorted((tmp_path / "road").glob("*.png")):
            archive.write(path, f"image_2/{path.name}")
    reply = upload(client, "bare-road", [("road.zip", buffer.getvalue())], modality="camera")
    assert reply.status_code == 201, reply.text
    labels = reply.json()["labels"]
    assert (labels["unit"], labels["labelled"], labels["checked"]) == ("images", 0, 3)
    assert labels["warning"] == ("No image has a steering label (0 of 3 images): MSE and DeepTest's relation "
                                 "compare outputs with the labels, so they have nothing to score")


def test_a_zip_of_velodyne_alone_is_read_as_its_frames(client: TestClient, world: Path) -> None:
    import io
    import zipfile

    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as archive:
        for path in sorted((world / "velodyne").iterdir()):
            archive.write(path, f"velodyne/{path.name}")
    reply = upload(client, "scans", [("scans.zip", buffer.getvalue())])
    assert reply.status_code == 201, reply.text
    assert reply.json()["frame_count"] == 2 and reply.json()["labels"]["labelled"] == 0
