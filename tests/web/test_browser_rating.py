"""The rating page (the thesis's first experiment, Table 6-7) in headless Chromium, as a rater uses it:
name and draw on the start form, pairs rated with the keyboard (1/2/3, s/i/d, ← back, → skip), the page
reloaded halfway (the rater goes on from the first pair not rated), the tally once every pair has a
verdict. Screenshots go to ``test-artifacts/web/rating-*.png``."""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.web.conftest import register
from tests.web.test_browser import Server

pytestmark = pytest.mark.browser

OPERATORS = [{"name": "uniform_noise_addition", "severities": [1]},
             {"name": "uniform_point_deletion", "severities": [3]}]


@pytest.fixture(scope="module")
def rating_server(tmp_path_factory: pytest.TempPathFactory, world: Path) -> Iterator[tuple[Server, int]]:
    """A server with a finished task: originals, UNA@1 and UPD@3 on the two-frame world (4 pairs)."""
    workspace = tmp_path_factory.mktemp("browser-rating") / "ws"
    register(workspace, world)
    with Server(workspace) as server:
        task = server.api("POST", "/api/tasks", json={"name": "rate", "dataset": "world", "sut": "classic",
                                                      "operators": OPERATORS})
        deadline = time.monotonic() + 120
        while server.api("GET", f"/api/tasks/{task['id']}")["status"] not in ("done", "failed", "cancelled"):
            assert time.monotonic() < deadline, "the task did not finish"
            time.sleep(0.2)
        yield server, task["id"]


def _picture_of(tab: Any, index: int) -> str:
    """Wait until pair ``index`` (0-based) is shown and its picture decoded; its pair id."""
    tab.wait_for_function(
        "i => { const img = document.querySelector('[data-testid=pair-picture]');"
        " return img && img.dataset.index === String(i) && img.complete && img.naturalWidth > 0; }", arg=index)
    return str(tab.get_attribute("[data-testid=pair-picture]", "data-pair-id"))


def _progress(tab: Any, text: str) -> None:
    tab.wait_for_function("t => document.querySelector('[data-testid=rating-progress]')?.textContent.includes(t)",
                           arg=text)


def test_rate_with_the_keyboard_reload_and_finish(page: Any, rating_server: tuple[Server, int],
                                                  artifacts: Path) -> None:
    server, task = rating_server
    page.goto(f"{server.url}/#/tasks/{task}/rate")
    page.wait_for_selector("[data-testid=rating-start]")
    assert "same (every object as clearly recognisable)" in page.text_content("[data-testid=rating-protocol]")
    page.fill("[data-testid=rater-name]", "ana")
    page.fill("[data-testid=per-operator]", "2")
    page.screenshot(path=str(artifacts / "rating-start.png"))
    page.click("[data-testid=start-rating]")

    # 2 frames × 2 operators: 4 pairs, none rated; the buttons show their keys
    first = _picture_of(page, 0)
    _progress(page, "0 / 4")
    assert page.text_content("[data-testid=verdict-same]").replace(" ", "") == "Same1/s"
    assert "pair 1 of 4" in page.text_content("[data-testid=pair-position]")
    page.screenshot(path=str(artifacts / "rating-pair.png"), full_page=True)

    page.keyboard.press("1")  # same
    _progress(page, "1 / 4")
    second = _picture_of(page, 1)
    assert second != first
    page.keyboard.press("d")  # different
    _progress(page, "2 / 4")
    _picture_of(page, 2)
    page.keyboard.press("ArrowLeft")  # back: the verdict just given is shown
    _picture_of(page, 1)
    assert "your verdict: different" in page.text_content("[data-testid=pair-position]")
    assert "chosen" in page.get_attribute("[data-testid=verdict-different]", "class")
    page.click("[data-testid=rating-skip]")
    _picture_of(page, 2)

    # a rater who leaves and comes back goes on from the first pair without a verdict
    page.reload()
    _picture_of(page, 2)
    _progress(page, "2 / 4")
    assert "rater: ana" in page.text_content("[data-testid=rater]")
    assert not page.is_visible("[data-testid=tally-table]")  # the tally names operators: closed while rating

    page.keyboard.press("2")  # similar
    _progress(page, "3 / 4")
    _picture_of(page, 3)
    page.keyboard.press("3")  # different
    _progress(page, "4 / 4")
    page.wait_for_selector("[data-testid=rating-complete]")
    page.wait_for_selector("[data-testid=tally-table]")
    # the verdicts given: same, different, similar, different — the total row sums them
    total = page.text_content("[data-testid=tally-total]")
    cells = [c.strip() for c in page.locator("[data-testid=tally-total] td").all_text_contents()]
    assert cells[0] == "all"
    assert cells[1].startswith("1 ") and "25.0%" in cells[1]  # same
    assert cells[2].startswith("1 ") and "25.0%" in cells[2]  # similar
    assert cells[3].startswith("2 ") and "50.0%" in cells[3]  # different
    assert cells[4:8] == ["4", "50.0%", "4", "1"], total
    assert page.locator("[data-testid=tally-row]").count() == 2
    rows = page.locator("[data-testid=tally-row]").all_text_contents()
    assert rows[0].startswith("uniform_noise_addition@1 (UNA)") and rows[1].startswith("uniform_point_deletion@3 (UPD)")
    page.screenshot(path=str(artifacts / "rating-tally.png"), full_page=True)

    # the server kept them: ana's 4 verdicts
    tally = server.api("GET", f"/api/tasks/{task}/ratings/tally")
    assert (tally["total"]["same"], tally["total"]["similar"], tally["total"]["different"]) == (1, 1, 2)
    assert tally["raters"] == ["ana"]


def test_the_report_shows_table_6_7(page: Any, rating_server: tuple[Server, int], artifacts: Path) -> None:
    server, task = rating_server
    for pair in server.api("GET", f"/api/tasks/{task}/ratings/pairs?rater=bo&per_operator=2")["pairs"]:
        server.api("PUT", f"/api/tasks/{task}/ratings/pairs/{pair['id']}", json={"rater": "bo", "verdict": "same"})
    page.goto(f"{server.url}/api/tasks/{task}/report")
    section = page.wait_for_selector("#ratings")
    text = section.text_content()
    assert "Table 6-7" in text and "uniform_point_deletion@3 (UPD)" in text
    raters = server.api("GET", f"/api/tasks/{task}/ratings/tally")["raters"]  # bo, and ana when the test above ran
    assert f"{len(raters)} rater(s) ({', '.join(raters)})" in " ".join(text.split())
    section.screenshot(path=str(artifacts / "rating-report.png"))


def test_the_start_form_chooses_operators_and_says_what_is_wrong(page: Any, rating_server: tuple[Server, int]) -> None:
    server, task = rating_server
    page.goto(f"{server.url}/#/tasks/{task}/rate")
    page.fill("[data-testid=rater-name]", "cy")
    page.fill("[data-testid=per-operator]", "2")
    page.fill("[data-testid=draw-operators]", "UPD")
    page.click("[data-testid=start-rating]")
    _picture_of(page, 0)
    _progress(page, "0 / 2")  # 2 frames of one operator
    assert "operators=UPD" in page.url
    page.goto(f"{server.url}/#/tasks/{task}/rate?rater=cy&operators=fog")
    error = page.wait_for_selector("[data-testid=error]")
    assert error.text_content().startswith("HTTP 422: operators: the task has no operator 'fog'")
