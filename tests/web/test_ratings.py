"""The rating API (the thesis's first experiment, Table 6-7): a task's pairs, blinded, in each rater's
order; verdicts kept per rater; the picture and the tally; ratings.csv and the report's section."""

from __future__ import annotations

import csv
import io
from collections.abc import Iterator
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from tests.web.conftest import finished_task

# two thesis operators to rate and the thesis's RAR (rotate_z), which a draw leaves out
OPERATORS = [{"name": "uniform_noise_addition", "severities": [1]}, {"name": "uniform_point_deletion",
                                                                     "severities": [3]},
             {"name": "rotate_z", "severities": [3]}]


@pytest.fixture(scope="module")
def rated(tmp_path_factory: pytest.TempPathFactory, world: Path) -> Iterator[tuple[TestClient, int]]:
    """A client and a finished task (originals, UNA@1, UPD@3, RAR@3 on the two-frame world)."""
    yield from finished_task(tmp_path_factory.mktemp("web-ratings") / "ws", world,
                             {"name": "rate me", "dataset": "world", "sut": "classic", "operators": OPERATORS})


def test_the_pairs_are_blinded_and_drawn_per_operator(rated: tuple[TestClient, int]) -> None:
    client, task = rated
    reply = client.get(f"/api/tasks/{task}/ratings/pairs", params={"rater": "ana"})
    assert reply.status_code == 200, reply.text
    draw = reply.json()
    # 2 frames (fewer than the thesis's 100) × 2 operators (RAR left out) = 4 pairs
    assert (draw["frames"], draw["operators"], draw["total"], draw["rated"]) == (2, 2, 4, 0)
    assert draw["excluded"] == ["rotate_z@3"]
    assert draw["verdicts"] == ["same", "similar", "different"]
    text = reply.text.lower()
    assert "uniform" not in text and "rotate" not in text.replace("rotate_z@3", "")  # only the exclusion names it
    assert [p["index"] for p in draw["pairs"]] == [0, 1, 2, 3]
    again = client.get(f"/api/tasks/{task}/ratings/pairs", params={"rater": "ana"}).json()
    assert [p["id"] for p in again["pairs"]] == [p["id"] for p in draw["pairs"]]


def _pairs(client: TestClient, task: int) -> dict[str, list[int]]:
    """The draw's pair ids by operator, sorted by frame (the store knows them; the API does not say)."""
    from lidarfuzz.campaign.ratings import draw_pairs

    draw = draw_pairs(client.app.state.web.store, task)  # type: ignore[attr-defined]
    return {name: [p.id for p in draw.pairs if p.operator == name]
            for name in ("uniform_noise_addition", "uniform_point_deletion")}


def _rate(client: TestClient, task: int, pair: int, rater: str, verdict: str) -> dict[str, str]:
    reply = client.put(f"/api/tasks/{task}/ratings/pairs/{pair}", json={"rater": rater, "verdict": verdict})
    assert reply.status_code == 200, reply.text
    return dict(reply.json())


def test_verdicts_are_kept_per_rater_and_replaced(rated: tuple[TestClient, int]) -> None:
    client, task = rated
    first_noise = _pairs(client, task)["uniform_noise_addition"][0]
    first = _rate(client, task, first_noise, "ben", "same")
    again = _rate(client, task, first_noise, "ben", "similar")
    assert again["verdict"] == "similar" and again["first_rated_at"] == first["first_rated_at"]
    mine = client.get(f"/api/tasks/{task}/ratings/pairs", params={"rater": "ben"}).json()
    assert mine["rated"] == 1
    assert [(p["id"], p["verdict"]) for p in mine["pairs"] if p["verdict"]] == [(first_noise, "similar")]
    other = client.get(f"/api/tasks/{task}/ratings/pairs", params={"rater": "cy"}).json()
    assert other["rated"] == 0


def test_bad_input_is_one_line_naming_the_field(rated: tuple[TestClient, int]) -> None:
    client, task = rated
    pair = client.get(f"/api/tasks/{task}/ratings/pairs").json()["pairs"][0]["id"]
    bad = client.put(f"/api/tasks/{task}/ratings/pairs/{pair}", json={"rater": "ana", "verdict": "maybe"})
    assert bad.status_code == 422
    assert bad.json()["detail"] == "verdict: expected one of same, similar, different, got 'maybe'"
    nameless = client.put(f"/api/tasks/{task}/ratings/pairs/{pair}", json={"rater": " ", "verdict": "same"})
    assert nameless.status_code == 422 and nameless.json()["detail"].startswith("rater: a name is needed")
    unknown = client.get(f"/api/tasks/{task}/ratings/pairs", params={"operators": "fog"})
    assert unknown.status_code == 422 and unknown.json()["detail"].startswith("operators: the task has no operator")
    missing = client.put(f"/api/tasks/{task}/ratings/pairs/999999", json={"rater": "ana", "verdict": "same"})
    assert missing.status_code == 404
    assert client.get("/api/tasks/999/ratings/pairs").status_code == 404


def test_the_picture_shows_original_and_mutant(rated: tuple[TestClient, int]) -> None:
    client, task = rated
    pair = client.get(f"/api/tasks/{task}/ratings/pairs").json()["pairs"][0]
    picture = client.get(pair["picture"])
    assert picture.status_code == 200 and picture.headers["content-type"] == "image/png"
    assert picture.content[:8] == b"\x89PNG\r\n\x1a\n"
    # the simulated world has no image_2/: no camera picture, said in one line
    camera = client.get(pair["camera"])
    assert camera.status_code == 404 and "no camera image" in camera.json()["detail"]


