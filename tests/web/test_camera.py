"""The web API on camera data: a data set of three images and a CSV of steering angles uploaded as
loose files, a fixed-weight steering network (``tests.web.camera_system:Net``) registered as a
camera model, a camera task run through the API, and the pictures and figures the pages show.

The network's angle grows with the image's brightness; fog whitens the images, so some of them
break DeepTest's Eq. 2, and brightness @3 (+50…60 on every channel) turns every angle by far more
than ε, so Eq. 3 filters it out. The expected values below are derived from the stored outputs by
the paper's formulas, not read from the figures under test.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from fastapi.testclient import TestClient

from lidarfuzz.store import Store
from lidarfuzz.store.inventory import add_model
from lidarfuzz.web import create_app
from tests.web.conftest import BASE, ORIGIN, wait_for

pytest.importorskip("torch")

NET = "tests.web.camera_system:Net"
LABELS = {"000000": 0.1, "000001": -0.2, "000002": 0.05}
HEIGHT, WIDTH = 66, 200


def road_image(angle: float, seed: int) -> np.ndarray:
    """A 66×200 BGR road: sky over asphalt, a white lane line turned by ``angle``, a little noise."""
    image = np.zeros((HEIGHT, WIDTH, 3), np.uint8)
    image[: HEIGHT // 2] = (200, 160, 120)
    image[HEIGHT // 2:] = (90, 90, 90)
    cv2.line(image, (WIDTH // 2, HEIGHT), (int(WIDTH // 2 + 180 * math.sin(angle)), HEIGHT // 2), (255, 255, 255), 2)
    noise = np.random.default_rng(seed).integers(0, 20, image.shape)
    return np.clip(image.astype(np.int64) + noise, 0, 255).astype(np.uint8)


def camera_files(folder: Path) -> list[Path]:
    """Three PNGs and ``steering.csv`` (image, steering) in ``folder``."""
    folder.mkdir(parents=True, exist_ok=True)
    lines = ["image,steering"]
    for index, (frame, angle) in enumerate(LABELS.items()):
        cv2.imwrite(str(folder / f"{frame}.png"), road_image(angle, index))
        lines.append(f"{frame}.png,{angle!r}")
    (folder / "steering.csv").write_text("\n".join(lines) + "\n")
    return sorted(folder.iterdir())


def upload(client: TestClient, name: str, paths: list[Path], **fields: str) -> Any:
    files = [("files", (p.name, p.read_bytes(), "application/octet-stream")) for p in paths]
    return client.post("/api/datasets/upload", data={"name": name, **fields}, files=files)


def decoded(data: bytes) -> np.ndarray:
    """A PNG as OpenCV decodes it (BGR)."""
    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    assert image is not None, "not a PNG"
    return np.asarray(image)


def png_size(data: bytes) -> tuple[int, int]:
    """(width, height) of a PNG."""
    image = decoded(data)
    return int(image.shape[1]), int(image.shape[0])


@pytest.fixture(scope="module")
def camera_task(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[TestClient, int]]:
    """An app with the images uploaded as ``road``, the network registered as ``net`` and a finished
    camera task: fog @3 and @5, brightness @3, a guided search of 4 tests."""
    root = tmp_path_factory.mktemp("web-camera")
    paths = camera_files(root / "files")
    store = Store(root / "ws")
    add_model(store, "net", NET, modality="camera")
    store.close()
    with TestClient(create_app(root / "ws", inline=True), base_url=BASE, headers=ORIGIN) as client:
        reply = upload(client, "road", paths)
        assert reply.status_code == 201, reply.text
        reply = client.post("/api/tasks", json={
            "kind": "camera", "name": "road", "dataset": "road", "sut": "net", "search": {"budget": 4},
            "operators": [{"name": "image_fog", "severities": [3, 5]},
                          {"name": "image_brightness", "severities": [3]}]})
        assert reply.status_code == 201, reply.text
        task_id = reply.json()["id"]
        assert wait_for(client, task_id, timeout=120)["status"] == "done"
        yield client, task_id


def test_uploaded_images_and_csv_are_a_camera_data_set(camera_task: tuple[TestClient, int]) -> None:
    client, _ = camera_task
    row = next(d for d in client.get("/api/datasets").json()["items"] if d["name"] == "road")
    assert row["modality"] == "camera" and row["frame_count"] == 3
    listing = client.get("/api/datasets/road/images", params={"limit": 2, "offset": 1}).json()
    assert listing["total"] == 3
    assert [(i["frame_id"], i["steering"], i["width"], i["height"]) for i in listing["items"]] == [
        ("000001", -0.2, WIDTH, HEIGHT), ("000002", 0.05, WIDTH, HEIGHT)]
    assert client.get("/api/datasets/road/frames").json()["modality"] == "camera"


def test_a_data_set_image_is_a_png_with_its_arrow(camera_task: tuple[TestClient, int]) -> None:
    client, _ = camera_task
    reply = client.get("/api/datasets/road/frames/000001/image.png")
    assert reply.status_code == 200 and reply.headers["content-type"] == "image/png"
    assert "max-age" in reply.headers["cache-control"]
    assert png_size(reply.content) == (WIDTH, HEIGHT)
    # the arrow (green, 40,200,70 RGB) is drawn on the picture, not on the image as read
    picture = decoded(reply.content)[:, :, ::-1].astype(int)
    green = (np.abs(picture - np.array([40, 200, 70])).max(axis=-1) < 30).sum()
    assert green > 20
    # a thumbnail: 100 pixels wide keeps the aspect, 66 × 100 / 200 = 33 rows
    thumbnail = client.get("/api/datasets/road/frames/000001/image.png", params={"width": 100})
    assert png_size(thumbnail.content) == (100, 33)
    missing = client.get("/api/datasets/road/frames/000009/image.png")
    assert missing.status_code == 404 and "no frame '000009'" in missing.json()["detail"]
    # a camera data set has no point clouds: the LFZ1 route says where its pictures are
    lfz = client.get("/api/datasets/road/frames/000001")
    assert lfz.status_code == 422 and "image.png" in lfz.json()["detail"]


def test_camera_task_detail_has_mse_orig_eq3_and_coverage(camera_task: tuple[TestClient, int]) -> None:
    client, task_id = camera_task
    task = client.get(f"/api/tasks/{task_id}").json()
    assert task["modality"] == "camera" and task["kind"] == "camera"
    info = task["camera"]
    assert info["labelled"] == 3 and info["images"] == 3
    rows = {s["label"]: s for s in task["subtasks"]}
    assert set(rows) == {"original", "image_fog@3", "image_fog@5", "image_brightness@3", "guided"}
    mse_orig = info["mse_orig"]
    for label in ("image_fog@3", "image_fog@5", "image_brightness@3"):
        d = rows[label]["deeptest"]
        assert d["mse_orig"] == pytest.approx(mse_orig)
        # Eq. 3: kept when |MSE_t − MSE_orig| ≤ ε; fog is composite, never filtered
        assert d["filtered"] is (label == "image_brightness@3")
        assert d["kept"] is (not d["filtered"] or abs(d["mse"] - mse_orig) <= d["configured_epsilon"])
    assert rows["image_brightness@3"]["deeptest"]["kept"] is False
    guided = rows["guided"]["search"]
    assert set(guided["coverage"]) == set(info["seed_coverage"]) == {"nc", "tknc"}
    assert guided["stats"]["tests"] == 4


def test_camera_finding_has_its_figures_picture_and_neighbours(camera_task: tuple[TestClient, int]) -> None:
    client, task_id = camera_task
    items = client.get(f"/api/tasks/{task_id}/findings").json()["items"]
    assert len(items) >= 2 and {i["relation"] for i in items} == {"deeptest_steering"}
    assert all(i["operator"] == "image_fog" for i in items)  # brightness is filtered out by Eq. 3
    first, second = items[0], items[1]
    detail = client.get(f"/api/findings/{first['id']}").json()
    assert detail["modality"] == "camera" and detail["frames"] is None
    assert detail["previous"] is None and detail["next"] == second["id"]
    assert client.get(f"/api/findings/{second['id']}").json()["previous"] == first["id"]
    s = detail["steering"]
    assert s["label"] == LABELS[first["frame_id"]]
    # Eq. 2: (label − θ_t)² > λ · MSE_orig is what made it a finding
    assert s["squared_error"] == pytest.approx((s["label"] - s["prediction"]) ** 2)
    assert s["threshold"] == pytest.approx(s["lambda"] * s["mse_orig"])
    assert s["squared_error"] > s["threshold"]
    assert s["eq3"] == "not_filtered" and s["difference"] == pytest.approx(s["mse_t"] - s["mse_orig"])
    assert detail["operator_params"]["extinction"] > 0  # fog's concrete params, as replayed
    reply = client.get(detail["picture"])
    assert reply.status_code == 200 and reply.headers["content-type"] == "image/png"
    # two 480-pixel panels and a 4-pixel gap; each 66 × 480 / 200 = 158.4 → 158 rows, under a 26-row title
    assert png_size(reply.content) == (2 * 480 + 4, 158 + 26)
    lfz = client.get(f"/api/findings/{first['id']}/frames")
    assert lfz.status_code == 422 and "pair.png" in lfz.json()["detail"]
    assert client.get("/api/findings/999999/pair.png").status_code == 404


def test_a_lidar_finding_has_no_pair_picture(finished: tuple[TestClient, int]) -> None:
    client, task_id = finished
    finding = client.get(f"/api/tasks/{task_id}/findings").json()["items"][0]
    detail = client.get(f"/api/findings/{finding['id']}").json()
    assert detail["modality"] == "lidar" and detail["frames"].endswith("/frames") and "picture" not in detail
    reply = client.get(f"/api/findings/{finding['id']}/pair.png")
    assert reply.status_code == 422
    assert reply.json()["detail"] == (f"finding {finding['id']} is from a lidar task: it has no images; its frames "
                                      f"are /api/findings/{finding['id']}/frames")
    # and a LiDAR data set has no image.png
    image = client.get("/api/datasets/world/frames/000000/image.png")
    assert image.status_code == 422 and "holds lidar frames" in image.json()["detail"]


def test_camera_registration_and_refusals(client: TestClient, tmp_path: Path) -> None:
    paths = camera_files(tmp_path / "files")
    images = [p for p in paths if p.suffix == ".png"]
    no_csv = upload(client, "nocsv", images)
    assert no_csv.status_code == 422
    assert no_csv.json()["detail"] == "files: images need exactly one CSV of steering angles beside them, got 0"
    bad = upload(client, "bad", paths, modality="radar")
    assert bad.status_code == 422 and bad.json()["detail"].startswith("modality: expected lidar or camera")
    # the same files, named camera explicitly
    assert upload(client, "road", paths, modality="camera").json()["modality"] == "camera"
    # a LiDAR system is not a steering system
    refused = client.post("/api/models", json={"name": "c", "spec": "classic", "modality": "camera"})
    assert refused.status_code == 422 and "classic is a LiDAR system" in refused.json()["detail"]
    models = {m["name"]: m["modality"] for m in client.get("/api/models").json()["items"]}
    assert models == {"classic": "lidar"}
    suts = {s["name"]: s["modality"] for s in client.get("/api/suts").json()["items"]}
    assert suts["dave2"] == "camera" and suts["classic"] == "lidar"
    # a camera task on a LiDAR data set is refused, naming the data set
    reply = client.post("/api/tasks", json={"kind": "camera", "dataset": "world", "sut": "classic"})
    assert reply.status_code in (409, 422) and "world" in reply.json()["detail"]


def test_image_bytes_are_what_the_upload_held(camera_task: tuple[TestClient, int]) -> None:
    """The thumbnail's pixels away from the arrow and the text are the uploaded image's (RGB)."""
    client, _ = camera_task
    reply = client.get("/api/datasets/road/frames/000000/image.png")
    picture = decoded(reply.content)
    original = road_image(LABELS["000000"], 0)  # BGR, as written
    # bottom left: below the text box (2 lines: 18 × 2 + 8 = 44 rows) and left of the arrow (from x = 100)
    assert np.array_equal(picture[44:, :60], original[44:, :60])


def test_generate_a_camera_data_set_size_is_checked(client: TestClient) -> None:
    reply = client.post("/api/datasets/generate", json={"name": "cam", "frames": 1, "camera": "800x600"})
    assert reply.status_code == 422 and reply.json()["detail"][0]["loc"] == ["body", "camera"]


@pytest.mark.slow
def test_generate_a_camera_data_set(client: TestClient) -> None:
    """One simulator frame with camera 2 at 640×480: recorded as a camera data set whose image has
    the simulator's steering label (steering.csv) and the chosen size."""
    reply = client.post("/api/datasets/generate", json={"name": "cam", "frames": 1, "camera": "640x480"})
    assert reply.status_code == 202 and reply.json()["modality"] == "camera"
    deadline = time.monotonic() + 180
    while True:
        row = next(d for d in client.get("/api/datasets").json()["items"] if d["name"] == "cam")
        if row["status"] != "generating":
            break
        assert time.monotonic() < deadline, "the camera data set was not rendered in time"
        time.sleep(0.2)
    assert row["status"] == "ready" and row["modality"] == "camera", row
    item = client.get("/api/datasets/cam/images").json()["items"][0]
    assert (item["width"], item["height"]) == (640, 480)
    label = Path(row["path"], "steering.csv").read_text().splitlines()[1].split(",")[1]
    assert item["steering"] == pytest.approx(float(label))


