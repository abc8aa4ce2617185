"""The findings list, the subtask view and the operator previews in headless Chromium (as
tests/web/test_browser.py runs it): the count of the filter's result and of all, the severity and
kind filters and the sort kept in the URL (and through a reload and the pages), thumbnails loaded
lazily, the same car at several severities as one expandable row, a subtask's AP, failures, tool
errors, times and findings, and a New task form preview with its changed points. Screenshots go
to ``test-artifacts/web/findings-*.png``.

The task turns two frames by ``rotate_z`` at severities 1, 3 and 5 with the classic pipeline's
bug-zoo variant whose ROI does not turn: it loses cars, the same car at 3 and at 5.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any
from urllib.parse import parse_qs, urlsplit

import pytest

from tests.web.test_browser import Server

pytestmark = pytest.mark.browser


from tests.web.conftest import register, simulated_world  # noqa: E402


@pytest.fixture(scope="module")
def turned(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Server, int]]:
    """A server with data set ``world`` (two frames), model ``classic`` and the finished turn task."""
    root = tmp_path_factory.mktemp("browser-findings")
    register(root / "ws", simulated_world(tmp_path_factory, 2))
    with Server(root / "ws") as server:
        task = server.api("POST", "/api/tasks", json={"name": "turn", "dataset": "world", "sut": "classic",
                                                      "operators": [{"name": "rotate_z", "severities": [1, 3, 5]}]})
        deadline = time.monotonic() + 120
        while server.api("GET", f"/api/tasks/{task['id']}")["status"] not in ("done", "failed"):
            assert time.monotonic() < deadline, "the task did not finish"
            time.sleep(0.2)
        yield server, task["id"]


def hash_query(page: Any) -> dict[str, str]:
    """The query of the page's hash route (#/tasks/1/findings?severity=5 → {"severity": "5"})."""
    fragment = urlsplit(page.url).fragment
    return {k: v[0] for k, v in parse_qs(fragment.split("?", 1)[1] if "?" in fragment else "").items()}


def rows(page: Any) -> list[dict[str, str]]:
    return page.evaluate("""() => [...document.querySelectorAll('[data-testid=finding-row]')].map(r => ({
        id: r.dataset.findingId, size: r.dataset.groupSize,
        severities: r.querySelector('[data-testid=severities]').textContent}))""")


def shown(page: Any, url: str) -> None:
    """Open ``url`` and wait for the list to be drawn (a row, or the empty table's line)."""
    page.goto(url)
    page.wait_for_selector("[data-testid=findings-count]")


def test_the_list_counts_groups_and_shows_thumbnails(turned: tuple[Server, int], page: Any, artifacts: Path) -> None:
    server, task_id = turned
    items = server.api("GET", f"/api/tasks/{task_id}/findings")["items"]
    grouped = server.api("GET", f"/api/tasks/{task_id}/findings?group=true")
    shown(page, f"{server.url}/#/tasks/{task_id}/findings")
    count = page.get_by_test_id("findings-count").inner_text()
    # grouped by default: every finding counted, one row per group
    assert count.startswith(f"{len(items)} findings in {grouped['groups']} rows"), count
    assert "at least one common object" in page.get_by_test_id("group-rule").inner_text()
    assert [r["id"] for r in rows(page)] == [str(g["id"]) for g in grouped["items"]]
    # a thumbnail per row, loaded lazily, 160 x 120
    thumbs = page.locator("[data-testid=finding-thumb]")
    assert thumbs.count() == grouped["groups"]
    assert {thumbs.nth(i).get_attribute("loading") for i in range(thumbs.count())} == {"lazy"}
    page.wait_for_function("[...document.querySelectorAll('[data-testid=finding-thumb]')]"
                           ".every(i => i.complete && i.naturalWidth === 160 && i.naturalHeight === 120)")
    # the car lost at two severities is one row; it expands to both findings
    double = next(g for g in grouped["items"] if g["group"]["size"] > 1)
    row = page.locator(f"[data-testid=finding-row][data-finding-id='{double['id']}']")
    assert row.get_by_test_id("severities").inner_text() == ", ".join(map(str, double["group"]["severities"]))
    members = page.locator("[data-testid=group-members]").first
    assert members.is_hidden()
    row.get_by_test_id("group-toggle-row").click()
    members.wait_for(state="visible")
    assert [m.get_attribute("data-finding-id") for m in members.get_by_test_id("group-member").all()] == [
        str(m["id"]) for m in double["group"]["members"]]
    page.screenshot(path=str(artifacts / "findings-grouped.png"), full_page=True)
    row.get_by_test_id("finding-thumb").screenshot(path=str(artifacts / "findings-thumb.png"))
    # ungrouped: one row per finding, the count without rows
    page.get_by_test_id("group-toggle").uncheck()
    page.wait_for_function(f"document.querySelectorAll('[data-testid=finding-row]').length === {len(items)}")
    assert hash_query(page)["group"] == "0"
    assert page.get_by_test_id("findings-count").inner_text() == f"{len(items)} findings"


