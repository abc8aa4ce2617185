"""The point-cloud viewer in headless Chromium (as tests/web/test_browser.py runs it): a finding opens
framed on its object and "Reset view" returns there; the colour map stays readable on the dark
background; a box tells its class, score, IoU and partners; the settings are kept from finding to
finding, ← / → move between findings; a geometric operator's mutant is aligned back onto the original;
lidarfuzz's own error is said as such, with the system's detections drawn; a log plays on a timeline
from frames fetched ahead. Screenshots go to ``test-artifacts/web/viewer-*.png``."""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from tests.web.test_browser import BACKGROUND, Server, png_pixels

pytestmark = pytest.mark.browser


from lidarfuzz.sim.dataset import GenerationConfig, generate_dataset  # noqa: E402
from lidarfuzz.store import Store  # noqa: E402
from lidarfuzz.store.contracts import FailureRecord  # noqa: E402
from lidarfuzz.store.inventory import add_dataset, add_model  # noqa: E402
from lidarfuzz.store.models import Finding, FrameResult  # noqa: E402
from lidarfuzz.web.frames import decode  # noqa: E402
from tests.web.conftest import TURN, simulated_world  # noqa: E402

LOG_FRAMES = 5


@pytest.fixture(scope="module")
def viewer_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Server, int, Path]]:
    """A server whose store holds the two-frame world (``world``), a log of five frames driven through
    one scene (``log``), the ROI-cache bug-zoo pipeline (``classic``) and a finished task turning the
    world by 15-45° (findings of a geometric operator); with the task's id and the workspace."""
    root = tmp_path_factory.mktemp("browser-viewer")
    world = simulated_world(tmp_path_factory, 2)
    generate_dataset(root / "log", GenerationConfig(frames=LOG_FRAMES, seed=2, sequence=True), workers=1,
                     overwrite=True)
    store = Store(root / "ws")
    add_dataset(store, "world", world)
    add_dataset(store, "log", root / "log")
    add_model(store, "classic", "classic-bug-roi-cache")
    store.close()
    with Server(root / "ws") as server:
        task = server.api("POST", "/api/tasks", json={"name": "turn", "dataset": "world", "sut": "classic",
                                                       "operators": TURN})
        deadline = time.monotonic() + 120
        while server.api("GET", f"/api/tasks/{task['id']}")["status"] not in ("done", "failed"):
            assert time.monotonic() < deadline, "the task did not finish"
            time.sleep(0.2)
        yield server, task["id"], root / "ws"


def rendered(page: Any, previous: Any = None) -> dict[str, Any]:
    """The viewer's counters once a frame (another than ``previous``'s) is drawn."""
    page.wait_for_function("p => window.__viewer && window.__viewer !== p && window.__viewer.firstRenderMs !== null"
                           " && !window.__viewer.disposed", arg=previous)
    return page.evaluate("() => ({...window.__viewer})")


def finding_ids(server: Server, task_id: int) -> list[int]:
    return [f["id"] for f in server.api("GET", f"/api/tasks/{task_id}/findings", params={"limit": 50})["items"]]


def payload(server: Server, finding_id: int) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    import httpx

    return decode(httpx.get(f"{server.url}/api/findings/{finding_id}/frames", timeout=120).content)


def wcag_contrast(a: np.ndarray, b: np.ndarray) -> float:
    """WCAG 2 contrast of two sRGB colours (0-255), written out from the definition."""
    def luminance(rgb: np.ndarray) -> float:
        c = rgb.astype(np.float64) / 255
        lin = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
        return float(0.2126 * lin[0] + 0.7152 * lin[1] + 0.0722 * lin[2])

    hi, lo = sorted([luminance(a), luminance(b)], reverse=True)
    return (hi + 0.05) / (lo + 0.05)