def test_a_guided_search_finding_has_its_chain_and_figures(camera_task: tuple[TestClient, int]) -> None:
    """A finding of Algorithm 1's search: its figures come from the stored outcome of the test image
    (a search's finding does not copy them into its detail), its params are the chain's steps."""
    client, _ = camera_task
    reply = client.post("/api/tasks", json={"kind": "camera", "dataset": "road", "sut": "net", "search": {"budget": 40},
                                            "operators": [{"name": "image_contrast", "severities": [1]}]})
    task_id = reply.json()["id"]
    assert wait_for(client, task_id, timeout=120)["status"] == "done"
    guided = client.get(f"/api/tasks/{task_id}/findings", params={"operator": "guided"}).json()["items"]
    assert guided, "the search found no image breaking Eq. 2"
    detail = client.get(f"/api/findings/{guided[0]['id']}").json()
    assert detail["chain"] is True
    steps = detail["operator_params"]["steps"]
    assert len(steps) >= 1 and all(step["operator"].startswith("image_") for step in steps)
    s = detail["steering"]
    assert s["label"] == LABELS[guided[0]["frame_id"]]
    assert s["squared_error"] == pytest.approx((s["label"] - s["prediction"]) ** 2)
    assert s["squared_error"] > s["threshold"] == pytest.approx(s["lambda"] * s["mse_orig"])
    assert s["eq3"] == "not_filtered"  # a search's chains are composite: Eq. 3 never filters them
    assert client.get(detail["picture"]).status_code == 200


def test_a_finding_whose_images_are_gone_has_a_one_line_422(camera_task: tuple[TestClient, int]) -> None:
    client, task_id = camera_task
    finding = client.get(f"/api/tasks/{task_id}/findings").json()["items"][0]
    folder = Path(next(d for d in client.get("/api/datasets").json()["items"] if d["name"] == "road")["path"])
    moved = folder.with_name("moved-away")
    folder.rename(moved)
    try:
        reply = client.get(f"/api/findings/{finding['id']}/pair.png")
    finally:
        moved.rename(folder)
    assert reply.status_code == 422
    detail = reply.json()["detail"]
    assert detail.startswith(f"finding {finding['id']}: no picture: ") and "\n" not in detail
    assert client.get(f"/api/findings/{finding['id']}/pair.png").status_code == 200  # back in place