def test_the_tally_and_ratings_csv(rated: tuple[TestClient, int]) -> None:
    client, task = rated
    pairs = _pairs(client, task)
    (n1, n2), (d1, d2) = pairs["uniform_noise_addition"], pairs["uniform_point_deletion"]
    verdicts = {"dee": {n1: "same", n2: "same", d1: "different", d2: "similar"},
                "eve": {n1: "same", n2: "similar", d1: "different", d2: "similar"},
                "ben": {n1: "similar"}}  # ben's, as the test above leaves it
    for rater, given in verdicts.items():
        for pair, verdict in given.items():
            _rate(client, task, pair, rater, verdict)
    table = client.get(f"/api/tasks/{task}/ratings/tally").json()
    assert table["raters"] == ["ben", "dee", "eve"]
    noise, deletion = table["rows"]
    # noise: n1 [same 2, similar 1], n2 [same 1, similar 1]: 3 same, 2 similar, 0 different of 5
    assert (noise["label"], noise["alias"]) == ("uniform_noise_addition@1", "UNA")
    assert (noise["same"], noise["similar"], noise["different"], noise["total"], noise["raters"]) == (3, 2, 0, 5, 3)
    assert noise["shares"]["same"] == pytest.approx(0.6) and noise["same_or_similar"] == pytest.approx(1.0)
    # κ by hand: P1 = (4 + 1 - 3) / 6 = 1/3, P2 = (1 + 1 - 2) / 2 = 0, P̄ = 1/6; shares (3/5, 2/5, 0):
    # P̄e = 13/25; κ = (1/6 - 13/25) / (12/25) = -53/72
    assert noise["kappa"] == pytest.approx(-53 / 72)
    # deletion: d1 [different 2], d2 [similar 2]: full agreement, P̄ = 1, P̄e = 1/2, κ = 1
    assert (deletion["similar"], deletion["different"], deletion["total"]) == (2, 2, 4)
    assert deletion["same_or_similar"] == pytest.approx(0.5) and deletion["kappa"] == pytest.approx(1.0)
    # all: P̄ = (1/3 + 0 + 1 + 1) / 4 = 7/12; shares (3/9, 4/9, 2/9): P̄e = 29/81; κ = 73/208
    total = table["total"]
    assert (total["same"], total["similar"], total["different"], total["pairs"]) == (3, 4, 2, 4)
    assert total["kappa"] == pytest.approx(73 / 208)
    exported = client.get(f"/api/tasks/{task}/ratings.csv")
    assert exported.status_code == 200, exported.text
    lines = list(csv.DictReader(io.StringIO(exported.text)))
    assert [(r["label"], r["alias"], r["total"]) for r in lines] == [
        ("uniform_noise_addition@1", "UNA", "5"), ("uniform_point_deletion@3", "UPD", "4"), ("all", "", "9")]
    assert float(lines[0]["same_share"]) == pytest.approx(0.6)
    report = client.get(f"/api/tasks/{task}/report")
    assert report.status_code == 200
    assert "Table 6-7" in report.text and "uniform_noise_addition@1 (UNA)" in report.text


def test_the_raster_marks_each_points_cell_darker_with_height() -> None:
    import numpy as np

    from lidarfuzz.report.ratings import bev_raster

    # the window: x (forward) 70 m down to -10 m over 640 rows, y (left) 40 m to -40 m over 640 columns
    points = np.array([[69.99, 39.99, 1.5],  # row 0, column 0; 1.5 m up: the darkest, 1.0
                       [0.0, 0.0, -2.5],  # the sensor's cell: row 70/0.125 = 560, column 40/0.125 = 320; 0.3
                       [-0.01, -0.01, -0.5],  # row 70.01/0.125 -> 560, column 40.01/0.125 -> 320: that cell;
                       # higher: 0.3 + 0.7 * 2/4 = 0.65 wins
                       [-11.0, 0.0, 0.0],  # behind the window: not drawn
                       [10.0, -39.95, -0.5]])  # row 60/0.125 = 480, column 79.95/0.125 = 639.6 -> 639; 0.65
    raster = bev_raster(points)
    assert raster.shape == (640, 640)
    assert raster[0, 0] == pytest.approx(1.0)
    assert raster[560, 320] == pytest.approx(0.65) and raster[480, 639] == pytest.approx(0.65)
    assert np.count_nonzero(raster) == 3


def test_the_picture_is_blinded_and_draws_every_point() -> None:
    import numpy as np

    from lidarfuzz.report.ratings import CELL, MARGIN, TITLE_H, rating_picture
    from lidarfuzz.scene.points import PointCloud
    from lidarfuzz.scene.scene import Scene

    # 400 points, each in a cell of its own on a 2 m lattice off the 10 m grid lines, 1.5 m up (black);
    # the mutant keeps every other one (a point deletion): its panel shows 200, half as dense
    xs, ys = np.meshgrid(np.arange(20) * 2.0 + 11.0, np.arange(20) * 2.0 - 19.0)
    points = np.column_stack([xs.ravel(), ys.ravel(), np.full(400, 1.5), np.zeros(400)])
    picture = np.asarray(rating_picture(Scene(PointCloud(points)), Scene(PointCloud(points[::2])), "000007"))
    side = round(80 / CELL)
    panels = [picture[TITLE_H:TITLE_H + side, MARGIN + i * (side + MARGIN):MARGIN + i * (side + MARGIN) + side]
              for i in (0, 1)]
    assert [int((panel.max(axis=-1) == 0).sum()) for panel in panels] == [400, 200]