def highlighted_boxes(header: dict[str, Any]) -> list[tuple[str, str, int, np.ndarray]]:
    """The boxes a finding is about, ``(cloud, kind, index, centre)``, the centre where the aligned
    viewer draws it (the mutant's mapped back by the inverse of the operator's transform)."""
    inverse = np.linalg.inv(np.array(header["transform"]))
    out = []
    for cloud, key, rows in [("original", "missing", "gt"), ("original", "lost", "detections"),
                             ("mutant", "missing", "gt"), ("mutant", "spurious", "detections")]:
        entry = header["boxes"][cloud]
        for i in entry[key]:
            centre = np.array(entry[rows][i][:3], np.float64)
            centre = inverse[:3, :3] @ centre + inverse[:3, 3] if cloud == "mutant" else centre
            out.append((cloud, "gt" if rows == "gt" else "detection", i, centre))
    return out


def box_facts(header: dict[str, Any], cloud: str, kind: str, index: int) -> list[str]:
    """What the pinned facts of a box must say, read from the payload's per-box fields."""
    entry, other = header["boxes"][cloud], "mutant" if cloud == "original" else "original"
    if kind == "gt":
        partner, there = entry["gt_partner"][index], entry["gt_other"][index]
        return [f"Ground truth {index} · {entry['gt_labels'][index]} · {cloud}",
                f"detected by detection {partner}" if partner >= 0 else "not detected",
                f"in the {other}: ground truth {there}" if there >= 0 else f"in the {other}: no such object"]
    partner, there = entry["detection_partner"][index], entry["detection_other"][index]
    return [f"Detection {index} · {entry['labels'][index]} · score {entry['scores'][index]:.2f} · {cloud}",
            f"matches ground truth {partner}" if partner >= 0 else "matches no ground truth",
            f"in the {other}: detection {there}" if there >= 0 else f"in the {other}: no matching detection"]


