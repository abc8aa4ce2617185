"""A structural task created in the New task form, in real headless Chromium (the server, browser
and page fixtures of :mod:`tests.web.test_browser`): the user picks the kind, a registered log (a
short simulated VLP-16 drive), the controller — whose two main methods the form proposes as the
code to cover — and the segment size, keeps the default heuristics and strategies, and sees the
coverage tables on the task page; a target that does not exist comes back as an error next to the
targets field. Screenshots go to ``test-artifacts/web/`` as the other browser tests' do."""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.web.test_browser import Server

pytestmark = pytest.mark.browser

PROCESS = "lidarfuzz.suts.controller.avoidance:ObstacleAvoidance.process"
CALCULATE = "lidarfuzz.suts.controller.vfh:VFH.calculate"


@pytest.fixture(scope="module")
def logs_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    """A server whose store has a log (``drive``: 6 frames of a simulated VLP-16 drive, with
    timestamps) and a data set without order (``frames``: independent scenes)."""
    from lidarfuzz.sim.dataset import GenerationConfig, generate_dataset
    from lidarfuzz.store import Store
    from lidarfuzz.store.inventory import add_dataset

    root = tmp_path_factory.mktemp("structural-form")
    generate_dataset(root / "drive", GenerationConfig(frames=6, seed=1, drive=True, sensor="VLP-16"), workers=1)
    generate_dataset(root / "frames", GenerationConfig(frames=1, seed=0, sensor="VLP-16"), workers=1)
    store = Store(root / "ws")
    add_dataset(store, "drive", root / "drive")
    add_dataset(store, "frames", root / "frames")
    store.close()
    with Server(root / "ws") as running:
        yield running


def open_structural_form(page: Any, server: Server) -> None:
    page.goto(server.url + "/#/tasks/new")
    page.get_by_test_id("new-task-form").wait_for()
    page.get_by_test_id("task-kind").select_option("structural")
    page.get_by_test_id("log-drive").wait_for()


def test_a_structural_task_from_the_new_task_form(page: Any, logs_server: Server,
                                                  artifacts: Path) -> None:
    open_structural_form(page, logs_server)
    # the detection fields give way to the structural ones; the form proposes what the user expects
    assert page.get_by_test_id("operators").is_hidden() and page.get_by_test_id("task-model").is_hidden()
    assert page.get_by_test_id("log-drive").is_checked()
    assert page.get_by_test_id("log-frames").count() == 0  # no order: not offered as a log ...
    assert page.get_by_test_id("not-logs").inner_text() == "Not logs: frames"  # ... but said why
    assert page.get_by_test_id("task-sequence-system").input_value() == "controller"
    assert page.get_by_test_id("task-targets").input_value() == f"{PROCESS}\n{CALCULATE}"
    for name in ("greedy_edges", "greedy_nodes", "budget", "decision_change", "random"):
        assert page.get_by_test_id(f"heuristic-{name}").is_checked()
    assert page.get_by_test_id("strategy-HGT").is_checked() and page.get_by_test_id("strategy-AVG").is_checked()
    assert page.get_by_test_id("task-segments").input_value() == "5"
    page.get_by_test_id("task-name").fill("drive coverage")
    page.get_by_test_id("task-segments").fill("3")
    page.screenshot(path=str(artifacts / "23-structural-form.png"), full_page=True)

    page.get_by_test_id("task-submit").click()
    page.wait_for_url(re.compile(r"#/tasks/\d+$"))
    task_id = int(page.url.rsplit("/", 1)[1])
    page.get_by_test_id("task-facts").wait_for()
    page.wait_for_function("document.querySelector('h1 + [data-testid=status]')?.textContent === 'done'",
                           timeout=180_000)
    task = logs_server.api("GET", f"/api/tasks/{task_id}")
    # 6 frames in segments of 3; one field-test log, its base log per heuristic (5) and per heuristic the
    # HGT and AVG logs (10): 1 + 5 × (1 + 2) = 16 units
    assert (task["kind"], task["name"], task["dataset"], task["model"]) == ("structural", "drive coverage",
                                                                            "drive", "controller")
    assert (task["done"], task["total"]) == (16, 16)
    settings = task["search"]
    assert settings["targets"] == [PROCESS, CALCULATE] and settings["segment_size"] == 3
    assert settings["heuristics"] == ["greedy_edges", "greedy_nodes", "budget", "decision_change", "random"]
    assert settings["strategies"] == ["HGT", "AVG"]

    coverage = page.frame_locator("[data-testid=structural-frame]")
    for target in (PROCESS, CALCULATE):
        coverage.get_by_text(f"all-nodes of {target}").first.wait_for()
        coverage.get_by_text(f"all-edges of {target}").first.wait_for()
    coverage.get_by_text("greedy_edges agg HGT").first.wait_for()
    coverage.get_by_text("random agg AVG").first.wait_for()
    page.screenshot(path=str(artifacts / "24-structural-task-from-form.png"), full_page=True)


def test_a_target_that_does_not_exist_is_shown_next_to_the_targets(page: Any, logs_server: Server,
                                                                   artifacts: Path) -> None:
    before = logs_server.api("GET", "/api/tasks")["total"]
    open_structural_form(page, logs_server)
    page.get_by_test_id("task-targets").fill(f"{PROCESS}\nlidarfuzz.suts.controller.avoidance:ObstacleAvoidance.nowhere")
    page.get_by_test_id("task-submit").click()
    error = page.locator("[data-testid=task-targets] + [data-testid=field-error]")
    error.wait_for()
    text = error.inner_text()
    assert text.startswith("coverage.targets: ") and "ObstacleAvoidance.nowhere" in text, text
    assert page.get_by_test_id("task-error").inner_text().startswith("The server refused the task (422)")
    assert page.url.endswith("#/tasks/new")  # still on the form, nothing created
    assert logs_server.api("GET", "/api/tasks")["total"] == before
    page.screenshot(path=str(artifacts / "25-structural-form-target-error.png"), full_page=True)
