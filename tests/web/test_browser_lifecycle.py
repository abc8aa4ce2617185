"""The task pages, in headless Chromium (as tests/web/test_browser.py runs it), never misleading:
the system's failures apart from lidarfuzz's own errors, AP "—" with its reason, small-sample
warnings, per-subtask times and view links, the AP chart's three colours; Stop asks in the page,
Resume takes a stopped task up again, a refused action says why until the next one, a lost server
reads "disconnected — retrying", a loading system reads so; the New task form's links, one
severity for global_flip, a share above 1 refused at its input; the report scrolls once.
Screenshots go to ``test-artifacts/web/lifecycle-*.png``."""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.web.test_browser import Server

pytestmark = pytest.mark.browser


from lidarfuzz.store import Store  # noqa: E402
from lidarfuzz.store.inventory import add_dataset, add_model  # noqa: E402
from lidarfuzz.store.models import Subtask  # noqa: E402
from tests.web.conftest import simulated_world  # noqa: E402

#: a system whose every detection takes 0.4 s: a task runs long enough to be stopped; the first unit
#: (the system loading, as the page sees it) too
SLOW = "tests.campaign.systems:SlowClassic?delay=0.4"
#: 2 s a detection: the first unit takes longer than the events' poll, so the page sees it loading
SLOWER = "tests.campaign.systems:SlowClassic?delay=2.0"


@pytest.fixture(scope="module")
def served(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Server, Path]]:
    """A server whose store knows data set ``world`` (3 frames), ``classic`` and the slow system."""
    root = tmp_path_factory.mktemp("browser-lifecycle")
    world = simulated_world(tmp_path_factory, 3)
    store = Store(root / "ws")
    add_dataset(store, "world", world)
    add_model(store, "classic", "classic")
    add_model(store, "slow", SLOW)
    add_model(store, "slower", SLOWER)
    store.close()
    with Server(root / "ws") as server:
        yield server, root / "ws"


def finish(server: Server, task_id: int, states: tuple[str, ...] = ("done", "failed")) -> dict[str, Any]:
    deadline = time.monotonic() + 120
    while True:
        task: dict[str, Any] = server.api("GET", f"/api/tasks/{task_id}")
        if task["status"] in states:
            return task
        assert time.monotonic() < deadline, f"task {task_id} still {task['status']}"
        time.sleep(0.1)


def test_the_task_page_tells_the_systems_failures_from_lidarfuzzs_errors(
        served: tuple[Server, Path], page: Any, artifacts: Path) -> None:
    server, workspace = served
    task_id = server.api("POST", "/api/tasks", json={
        "name": "a-very-long-task-name-" * 6, "dataset": "world", "sut": "classic",
        "operators": [{"name": "rotate_z", "severities": [3]}, {"name": "fog", "severities": [5]}]})["id"]
    finish(server, task_id)
    # what a run with errors leaves (set by hand): rotate_z@3 with 1 failure of the system and 2 oracle
    # errors; fog@5 with 1 operator error and no AP (an operator that moved every object out of view)
    store = Store(workspace)
    with store.session() as s:
        subs = {sub.name: sub for sub in s.query(Subtask).filter(Subtask.task_id == task_id)}
        subs["rotate_z"].results = subs["rotate_z"].results.model_copy(
            update={"failures": 1, "tool_errors": {"oracle_error": 2}})
        subs["fog"].results = subs["fog"].results.model_copy(
            update={"tool_errors": {"operator_error": 1}, "ap": None, "ap_note": "no AP: the operator moved "
                                                                                 "every labelled object out of view"})
    store.close()
    page.goto(f"{server.url}/#/tasks/{task_id}")
    summary = page.get_by_test_id("failures-summary")
    summary.wait_for()
    # by hand: failures 0 + 1 + 0 = 1; lidarfuzz's errors 2 oracle + 1 operator = 3
    assert page.get_by_test_id("system-failures").get_attribute("data-count") == "1"
    assert page.get_by_test_id("tool-errors").get_attribute("data-count") == "3"
    assert "1 operator error, 2 oracle errors" in summary.inner_text()
    rows = page.get_by_test_id("subtask-row")
    assert rows.count() == 3  # the originals, rotate_z@3, fog@5
    turn = page.locator("[data-testid=subtask-row][data-label='rotate_z@3']")
    assert turn.get_by_test_id("subtask-failures").inner_text() == "1"
    assert turn.get_by_test_id("subtask-tool-errors").inner_text() == "2 oracle"
    fog = page.locator("[data-testid=subtask-row][data-label='fog@5']")
    assert fog.get_by_test_id("ap-note").inner_text() == "no AP: the operator moved every labelled object out of view"
    # times: ISO 8601 local, "YYYY-MM-DD HH:MM:SS", started no later than finished
    started, finished = (turn.get_by_test_id(t).inner_text() for t in ("subtask-started", "subtask-finished"))
    assert len(started) == len(finished) == 19 and started[4] == "-" and started[10] == " " and started <= finished
    sub_id = subs["rotate_z"].id
    assert turn.get_by_test_id("subtask-view").get_attribute("href") == f"#/tasks/{task_id}/findings?subtask={sub_id}"
    # the chart: three lines in three colours, named in the legend
    colours = page.eval_on_selector_all("[data-testid=ap-chart] path.series",
                                        "ps => ps.map(p => p.getAttribute('stroke'))")
    assert len(colours) == len(set(colours)) == 3
    legend = [page.get_by_test_id(f"legend-{m}").inner_text() for m in ("bbox", "bev", "3d")]
    assert legend == ["bbox (2D)", "BEV", "3D"]
    # the long name wraps: the heading is no wider than the page
    assert page.evaluate("() => document.documentElement.scrollWidth <= window.innerWidth")
    page.screenshot(path=str(artifacts / "lifecycle-failures.png"), full_page=True)