def test_a_finding_opens_on_its_object_with_box_facts_kept_settings_and_arrow_keys(
        page: Any, viewer_server: tuple[Server, int, Path], artifacts: Path) -> None:
    server, task_id, _ = viewer_server
    ids = finding_ids(server, task_id)
    assert len(ids) >= 2, "the task should have findings to step through"
    header, clouds = payload(server, ids[0])
    page.goto(f"{server.url}/#/findings/{ids[0]}?task={task_id}")
    state = rendered(page)
    # a rotation: the aligned option is offered and on
    assert page.get_by_test_id("viewer-aligned").is_visible() and state["aligned"] is True
    # 1. framed on the object: the camera looks at one of the highlighted boxes' centres
    target = np.array(page.evaluate("window.__viewer.camera().target"))
    framed = [b for b in highlighted_boxes(header) if np.abs(target - b[3]).max() < 1e-3]
    assert framed, f"the camera looks at {target}, none of the finding's boxes"
    canvas = page.get_by_test_id("viewer-canvas")
    canvas.screenshot(path=str(artifacts / "viewer-01-finding-framed.png"))
    box = canvas.bounding_box()
    page.mouse.move(box["x"] + 200, box["y"] + 300)
    page.mouse.down(button="right")
    page.mouse.move(box["x"] + 420, box["y"] + 380, steps=5)
    page.mouse.up(button="right")
    moved = np.array(page.evaluate("window.__viewer.camera().target"))
    assert np.abs(moved - target).max() > 0.5, "the right drag should have panned"
    page.get_by_test_id("viewer-reset").click()
    np.testing.assert_allclose(page.evaluate("window.__viewer.camera().target"), target, atol=1e-6)
    # from above too: centred on the object (z 0: the ground plane)
    page.get_by_test_id("viewer-bev").check()
    page.wait_for_function("window.__viewer.bev === true")
    np.testing.assert_allclose(page.evaluate("window.__viewer.camera().target")[:2], target[:2], atol=1e-6)
    canvas.screenshot(path=str(artifacts / "viewer-01-finding-from-above.png"))
    page.get_by_test_id("viewer-bev").uncheck()
    page.wait_for_function("window.__viewer.bev === false")

    # 2. the colour map's dark end is readable: the colour bar's first and last pixels against the background
    shot = page.get_by_test_id("viewer-colourbar").screenshot(path=str(artifacts / "viewer-02-colourbar.png"))
    bar = png_pixels(shot)
    middle = bar.shape[0] // 2
    for pixel in (bar[middle, 2, :3], bar[middle, -3, :3]):
        assert wcag_contrast(pixel, np.array(BACKGROUND)) >= 2.9, f"colour {pixel} vanishes into the background"

    # 3. a click on the framed box pins its facts, from the payload's per-box fields
    cloud, kind, index, _ = framed[0]
    point = page.evaluate(f"window.__viewer.boxAt('{cloud}', '{kind}', {index})")
    assert page.evaluate(f"window.__viewer.pick({point['x']}, {point['y']})") == {
        "cloud": cloud, "kind": kind, "index": index}
    page.mouse.click(point["x"], point["y"])
    info = page.get_by_test_id("viewer-box-info")
    info.wait_for(state="visible")
    text = info.inner_text()
    for line in box_facts(header, cloud, kind, index):
        assert line in text, f"{line!r} not in the box's facts {text!r}"
    page.screenshot(path=str(artifacts / "viewer-03-box-facts.png"))

    # 5. aligned overlay: the mutant turned back, only real changes drawn apart; then not aligned
    page.get_by_test_id("viewer-layout").select_option("overlay")
    page.wait_for_function("window.__viewer.layout === 'overlay'")
    channels = header["clouds"][0]["channels"]
    change, aligned_change = channels.index("change"), channels.index("aligned_change")
    mutant_count = len(clouds["mutant"])
    # the overlay draws the mutant and the original's points the mutant lacks
    removed_aligned = int(np.sum(clouds["original"][:, aligned_change] == 2))
    removed_exact = int(np.sum(clouds["original"][:, change] == 2))
    assert removed_aligned < 0.01 * len(clouds["original"]) < removed_exact  # a turn moves every point
    page.wait_for_function(f"window.__viewer.pointsDrawn === {mutant_count + removed_aligned}")
    canvas.screenshot(path=str(artifacts / "viewer-04-overlay-aligned.png"))
    page.get_by_test_id("viewer-aligned").uncheck()
    page.wait_for_function(f"window.__viewer.aligned === false && window.__viewer.pointsDrawn === "
                           f"{mutant_count + removed_exact}")
    canvas.screenshot(path=str(artifacts / "viewer-05-overlay-not-aligned.png"))

    # 4. settings kept across findings; → and ← step through them
    page.get_by_test_id("viewer-colour").select_option("intensity")
    page.get_by_test_id("viewer-detections").uncheck()
    page.wait_for_function("window.__viewer.colour === 'intensity'")
    first = page.evaluate_handle("window.__viewer")
    page.keyboard.press("ArrowRight")
    page.wait_for_url(f"**/findings/{ids[1]}?task={task_id}")
    state = rendered(page, first)
    assert state["colour"] == "intensity" and state["layout"] == "overlay" and state["aligned"] is False
    assert page.get_by_test_id("viewer-colour").input_value() == "intensity"
    assert not page.get_by_test_id("viewer-detections").is_checked()
    assert page.get_by_test_id("viewer-layout").input_value() == "overlay"
    second = page.evaluate_handle("window.__viewer")
    page.keyboard.press("ArrowLeft")
    page.wait_for_url(f"**/findings/{ids[0]}?task={task_id}")
    rendered(page, second)
    page.screenshot(path=str(artifacts / "viewer-06-kept-settings.png"))