def test_a_thumbnail_that_cannot_be_drawn_says_so(turned: tuple[Server, int], page: Any) -> None:
    """The server answers 422 when a finding's frame cannot be rebuilt (its data set moved): the row
    says so in a line instead of showing a broken image."""
    server, task_id = turned
    page.route("**/thumb.png*", lambda route: route.fulfill(
        status=422, content_type="application/json", body='{"detail": "finding 1: no picture: gone"}'))
    shown(page, f"{server.url}/#/tasks/{task_id}/findings")
    rows_shown = page.locator("[data-testid=finding-row]").count()
    page.wait_for_function(f"document.querySelectorAll('[data-testid=thumb-missing]').length === {rows_shown}")
    assert page.locator("[data-testid=finding-thumb]").count() == 0
    assert page.get_by_test_id("thumb-missing").first.inner_text() == "no picture: its frame cannot be read"


def test_filters_and_sort_live_in_the_url(turned: tuple[Server, int], page: Any, artifacts: Path) -> None:
    server, task_id = turned
    items = server.api("GET", f"/api/tasks/{task_id}/findings")["items"]
    at5 = [f for f in items if f["severity"] == 5]
    shown(page, f"{server.url}/#/tasks/{task_id}/findings?group=0")
    page.get_by_test_id("filter-severity").select_option("5")
    page.wait_for_function("document.querySelector('[data-testid=filter-severity]')?.value === '5'")
    assert hash_query(page) == {"severity": "5", "group": "0"}
    assert page.get_by_test_id("findings-count").inner_text() == f"{len(at5)} of {len(items)} findings"
    assert {r["severities"] for r in rows(page)} == {"5"}
    page.get_by_test_id("sort").select_option("-magnitude")
    page.wait_for_function("document.querySelector('[data-testid=sort]')?.value === '-magnitude'")
    expected = sorted(at5, key=lambda f: (-(f["magnitude"] or 0.0), f["id"]))  # the largest first, ties by id
    assert [r["id"] for r in rows(page)] == [str(f["id"]) for f in expected]
    assert hash_query(page) == {"severity": "5", "group": "0", "sort": "-magnitude"}
    # a reload keeps them; so does the next page (one row per page here)
    page.reload()
    page.wait_for_selector("[data-testid=finding-row]")
    assert page.get_by_test_id("filter-severity").input_value() == "5"
    assert page.get_by_test_id("sort").input_value() == "-magnitude"
    shown(page, f"{server.url}/#/tasks/{task_id}/findings?severity=5&group=0&sort=-magnitude&limit=1")
    assert page.get_by_test_id("page-range").inner_text() == f"1–1 of {len(at5)}"
    page.get_by_test_id("page-next").click()
    page.wait_for_function("document.querySelector('[data-testid=page-range]')?.textContent.startsWith('2–2')")
    assert hash_query(page) == {"severity": "5", "group": "0", "sort": "-magnitude", "limit": "1", "offset": "1"}
    assert [r["id"] for r in rows(page)] == [str(expected[1]["id"])]
    # the kind filter: no system failure here
    page.get_by_test_id("filter-kind").select_option("violation")
    page.wait_for_function("document.querySelector('[data-testid=filter-kind]')?.value === 'violation'")
    assert hash_query(page)["kind"] == "violation" and "offset" not in hash_query(page)  # a new filter: page 1
    page.screenshot(path=str(artifacts / "findings-filtered.png"), full_page=True)
    words = page.locator("#page").inner_text().split()
    assert "null" not in words and "undefined" not in words  # nothing absent written out