def test_small_samples_are_flagged_on_the_page(served: tuple[Server, Path], page: Any, artifacts: Path) -> None:
    server, _ = served
    task_id = server.api("POST", "/api/tasks", json={"dataset": "world", "sut": "classic", "frames": 1,
                                                     "operators": [{"name": "rotate_z", "severities": [3]}]})["id"]
    task = finish(server, task_id)
    assert task["summary"]["ap_warnings"], "one frame: the summary warns"  # what the page must show
    page.goto(f"{server.url}/#/tasks/{task_id}")
    box = page.get_by_test_id("ap-warnings")
    box.wait_for()
    assert task["summary"]["ap_warnings"][0] in box.inner_text()
    page.screenshot(path=str(artifacts / "lifecycle-warnings.png"), full_page=True)


def test_stop_asks_resume_goes_on_and_a_refusal_stays(served: tuple[Server, Path], page: Any,
                                                         artifacts: Path) -> None:
    server, _ = served
    task_id = server.api("POST", "/api/tasks", json={
        "dataset": "world", "sut": "slower", "operators": [{"name": "fog", "severities": [1, 2, 3, 4, 5]}]})["id"]
    page.goto(f"{server.url}/#/tasks/{task_id}")
    page.get_by_test_id("loading-system").wait_for()  # running, no unit done yet: the system loads
    page.screenshot(path=str(artifacts / "lifecycle-loading.png"))
    page.wait_for_selector("[data-testid=running-operator]")  # a unit is done: no longer loading
    assert page.get_by_test_id("live").get_attribute("data-state") == "live"
    page.get_by_test_id("stop-task").click()
    page.get_by_test_id("confirm-box").get_by_text("Stop the task").wait_for()
    page.screenshot(path=str(artifacts / "lifecycle-confirm-stop.png"))
    page.get_by_test_id("confirm-no").click()  # asked, declined: still running
    assert server.api("GET", f"/api/tasks/{task_id}")["status"] == "running"
    page.get_by_test_id("stop-task").click()
    page.get_by_test_id("confirm-yes").click()
    page.wait_for_selector("[data-testid=status]:text('cancelled')")
    page.get_by_test_id("resume-task").wait_for()
    # meanwhile someone deletes the task: this page's Resume is refused, and says why
    server.api("DELETE", f"/api/tasks/{task_id}")
    page.get_by_test_id("resume-task").click()
    refusal = page.get_by_test_id("action-error")
    refusal.wait_for()
    assert refusal.inner_text() == f"Resume refused: HTTP 404: no task {task_id}"
    page.screenshot(path=str(artifacts / "lifecycle-refused.png"))
    page.get_by_test_id("delete-task").click()  # the next action clears the old notice
    assert page.get_by_test_id("action-error").count() == 0
    page.get_by_test_id("confirm-no").click()


