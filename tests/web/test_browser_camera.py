"""The front end on a camera task, in headless Chromium (as tests/web/test_browser.py runs it): the
task's page shows MSE_orig, Eq. 3's verdicts and the search's coverage instead of AP, a finding shows
its picture and figures instead of the point-cloud viewer, the data set browses as images, and the
New task form offers the camera kind with camera data sets, steering systems and image
transformations only. Screenshots go to ``test-artifacts/web/camera-*.png``."""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.web.test_browser import Server

pytestmark = pytest.mark.browser
pytest.importorskip("torch")


from lidarfuzz.store import Store  # noqa: E402
from lidarfuzz.store.inventory import add_model  # noqa: E402
from tests.web.test_camera import LABELS, NET, camera_files  # noqa: E402


@pytest.fixture(scope="module")
def camera_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Server, int]]:
    """A server with the images uploaded (``road``), the steering net registered (``net``), a LiDAR
    model beside it (``classic``, which the camera form must not offer) and a finished camera task."""
    root = tmp_path_factory.mktemp("browser-camera")
    paths = camera_files(root / "files")
    store = Store(root / "ws")
    add_model(store, "net", NET, modality="camera")
    add_model(store, "classic", "classic")
    store.close()
    with Server(root / "ws") as server:
        files = [("files", (p.name, p.read_bytes(), "application/octet-stream")) for p in paths]
        server.api("POST", "/api/datasets/upload", data={"name": "road"}, files=files)
        task = server.api("POST", "/api/tasks", json={
            "kind": "camera", "dataset": "road", "sut": "net", "search": {"budget": 4},
            "operators": [{"name": "image_fog", "severities": [3, 5]},
                          {"name": "image_brightness", "severities": [3]}]})
        deadline = time.monotonic() + 120
        while server.api("GET", f"/api/tasks/{task['id']}")["status"] not in ("done", "failed"):
            assert time.monotonic() < deadline, "the camera task did not finish"
            time.sleep(0.2)
        yield server, task["id"]


def loaded(page: Any, selector: str) -> None:
    """Wait until every image matching ``selector`` has decoded (a positive natural width)."""
    page.wait_for_function("s => [...document.querySelectorAll(s)].length > 0 && "
                           "[...document.querySelectorAll(s)].every(i => i.complete && i.naturalWidth > 0)",
                           arg=selector)


def test_camera_task_finding_and_browse_pages(page: Any, camera_server: tuple[Server, int], artifacts: Path) -> None:
    server, task_id = camera_server
    # the task: MSE_orig, Eq. 3 per transformation, the coverage table; no AP chart
    page.goto(f"{server.url}/#/tasks/{task_id}")
    page.get_by_test_id("mse-orig").wait_for()
    assert page.get_by_test_id("mse-orig").inner_text().startswith("MSE_orig = ")
    assert "3 labelled of 3 original images" in page.get_by_test_id("mse-orig").inner_text()
    assert page.get_by_test_id("ap-chart-box").count() == 0
    verdict = "[data-testid=eq3-verdict]"
    rows = [row for row in page.locator("[data-testid=subtask-row]").all() if row.locator(verdict).count()]
    verdicts = {row.get_attribute("data-label"): row.locator(verdict).inner_text() for row in rows}
    assert verdicts["image_brightness@3"].startswith("filtered out at ε = 0.03")
    assert verdicts["image_fog@3"] == verdicts["image_fog@5"] == "not filtered (a composite transformation)"
    coverage = page.get_by_test_id("search-coverage").inner_text()
    assert "NC" in coverage and "TKNC" in coverage
    headers = page.locator("[data-testid=subtasks-table] th").all_inner_texts()
    assert "Eq. 3" in headers and "AP 3D" not in headers
    page.screenshot(path=str(artifacts / "camera-task.png"), full_page=True)

    # a finding: its picture and figures, no viewer canvas; next/previous move between findings
    page.get_by_test_id("findings-link").click()
    page.get_by_test_id("open-finding").first.click()
    loaded(page, "[data-testid=finding-picture]")
    figures = page.get_by_test_id("steering-figures").inner_text()
    assert "violated: the squared error exceeds λ · MSE_orig" in figures
    assert "not filtered (a composite transformation)" in figures and "extinction" in figures
    assert page.get_by_test_id("viewer-canvas").count() == 0
    width = page.evaluate("() => document.querySelector('[data-testid=finding-picture]').naturalWidth")
    assert width == 2 * 480 + 4
    page.screenshot(path=str(artifacts / "camera-finding.png"), full_page=True)
    first = page.url
    page.get_by_test_id("finding-next").click()
    page.wait_for_function("u => window.location.href !== u", arg=first)
    loaded(page, "[data-testid=finding-picture]")
    page.get_by_test_id("finding-prev").click()
    page.wait_for_function("u => window.location.href === u", arg=first)

    # the data set: a grid of thumbnails with their labels, then one image
    page.goto(f"{server.url}/#/browse/road")
    loaded(page, "[data-testid=thumb-image]")
    labels = page.locator("[data-testid=thumb-steering]").all_inner_texts()
    assert labels == [f"{v:+.4f}" for v in LABELS.values()]
    page.screenshot(path=str(artifacts / "camera-browse.png"), full_page=True)
    page.locator("[data-testid=frame-link]").nth(1).click()
    loaded(page, "[data-testid=frame-image]")
    assert "steering label -0.2000" in page.get_by_test_id("frame-facts").inner_text()
    page.screenshot(path=str(artifacts / "camera-frame.png"), full_page=True)


def test_new_task_form_offers_the_camera_kind(page: Any, camera_server: tuple[Server, int], artifacts: Path) -> None:
    server, _ = camera_server
    # the lists say which data sets and models are the camera's
    page.goto(f"{server.url}/#/datasets")
    page.locator("[data-testid=dataset-row][data-name=road] [data-testid=dataset-modality]").wait_for()
    page.screenshot(path=str(artifacts / "camera-datasets.png"), full_page=True)
    page.goto(f"{server.url}/#/models")
    page.locator("[data-testid=model-row][data-name=net] [data-testid=model-modality-badge]").wait_for()
    assert page.locator("[data-testid=model-row][data-name=classic] [data-testid=model-modality-badge]").count() == 0
    page.screenshot(path=str(artifacts / "camera-models.png"), full_page=True)
    page.goto(f"{server.url}/#/tasks/new")
    page.get_by_test_id("task-kind").select_option("camera")
    assert page.locator("[data-testid=task-dataset] option").all_inner_texts() == ["road (3 frames)"]
    assert [t.split(" — ")[0] for t in page.locator("[data-testid=task-model] option").all_inner_texts()] == ["net"]
    assert page.get_by_test_id("op-image_fog").is_visible() and not page.get_by_test_id("op-global_flip").is_visible()
    page.get_by_test_id("op-image_rain").check()
    page.get_by_test_id("task-budget").fill("2")
    page.screenshot(path=str(artifacts / "camera-new-task.png"), full_page=True)
    page.get_by_test_id("task-submit").click()
    page.wait_for_function("() => /#\\/tasks\\/\\d+$/.test(window.location.hash)")
    task_id = int(page.url.rsplit("/", 1)[1])
    task = server.api("GET", f"/api/tasks/{task_id}")
    assert task["kind"] == "camera" and task["search"]["budget"] == 2
    assert [o["name"] for o in task["operators"]] == ["image_rain"]