def test_the_subtask_view(turned: tuple[Server, int], page: Any, artifacts: Path) -> None:
    server, task_id = turned
    task = server.api("GET", f"/api/tasks/{task_id}")
    sub = next(s for s in task["subtasks"] if s["label"] == "rotate_z@3")
    mine = server.api("GET", f"/api/tasks/{task_id}/findings?subtask={sub['id']}")
    # from the task page's subtask row, as a user gets there
    page.goto(f"{server.url}/#/tasks/{task_id}")
    page.locator("[data-testid=subtask-row][data-label='rotate_z@3'] [data-testid=subtask-view]").click()
    page.wait_for_selector("[data-testid=findings-count]")
    assert hash_query(page) == {"subtask": str(sub["id"])}
    panel = page.get_by_test_id("subtask-panel")
    assert panel.locator("h2").inner_text() == "Subtask rotate_z@3"
    assert page.get_by_test_id("subtask-failures").inner_text() == str(sub["failures"]) == "0"
    assert page.get_by_test_id("subtask-tool-errors").inner_text() == "none"
    assert page.get_by_test_id("subtask-started").inner_text() not in ("", "—")
    assert page.get_by_test_id("subtask-finished").inner_text() not in ("", "—")
    if sub["ap_moderate"]:  # AP per class and mAP, moderate; an undefined one reads "—"
        car = sub["ap_moderate"]["3d"].get("Car")
        cell = page.locator("[data-testid=subtask-ap] tr[data-metric='3d'] td[data-cls='Car']")
        assert cell.inner_text() == ("—" if car is None else f"{car:.2f}")
    else:
        assert page.get_by_test_id("subtask-ap-note").inner_text().startswith("AP: —")
    if sub["sample_warnings"]:
        assert page.get_by_test_id("subtask-warnings").inner_text().count("⚠") == len(sub["sample_warnings"])
    # its findings only
    assert page.get_by_test_id("findings-count").inner_text().startswith(f"{mine['total']} of {mine['total_all']}")
    assert {r["severities"] for r in rows(page)} <= {"3"}
    page.screenshot(path=str(artifacts / "findings-subtask.png"), full_page=True)
    page.get_by_test_id("all-subtasks").click()
    page.wait_for_function("!document.querySelector('[data-testid=subtask-panel]')")
    assert "subtask" not in hash_query(page)


def test_a_preview_in_the_new_task_form(turned: tuple[Server, int], page: Any, artifacts: Path) -> None:
    server, _ = turned
    page.goto(f"{server.url}/#/tasks/new")
    row = page.locator(".op-row[data-operator='fog']")
    row.locator("summary").click()
    page.wait_for_function("document.querySelector('[data-testid=preview-fog]')?.naturalWidth === 726")
    row.get_by_test_id("preview-fog").screenshot(path=str(artifacts / "findings-preview-fog.png"))
    # the picture as the browser decoded it, at its own size: fog loses far returns, so the left panel
    # (the original, below the 44-pixel header, 360 wide) shows them in the viewer's red (255, 64, 64)
    red = page.evaluate("""() => {
        const img = document.querySelector('[data-testid=preview-fog]');
        const canvas = document.createElement('canvas');
        canvas.width = img.naturalWidth; canvas.height = img.naturalHeight;
        const context = canvas.getContext('2d');
        context.drawImage(img, 0, 0);
        const data = context.getImageData(0, 44, 360, img.naturalHeight - 44).data;
        let count = 0;
        for (let i = 0; i < data.length; i += 4) count += data[i] === 255 && data[i + 1] === 64 && data[i + 2] === 64;
        return count;
    }""")
    assert red > 200, f"no removed points highlighted ({red} red pixels)"


@pytest.fixture(scope="module")
def camera(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Server, int]]:
    """A server with tests/web/test_camera.py's road images and steering net and a finished camera
    task (fog @5)."""
    pytest.importorskip("torch")
    from lidarfuzz.store import Store
    from lidarfuzz.store.inventory import add_model
    from tests.web.test_camera import NET, camera_files

    root = tmp_path_factory.mktemp("browser-findings-camera")
    paths = camera_files(root / "files")
    store = Store(root / "ws")
    add_model(store, "net", NET, modality="camera")
    store.close()
    with Server(root / "ws") as server:
        files = [("files", (p.name, p.read_bytes(), "application/octet-stream")) for p in paths]
        server.api("POST", "/api/datasets/upload", data={"name": "road"}, files=files)
        task = server.api("POST", "/api/tasks", json={"kind": "camera", "dataset": "road", "sut": "net",
                                                      "operators": [{"name": "image_fog", "severities": [5]}]})
        deadline = time.monotonic() + 120
        while server.api("GET", f"/api/tasks/{task['id']}")["status"] not in ("done", "failed"):
            assert time.monotonic() < deadline, "the camera task did not finish"
            time.sleep(0.2)
        yield server, task["id"]


def test_a_camera_subtask_and_its_thumbnails(camera: tuple[Server, int], page: Any, artifacts: Path) -> None:
    server, task_id = camera
    sub = next(s for s in server.api("GET", f"/api/tasks/{task_id}")["subtasks"] if s["label"] == "image_fog@5")
    shown(page, f"{server.url}/#/tasks/{task_id}/findings?subtask={sub['id']}")
    facts = page.get_by_test_id("subtask-deeptest").inner_text()
    d = sub["deeptest"]
    assert f"{d['violated']} of {d['mutants']}" in facts and "not filtered" in facts  # fog is composite
    # the transformed images, 160 wide (the 200 × 66 road images: 53 rows)
    page.wait_for_function("[...document.querySelectorAll('[data-testid=finding-thumb]')]"
                           ".every(i => i.complete && i.naturalWidth === 160 && i.naturalHeight === 53)")
    page.screenshot(path=str(artifacts / "findings-camera-subtask.png"), full_page=True)
