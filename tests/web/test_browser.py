"""End-to-end tests of the web front end in real headless Chromium (Debian's ``chromium``, driven by
Playwright with its executable path set; WebGL through SwiftShader).

A real server (``create_app`` under uvicorn, in a thread) runs on a free port over a temporary
workspace. The journey test does what a user does: upload a data set (a zip of a small simulated
world), register the classic pipeline, create a task in the New task dialog, watch it finish,
open the report and its exports, filter the findings and open one in the 3D viewer. Screenshots
of every step go to ``test-artifacts/web/`` (or ``$LIDARFUZZ_TEST_ARTIFACTS``). A test fails if
the viewer draws nothing: its own counters (``window.__viewer``) must be positive *and* the
canvas, read back from a PNG screenshot, must hold enough non-background pixels.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import socket
import struct
import threading
import time
import zipfile
import zlib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from tests.requirements import missing

pytestmark = pytest.mark.browser

CHROMIUM = Path(os.environ.get("LIDARFUZZ_CHROMIUM", "/usr/bin/chromium"))
if not CHROMIUM.exists():
    missing(f"{CHROMIUM} not found", "the Debian package chromium (.ci/run installs it)", module=True)
try:
    from playwright import sync_api  # noqa: F401 (the browser fixture in conftest.py takes it from here)
except ImportError:
    missing("Playwright not importable", "the Python package playwright (pip install -e '.[test]')", module=True)
uvicorn = pytest.importorskip("uvicorn")

from lidarfuzz.web.app import create_app  # noqa: E402
from tests.web.conftest import simulated_world  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
BACKGROUND = (16, 18, 23)  # the viewer's clear colour, 0x101217
CHROMIUM_ARGS = ["--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist"]
TIMEOUT_MS = 60_000


# -- the PNG reader (zlib only): what a screenshot shows -----------------------------------------
def _paeth(a: int, b: int, c: int) -> int:
    p = a + b - c
    pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
    return a if pa <= pb and pa <= pc else b if pb <= pc else c


def png_pixels(data: bytes) -> np.ndarray:
    """An 8-bit RGB or RGBA PNG (as Chromium's screenshots are) as an H×W×C uint8 array."""
    assert data[:8] == b"\x89PNG\r\n\x1a\n", "not a PNG"
    pos, idat, header = 8, [], None
    while pos < len(data):
        (length,) = struct.unpack(">I", data[pos:pos + 4])
        kind, body = data[pos + 4:pos + 8], data[pos + 8:pos + 8 + length]
        if kind == b"IHDR":
            header = struct.unpack(">IIBBBBB", body)
        elif kind == b"IDAT":
            idat.append(body)
        pos += 12 + length
    assert header is not None
    width, height, depth, colour, _, _, interlace = header
    assert depth == 8 and colour in (2, 6) and interlace == 0, f"unexpected PNG layout {header}"
    bpp = 3 if colour == 2 else 4
    raw = np.frombuffer(zlib.decompress(b"".join(idat)), np.uint8).reshape(height, 1 + width * bpp)
    out = np.zeros((height, width * bpp), np.uint8)
    prior = np.zeros(width * bpp, np.int64)
    for y in range(height):
        kind, line = raw[y, 0], raw[y, 1:].astype(np.int64)
        if kind == 0:
            row = line
        elif kind == 1:  # Sub: a running sum per channel
            row = np.cumsum(line.reshape(width, bpp), axis=0).reshape(-1) % 256
        elif kind == 2:  # Up
            row = (line + prior) % 256
        else:  # Average, Paeth: byte by byte
            row = line.copy()
            for i in range(width * bpp):
                left = int(row[i - bpp]) if i >= bpp else 0
                up = int(prior[i])
                if kind == 3:
                    row[i] = (row[i] + (left + up) // 2) % 256
                else:
                    upleft = int(prior[i - bpp]) if i >= bpp else 0
                    row[i] = (row[i] + _paeth(left, up, upleft)) % 256
        out[y] = row
        prior = row
    return out.reshape(height, width, bpp)


def drawn_fraction(png: bytes) -> float:
    """The share of pixels that differ clearly from the viewer's background."""
    pixels = png_pixels(png)[..., :3].astype(np.int16)
    differs = np.abs(pixels - np.array(BACKGROUND, np.int16)).max(axis=-1) > 24
    return float(differs.mean())


def test_png_reader_reads_what_zlib_wrote() -> None:
    """The reader itself, on a hand-made RGB PNG using the Sub, Up and Paeth filters."""
    rows = [bytes([1, 1, 2, 3, 1, 1, 1]), bytes([2, 5, 5, 5, 0, 0, 0]), bytes([4, 1, 1, 1, 1, 1, 1])]

    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    png = (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", 2, 3, 8, 2, 0, 0, 0))
           + chunk(b"IDAT", zlib.compress(b"".join(rows))) + chunk(b"IEND", b""))
    pixels = png_pixels(png)
    assert pixels[0].tolist() == [[1, 2, 3], [2, 3, 4]]  # Sub: the second pixel adds the first
    assert pixels[1].tolist() == [[6, 7, 8], [2, 3, 4]]  # Up: adds the row above
    # Paeth: first pixel predicts from above (6,7,8); the second from left/up/up-left → above (2,3,4)
    assert pixels[2].tolist() == [[7, 8, 9], [3, 4, 5]]


# -- fixtures ------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def world(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Three simulated HDL-64E frames in KITTI layout (the campaign tests' world)."""
    return simulated_world(tmp_path_factory, 3)


def zip_folder(folder: Path, target: Path) -> Path:
    with zipfile.ZipFile(target, "w", zipfile.ZIP_STORED) as archive:
        for path in sorted(folder.rglob("*")):
            if path.is_file():
                archive.write(path, path.relative_to(folder).as_posix())
    return target


@pytest.fixture(scope="module")
def world_zip(world: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    return zip_folder(world, tmp_path_factory.mktemp("zips") / "world.zip")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class Server:
    """``create_app`` under uvicorn in a thread, as ``lidarfuzz serve`` runs it."""

    def __init__(self, workspace: Path, token: str | None = None) -> None:
        self.port = _free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.token = token
        app = create_app(workspace, token=token, workers=1, inline=True)
        self.server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=self.port, log_level="warning"))
        self.thread = threading.Thread(target=self.server.run, daemon=True)

    def __enter__(self) -> Server:
        self.thread.start()
        deadline = time.monotonic() + 30
        while not self.server.started:
            assert self.thread.is_alive() and time.monotonic() < deadline, "the server did not start"
            time.sleep(0.05)
        return self

    def __exit__(self, *exc: object) -> None:
        self.server.should_exit = True
        self.thread.join(timeout=30)

    def api(self, method: str, path: str, **kwargs: Any) -> Any:
        import httpx

        # a tokenless server takes writes only with its own Origin, as from its page
        headers = {"Authorization": f"Bearer {self.token}"} if self.token else {"Origin": self.url}
        response = httpx.request(method, self.url + path, headers=headers, timeout=120, **kwargs)
        response.raise_for_status()
        return response.json() if response.content else None


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    with Server(tmp_path_factory.mktemp("workspace")) as running:
        yield running


@pytest.fixture(scope="module")
def api_world(server: Server, world_zip: Path) -> str:
    """The world, uploaded through the API (for the tests that are not about uploading), and the
    classic pipeline registered."""
    names = {d["name"] for d in server.api("GET", "/api/datasets")["items"]}
    if "api-world" not in names:
        with world_zip.open("rb") as handle:
            server.api("POST", "/api/datasets/upload", data={"name": "api-world"},
                       files={"files": ("world.zip", handle, "application/zip")})
    if "api-classic" not in {m["name"] for m in server.api("GET", "/api/models")["items"]}:
        server.api("POST", "/api/models", json={"name": "api-classic", "spec": "classic"})
    return "api-world"


# -- helpers -------------------------------------------------------------------------------------
def shown_viewer(page: Any) -> Any:
    """A handle on the viewer now shown (its ``window.__viewer``; ``null`` when none), to pass to
    :func:`wait_for_render` after moving to another frame."""
    return page.evaluate_handle("() => window.__viewer ?? null")


def wait_for_render(page: Any, replacing: Any = None) -> dict[str, Any]:
    """The viewer's counters once it has drawn its frame (its first render with the frame sets
    ``firstRenderMs`` and, in the same call, what was drawn).

    ``replacing``: the :func:`shown_viewer` of the page before a move to another frame. The old
    viewer's counters stay in ``window.__viewer`` until the new page replaces them, after its API
    calls: waiting for a different object is what keeps them from being read as the new frame's.
    """
    page.wait_for_function("previous => window.__viewer && window.__viewer !== previous"
                           " && window.__viewer.firstRenderMs !== null && !window.__viewer.disposed", arg=replacing)
    return page.evaluate("() => ({...window.__viewer})")


def canvas_check(page: Any, path: Path, *, halves: bool = False) -> float:
    """Screenshot the viewer's canvas and check that it shows something (in both halves when side by side)."""
    png = page.locator("[data-testid=viewer-canvas]").screenshot(path=str(path))
    fraction = drawn_fraction(png)
    assert fraction > 0.02, f"the viewer drew almost nothing: {fraction:.2%} of its pixels ({path})"
    if halves:
        pixels = png_pixels(png)[..., :3].astype(np.int16)
        differs = np.abs(pixels - np.array(BACKGROUND, np.int16)).max(axis=-1) > 24
        middle = differs.shape[1] // 2
        left, right = differs[:, : middle - 4].mean(), differs[:, middle + 4:].mean()
        assert left > 0.02 and right > 0.02, f"one half is empty: left {left:.2%}, right {right:.2%} ({path})"
    return fraction


# -- the journey ---------------------------------------------------------------------------------
def test_journey_upload_register_run_report_and_view_a_finding(page: Any, server: Server, world_zip: Path,
                                                               artifacts: Path) -> None:
    page.goto(server.url + "/")
    page.get_by_test_id("tasks-table").wait_for()

    # 1. upload the data set
    page.get_by_test_id("nav-datasets").click()
    page.get_by_test_id("upload-name").fill("world")
    page.get_by_test_id("upload-files").set_input_files(str(world_zip))
    page.get_by_test_id("upload-submit").click()
    row = page.locator("[data-testid=dataset-row][data-name=world]")
    row.wait_for()
    assert row.locator("td").nth(2).inner_text() == "3"
    page.screenshot(path=str(artifacts / "01-datasets.png"), full_page=True)

    # 2. register a bug-zoo variant of the classic pipeline (its ROI does not turn with the scene: the
    # correct pipeline raises no finding on these harmless mutants)
    page.get_by_test_id("nav-models").click()
    page.get_by_test_id("model-name").fill("classic")
    page.get_by_test_id("model-spec").fill("classic-bug-roi-cache")
    page.get_by_test_id("model-submit").click()
    page.locator("[data-testid=model-row][data-name=classic]").wait_for()
    page.screenshot(path=str(artifacts / "02-models.png"), full_page=True)

    # 3. a task: rotate_z and fov_loss at severity 5 (the turn makes the variant lose cars off the old road)
    page.get_by_test_id("nav-tasks").click()
    page.get_by_test_id("new-task").click()
    page.get_by_test_id("new-task-form").wait_for()
    page.get_by_test_id("task-name").fill("browser test")
    page.get_by_test_id("task-dataset").select_option("world")
    page.get_by_test_id("task-model").select_option("classic")
    for operator in ("rotate_z", "fov_loss"):
        page.get_by_test_id(f"op-{operator}").check()
        for severity in (1, 3):
            page.get_by_test_id(f"op-{operator}-sev-{severity}").uncheck()
    # the operator's description, severity table and before/after preview
    page.locator(".op-row[data-operator=fov_loss] details summary").click()
    page.wait_for_function("document.querySelector('[data-testid=preview-fov_loss]')?.naturalWidth > 0")
    page.locator(".op-row[data-operator=fov_loss]").screenshot(path=str(artifacts / "03-new-task-operator.png"))
    page.get_by_test_id("task-submit").click()
    page.wait_for_url(re.compile(r"#/tasks/\d+$"))
    task_id = int(page.url.rsplit("/", 1)[1])

    # 4. watch it finish (live: the page is not reloaded)
    page.get_by_test_id("task-facts").wait_for()
    page.screenshot(path=str(artifacts / "04-task-running.png"), full_page=True)
    page.wait_for_function("document.querySelector('h1 + [data-testid=status]')?.textContent === 'done'",
                           timeout=180_000)
    page.wait_for_function("document.querySelectorAll('[data-testid=subtask-row][data-status=done]').length === 3")
    assert page.get_by_test_id("overall-progress").inner_text().replace(" ", "") == "9/9"
    chart = page.get_by_test_id("ap-chart")
    chart.wait_for()
    assert int(chart.get_attribute("data-points") or 0) > 0
    page.screenshot(path=str(artifacts / "05-task-done.png"), full_page=True)

    # 5. the report, embedded, and its exports
    page.get_by_test_id("report-link").click()
    report = page.frame_locator("[data-testid=report-frame]")
    report.get_by_text("AP per subtask").first.wait_for()
    page.screenshot(path=str(artifacts / "06-report.png"))
    with page.expect_download() as download:
        page.get_by_test_id("export-report-json").click()
    assert download.value.suggested_filename == f"task-{task_id}-report.json"
    exported = json.loads(Path(download.value.path()).read_text())
    assert exported["task"]["id"] == task_id
    with page.expect_download() as download:
        page.get_by_test_id("export-junit-xml").click()
    assert Path(download.value.path()).read_text().lstrip().startswith("<?xml")

    # 6. the findings, filtered
    page.get_by_test_id("nav-tasks").click()
    task_row = page.locator(f"[data-testid=task-row][data-task-id='{task_id}']")
    task_row.wait_for()
    cells = task_row.locator("td").all_inner_texts()
    assert cells[1:6] == [f"#{task_id}", "browser test", "done", "world", "classic"], cells  # after the tick box
    assert task_row.get_by_test_id("task-progress").inner_text().replace(" ", "") == "9/9"
    page.screenshot(path=str(artifacts / "07-tasks.png"), full_page=True)
    task_row.get_by_test_id("task-detail-link").click()
    page.get_by_test_id("findings-link").click()
    page.get_by_test_id("finding-row").first.wait_for()
    # filter by the relation of the first finding (the variant breaks equivariance under the turn;
    # which relations a 3-frame world adds beside it is the data's business)
    relation = page.locator("[data-testid=finding-row] td:nth-child(2)").first.inner_text().strip()
    page.get_by_test_id("filter-relation").select_option(relation)
    page.wait_for_url(f"**relation={relation}**")
    # the filtered page: its select shows the filter, and its rows have come
    page.wait_for_function(f"document.querySelector('[data-testid=filter-relation]')?.value === '{relation}'"
                           " && document.querySelectorAll('[data-testid=finding-row]').length > 0")
    relations = page.locator("[data-testid=finding-row] td:nth-child(2)").all_inner_texts()
    assert relations and set(relations) == {relation}
    page.screenshot(path=str(artifacts / "07-findings.png"), full_page=True)

    # 7. a finding in the viewer: original and mutant side by side, then overlaid, then from above
    page.get_by_test_id("open-finding").first.click()
    state = wait_for_render(page)
    assert state["layout"] == "side"
    assert state["pointsDrawn"] > 10_000 and state["boxesDrawn"] > 0, state
    assert page.get_by_test_id("viewer-legend").get_by_text("missing").count() == 1
    canvas_check(page, artifacts / "08-viewer-side-by-side.png", halves=True)
    page.screenshot(path=str(artifacts / "08-viewer-page.png"))

    page.get_by_test_id("viewer-layout").select_option("overlay")
    page.wait_for_function("window.__viewer.layout === 'overlay'")
    overlay = wait_for_render(page)
    assert 0 < overlay["pointsDrawn"] <= state["pointsDrawn"]  # the mutant plus what it lost
    canvas_check(page, artifacts / "09-viewer-overlay.png")

    page.get_by_test_id("viewer-bev").check()
    page.get_by_test_id("viewer-colour").select_option("intensity")
    page.wait_for_function("window.__viewer.bev === true && window.__viewer.colour === 'intensity'")
    canvas_check(page, artifacts / "10-viewer-birds-eye.png")


def test_upload_problems_are_listed_with_file_and_line(page: Any, server: Server, world: Path,
                                                       tmp_path: Path, artifacts: Path) -> None:
    broken = tmp_path / "broken"
    shutil.copytree(world, broken)
    (broken / "label_2" / "000001.txt").write_text("Car 0.00 0\n")
    archive = zip_folder(broken, tmp_path / "broken.zip")
    page.goto(server.url + "/#/datasets")
    page.get_by_test_id("upload-name").fill("broken")
    page.get_by_test_id("upload-files").set_input_files(str(archive))
    page.get_by_test_id("upload-submit").click()
    error = page.get_by_test_id("upload-error")
    error.wait_for()
    problems = error.get_by_test_id("problems").locator("li").all_inner_texts()
    assert any(p.startswith("label_2/000001.txt:1 ") and "15 fields" in p for p in problems), problems
    page.screenshot(path=str(artifacts / "11-upload-problems.png"), full_page=True)
    assert page.locator("[data-testid=dataset-row][data-name=broken]").count() == 0


def test_new_task_server_errors_are_shown_at_their_field(page: Any, server: Server, api_world: str,
                                                         world_zip: Path, artifacts: Path) -> None:
    with world_zip.open("rb") as handle:
        server.api("POST", "/api/datasets/upload", data={"name": "vanishing"},
                   files={"files": ("world.zip", handle, "application/zip")})
    page.goto(server.url + "/#/tasks/new")
    page.get_by_test_id("task-dataset").select_option("vanishing")
    page.get_by_test_id("op-fog").check()

    # checked in the page first: no operator severity, a bad seed
    page.get_by_test_id("task-seed").fill("-3")
    for severity in (1, 3, 5):
        page.get_by_test_id(f"op-fog-sev-{severity}").uncheck()
    page.get_by_test_id("task-submit").click()
    page.get_by_test_id("field-error").first.wait_for()
    errors = page.get_by_test_id("field-error").all_inner_texts()
    assert any("seed" in e for e in errors) and any("severity" in e for e in errors), errors

    # the server's 422: the data set went away after the dialog opened
    page.get_by_test_id("task-seed").fill("0")
    page.get_by_test_id("op-fog-sev-3").check()
    server.api("DELETE", "/api/datasets/vanishing")
    page.get_by_test_id("task-submit").click()
    error = page.locator("label:has([data-testid=task-dataset]) + [data-testid=field-error]")
    error.wait_for()
    assert "no data set named 'vanishing'" in error.inner_text()
    page.screenshot(path=str(artifacts / "12-new-task-errors.png"))


def test_frame_browser_draws_every_point_and_every_colour_mode(page: Any, server: Server, api_world: str,
                                                               world: Path, artifacts: Path) -> None:
    page.goto(server.url + "/#/browse")
    page.get_by_test_id("browse-dataset").select_option(api_world)
    page.get_by_test_id("frame-link").first.click()
    state = wait_for_render(page)
    points = (world / "velodyne" / "000000.bin").stat().st_size // 16
    labels = [line.split()[0] for line in (world / "label_2" / "000000.txt").read_text().splitlines()]
    assert state["pointsDrawn"] == points
    assert state["boxesDrawn"] == sum(label != "DontCare" for label in labels)
    canvas_check(page, artifacts / "13-frame.png")
    options = page.get_by_test_id("viewer-colour").locator("option").evaluate_all("os => os.map(o => o.value)")
    assert {"height", "intensity", "ring", "label"} <= set(options)
    for mode in ("intensity", "ring", "label"):
        page.get_by_test_id("viewer-colour").select_option(mode)
        page.wait_for_function(f"window.__viewer.colour === '{mode}'")
        canvas_check(page, artifacts / f"14-frame-{mode}.png")
    renders = page.evaluate("window.__viewer.renders")
    page.get_by_test_id("viewer-point-size").evaluate(
        "el => { el.value = '5'; el.dispatchEvent(new Event('input', {bubbles: true})); }")
    page.wait_for_function(f"window.__viewer.renders > {renders}")
    first = shown_viewer(page)
    page.get_by_test_id("frame-next").click()
    page.wait_for_url("**/000001")
    second = wait_for_render(page, replacing=first)
    assert second["pointsDrawn"] == (world / "velodyne" / "000001.bin").stat().st_size // 16


def test_token_from_the_url_is_kept_and_sent(browser: Any, tmp_path: Path, world_zip: Path) -> None:
    with Server(tmp_path / "workspace", token="s3cret-token") as secured:
        context = browser.new_context()
        page = context.new_page()
        page.set_default_timeout(TIMEOUT_MS)
        page.goto(secured.url + "/")
        page.get_by_test_id("error").wait_for()  # no token: the API says 401
        assert "401" in page.get_by_test_id("error").inner_text()
        with world_zip.open("rb") as handle:
            secured.api("POST", "/api/datasets/upload", data={"name": "w"},
                        files={"files": ("world.zip", handle, "application/zip")})
        page.goto(secured.url + "/?token=s3cret-token#/browse/w/000000")
        state = wait_for_render(page)  # the binary frame came with the token
        assert state["pointsDrawn"] > 0
        assert "token" not in page.url  # taken out of the address bar (and the history)
        assert page.evaluate("sessionStorage.getItem('lidarfuzz.token')") == "s3cret-token"
        page.goto(secured.url + "/#/datasets")
        page.locator("[data-testid=dataset-row][data-name=w]").wait_for()
        context.close()


def test_new_task_with_explicit_parameters_and_chosen_relations(page: Any, server: Server, api_world: str,
                                                                artifacts: Path) -> None:
    page.goto(server.url + "/#/tasks/new")
    page.get_by_test_id("task-dataset").select_option(api_world)
    page.get_by_test_id("task-model").select_option("api-classic")
    page.get_by_test_id("task-frames").fill("2")
    page.get_by_test_id("op-rotate_z").check()
    row = page.locator(".op-row[data-operator=rotate_z]")
    row.locator("input[type=radio][value=config]").check()
    low, high = row.get_by_label("angle_range low"), row.get_by_label("angle_range high")
    low.fill("30")
    high.fill("10")
    page.get_by_test_id("relations-choose").check()
    page.get_by_test_id("relation-equivariance").check()
    page.get_by_test_id("task-submit").click()
    error = row.get_by_test_id("field-error")
    error.wait_for()
    assert "low 30 is above high 10" in error.inner_text()  # checked against the params schema, in the page
    high.fill("40")
    page.get_by_test_id("task-submit").click()
    page.wait_for_url(re.compile(r"#/tasks/\d+$"))
    task = server.api("GET", f"/api/tasks/{int(page.url.rsplit('/', 1)[1])}")
    assert task["operators"][0]["config"]["angle_range"] == [30, 40]
    assert [r if isinstance(r, str) else r["name"] for r in task["relations"]] == ["equivariance"]
    assert task["frames"] == 2
    page.get_by_test_id("subtask-row").nth(1).wait_for()
    page.screenshot(path=str(artifacts / "15-task-explicit-parameters.png"), full_page=True)


def test_stop_and_delete_a_running_task(page: Any, server: Server, api_world: str) -> None:
    operators = [{"name": name, "severities": [1, 2, 3, 4, 5]}
                 for name in ("fog", "rain", "snow", "beam_missing", "gaussian_jitter", "uniform_point_deletion")]
    task_id = server.api("POST", "/api/tasks", json={"dataset": api_world, "sut": "api-classic",
                                                     "operators": operators})["id"]
    page.goto(server.url + f"/#/tasks/{task_id}")
    page.wait_for_function("document.querySelector('h1 + [data-testid=status]')?.textContent === 'running'")
    page.get_by_test_id("running-operator").wait_for()  # the operator running now
    page.get_by_test_id("stop-task").click()
    page.get_by_test_id("confirm-yes").click()  # Stop asks first, in the page
    page.wait_for_function("document.querySelector('h1 + [data-testid=status]')?.textContent === 'cancelled'")
    done = server.api("GET", f"/api/tasks/{task_id}")
    assert done["status"] == "cancelled" and done["done"] < done["total"]
    page.get_by_test_id("delete-task").click()
    page.get_by_test_id("confirm-yes").click()
    page.wait_for_url("**/#/tasks")
    page.get_by_test_id("tasks-table").wait_for()
    assert page.locator(f"[data-testid=task-row][data-task-id='{task_id}']").count() == 0


def test_generate_a_data_set_and_the_offline_api_docs(page: Any, server: Server) -> None:
    page.goto(server.url + "/#/datasets")
    page.get_by_test_id("generate-name").fill("generated")
    page.locator("[data-testid=generate-form] input[name=frames]").fill("1")
    page.get_by_test_id("generate-submit").click()
    page.get_by_test_id("generate-message").get_by_text("Rendering generated").wait_for()
    # listed while it renders, then recorded (the page refreshes itself)
    page.wait_for_function("""() => {
        const row = document.querySelector('[data-testid=dataset-row][data-name=generated]');
        return row && !row.querySelector('[data-testid=dataset-status]') && row.cells[2].textContent === '1';
    }""", timeout=120_000)

    requests: list[str] = []
    page.on("request", lambda request: requests.append(request.url))
    page.goto(server.url + "/docs")
    page.locator(".swagger-ui .info .title").get_by_text("lidarfuzz").wait_for()
    assert all(url.startswith(server.url) or url.startswith("data:") for url in requests), requests


def test_journey_a_structural_task_shows_its_coverage_tables_and_views(page: Any, tmp_path: Path,
                                                                      artifacts: Path) -> None:
    # created through the API (test_browser_structural.py creates one in the New task form), then followed in the app
    from lidarfuzz.store import Store
    from lidarfuzz.store.inventory import add_dataset
    from tests.campaign.test_structural import write_log

    workspace = tmp_path / "ws"
    store = Store(workspace)
    add_dataset(store, "drive", write_log(tmp_path / "drive"))
    store.close()
    with Server(workspace) as server:
        task = server.api("POST", "/api/tasks", json={
            "kind": "structural", "dataset": "drive", "sut": "controller", "segments": 2,
            "coverage": {"targets": ["lidarfuzz.suts.controller.avoidance:ObstacleAvoidance.process"]},
            "heuristics": ["greedy_edges"], "strategies": ["HGT"]})
        page.goto(f"{server.url}/#/tasks/{task['id']}")
        page.wait_for_function("document.querySelector('h1 + [data-testid=status]')?.textContent === 'done'",
                               timeout=120_000)
        coverage = page.frame_locator("[data-testid=structural-frame]")
        coverage.get_by_text("greedy_edges agg HGT").first.wait_for()
        coverage.locator("svg").first.wait_for()  # the control-flow graph of process()
        # the frame's final tables may still replace a running task's: wait for them, not count at once
        from playwright.sync_api import expect
        expect(coverage.locator(".lf-cov-source")).to_have_count(1)
        page.screenshot(path=str(artifacts / "21-structural-task.png"), full_page=True)
        page.get_by_test_id("report-link").click()
        page.frame_locator("[data-testid=report-frame]").get_by_text("Structural testing with logs").first.wait_for()
        page.screenshot(path=str(artifacts / "22-structural-report.png"))