def test_resume_runs_a_stopped_task_to_the_end(served: tuple[Server, Path], page: Any) -> None:
    server, _ = served
    task_id = server.api("POST", "/api/tasks", json={
        "dataset": "world", "sut": "slow", "operators": [{"name": "fog", "severities": [2, 4]}]})["id"]
    finish(server, task_id, ("running",))
    server.api("POST", f"/api/tasks/{task_id}/stop")
    finish(server, task_id, ("cancelled",))
    page.goto(f"{server.url}/#/tasks/{task_id}")
    page.get_by_test_id("resume-task").click()
    page.get_by_test_id("action-notice").wait_for()
    page.wait_for_selector("[data-testid=status]:text('done')", timeout=120_000)


def test_a_lost_server_reads_disconnected(served: tuple[Server, Path], page: Any, artifacts: Path) -> None:
    server, _ = served
    task_id = server.api("POST", "/api/tasks", json={
        "dataset": "world", "sut": "slow", "operators": [{"name": "fog", "severities": [1, 2, 3, 4, 5]}]})["id"]
    # the live events cannot reach the server (as when it stopped): the page says so, and retries
    page.route(f"**/api/tasks/{task_id}/events*", lambda route: route.abort("connectionrefused"))
    page.goto(f"{server.url}/#/tasks/{task_id}")
    page.wait_for_selector("[data-testid=live][data-state=disconnected]")
    assert page.get_by_test_id("live").inner_text() == "disconnected — retrying"
    page.screenshot(path=str(artifacts / "lifecycle-disconnected.png"))
    page.unroute(f"**/api/tasks/{task_id}/events*")  # the server answers again: live
    page.wait_for_selector("[data-testid=live][data-state=live]")
    server.api("POST", f"/api/tasks/{task_id}/stop")
    finish(server, task_id, ("cancelled",))


def test_the_new_task_form_checks_parameters_at_their_field(served: tuple[Server, Path], page: Any,
                                                            artifacts: Path) -> None:
    server, _ = served
    page.goto(f"{server.url}/#/tasks/new")
    page.get_by_test_id("new-task-form").wait_for()
    assert page.get_by_test_id("upload-dataset-link").get_attribute("href") == "#/datasets"
    assert page.get_by_test_id("upload-model-link").get_attribute("href") == "#/models"
    # global_flip mirrors at every severity: one severity offered
    assert page.locator("[data-testid^=op-global_flip-sev-]").count() == 1
    assert page.locator("[data-testid^=op-fog-sev-]").count() == 5
    # the share's inputs carry the schema's bounds; a share of 1.5 is refused at that input
    row = page.locator(".op-row[data-operator=random_region_point_deletion]")
    page.get_by_test_id("op-random_region_point_deletion").check()
    row.locator("input[value=config]").check()
    field = row.locator("[data-param=share_range]")
    high = field.locator("input").nth(1)
    assert (high.get_attribute("min"), high.get_attribute("max")) == ("0", "1")
    high.fill("1.5")
    page.get_by_test_id("task-submit").click()
    error = row.get_by_test_id("field-error")
    error.wait_for()
    assert "share_range high: must be ≤ 1" in error.inner_text()
    page.screenshot(path=str(artifacts / "lifecycle-form-share.png"))


def test_the_report_scrolls_once(served: tuple[Server, Path], page: Any, artifacts: Path) -> None:
    server, _ = served
    task_id = server.api("POST", "/api/tasks", json={"dataset": "world", "sut": "classic",
                                                     "operators": [{"name": "rotate_z", "severities": [3]}]})["id"]
    finish(server, task_id)
    page.goto(f"{server.url}/#/tasks/{task_id}/report")
    page.wait_for_function("() => !document.querySelector('[data-testid=report-loading]')")
    page.frame_locator("[data-testid=report-frame]").locator("h1").first.wait_for()  # the report drawn
    page.wait_for_function("() => document.documentElement.scrollHeight <= window.innerHeight + 1")
    frame = page.get_by_test_id("report-frame").bounding_box()
    assert frame is not None and frame["height"] >= 240
    page.screenshot(path=str(artifacts / "lifecycle-report.png"))