def test_lidarfuzzs_own_error_is_said_as_such_and_the_detections_drawn(
        page: Any, viewer_server: tuple[Server, int, Path], artifacts: Path) -> None:
    server, task_id, workspace = viewer_server
    finding_id = finding_ids(server, task_id)[-1]
    store = Store(workspace)
    with store.session() as s:
        row = s.get(FrameResult, s.get(Finding, finding_id).frame_result_id)
        detections = len(row.detections.boxes())
        row.failure = FailureRecord(kind="oracle_error", detail="gt_recall",
                                    message="relation gt_recall: IndexError: list index out of range")
    store.close()
    page.goto(f"{server.url}/#/findings/{finding_id}")
    state = rendered(page)
    notice = page.get_by_test_id("viewer-tool-error")
    assert notice.is_visible()
    assert notice.inner_text().startswith("lidarfuzz's relation gt_recall raised: IndexError: list index out of range")
    assert "the system failed here" not in page.get_by_test_id("viewer").inner_text()
    header, _ = payload(server, finding_id)
    assert header["boxes"]["mutant"]["failed"] is False and len(header["boxes"]["mutant"]["detections"]) == detections
    assert state["boxesDrawn"] >= detections > 0
    page.screenshot(path=str(artifacts / "viewer-07-tool-error.png"))


def test_a_log_plays_on_a_timeline_from_frames_fetched_ahead(page: Any, viewer_server: tuple[Server, int, Path],
                                                             artifacts: Path) -> None:
    server, _, _ = viewer_server
    # the world has no order: no timeline
    page.goto(f"{server.url}/#/browse/world/000000")
    rendered(page)
    assert page.get_by_test_id("playback").count() == 0
    listing = server.api("GET", "/api/datasets/log/frames")
    assert listing["order"] == "timestamps" and listing["frame_ids"] == [f"{i:06d}" for i in range(LOG_FRAMES)]
    first = page.evaluate_handle("window.__viewer")
    page.goto(f"{server.url}/#/browse/log/000000")
    rendered(page, first)
    assert page.get_by_test_id("playback").is_visible()
    # move the camera: playback keeps it
    canvas = page.get_by_test_id("viewer-canvas")
    box = canvas.bounding_box()
    page.mouse.move(box["x"] + 300, box["y"] + 300)
    page.mouse.down(button="right")
    page.mouse.move(box["x"] + 500, box["y"] + 360, steps=5)
    page.mouse.up(button="right")
    camera = page.evaluate("window.__viewer.camera()")
    # frames 1-4 are fetched ahead while frame 0 is shown (up to 6 ahead), so playback never waits
    page.wait_for_function(f"window.__playback.readyAhead() === {LOG_FRAMES - 1}")
    page.get_by_test_id("playback-rate").select_option("5")
    page.get_by_test_id("playback-play").click()
    page.wait_for_function(f"window.__playback.at === {LOG_FRAMES - 1} && !window.__playback.playing")
    playback = page.evaluate("({...window.__playback})")
    assert playback["shown"] == LOG_FRAMES  # the first frame, then 4 steps
    assert playback["fromCache"] == LOG_FRAMES - 1 and playback["waited"] == 0
    assert page.url.endswith(f"#/browse/log/{LOG_FRAMES - 1:06d}")
    assert page.get_by_test_id("playback-position").inner_text().startswith(f"frame {LOG_FRAMES} of {LOG_FRAMES}")
    assert page.evaluate("window.__viewer.camera()") == camera
    canvas.screenshot(path=str(artifacts / "viewer-08-log-played.png"))
    # ← steps back; the scrubber jumps
    page.keyboard.press("ArrowLeft")
    page.wait_for_function(f"window.__playback.at === {LOG_FRAMES - 2}")
    assert page.get_by_test_id("browse-frame").input_value() == f"{LOG_FRAMES - 2:06d}"
    page.get_by_test_id("playback-scrubber").evaluate(
        "el => { el.value = '1'; el.dispatchEvent(new Event('input', {bubbles: true})); }")
    page.wait_for_function("window.__playback.at === 1")
    state = page.evaluate("({...window.__viewer})")
    assert state["pointsDrawn"] > 0
    # a data set's frame: no system ran on it, so nothing says it failed
    assert "failed" not in page.get_by_test_id("viewer").inner_text()
    page.screenshot(path=str(artifacts / "viewer-09-log-timeline.png"))
