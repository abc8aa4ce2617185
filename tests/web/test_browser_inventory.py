"""The data-set and model pages in headless Chromium (as tests/web/test_browser.py runs it): notes in
the upload and registration forms, the lists and the detail pages (edited there); the model type
and modality columns; the warning when uploaded frames lack labels; refusals to delete what a task
uses kept under their row with links to the tasks, gone at the next action; long names wrapping;
and the upload widget on the visualisation page (a folder picked or files dropped), which opens the
new data set right away. Screenshots go to ``test-artifacts/web/inventory-*.png``."""

from __future__ import annotations

import base64
import shutil
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.web.conftest import TURN
from tests.web.test_browser import Server

pytestmark = pytest.mark.browser


from lidarfuzz.store import Store  # noqa: E402
from lidarfuzz.store.inventory import add_dataset, add_model  # noqa: E402

NO_LABELS = ("No frame has labels (0 of 2 frames): AP needs labels and will be shown as — (no labels); the "
             "metamorphic relations still run.")
LONG_NAME = "a-data-set-named-at-length-" + "x" * 73  # 100 characters, the longest name the server takes


@pytest.fixture(scope="module")
def frames(world: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, list[Path]]:
    """The world's files as a user has them: the two scans, their calibrations and label files."""
    root = tmp_path_factory.mktemp("user-files")
    out: dict[str, list[Path]] = {}
    for folder in ("velodyne", "calib", "label_2"):
        (root / folder).mkdir()
        out[folder] = [Path(shutil.copy(p, root / folder / p.name)) for p in sorted((world / folder).iterdir())]
    return out


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory, world: Path) -> Iterator[Server]:
    """A server knowing data set ``world`` and model ``classic``, with one finished task (``noise``)
    using both, and a data set and a model nothing uses."""
    workspace = tmp_path_factory.mktemp("browser-inventory") / "ws"
    store = Store(workspace)
    add_dataset(store, "world", world, notes="two HDL-64E frames, seed 0")
    add_dataset(store, LONG_NAME, world)
    add_model(store, "classic", "classic-bug-roi-cache", notes="ROI does not turn with the scene")
    add_model(store, "spare", "classic")
    store.close()
    with Server(workspace) as running:
        task = running.api("POST", "/api/tasks", json={"name": "noise", "dataset": "world", "sut": "classic",
                                                       "operators": TURN})
        deadline = time.monotonic() + 120
        while running.api("GET", f"/api/tasks/{task['id']}")["status"] not in ("done", "failed"):
            assert time.monotonic() < deadline, "the task did not finish"
            time.sleep(0.1)
        running.task_id = task["id"]  # type: ignore[attr-defined]
        yield running


def no_horizontal_scroll(page: Any) -> None:
    """Long names and notes wrap: the page is no wider than the window."""
    width = page.evaluate("() => [document.documentElement.scrollWidth, window.innerWidth]")
    assert width[0] <= width[1], width


def test_an_upload_without_labels_warns_and_its_notes_are_listed(page: Any, server: Server, artifacts: Path,
                                                                 frames: dict[str, list[Path]]) -> None:
    notes = "Scans from the roof rig, drive 5, no annotations yet. " * 4  # 220 characters: clamped in the list
    page.goto(server.url + "/#/datasets")
    page.get_by_test_id("upload-files").set_input_files([str(p) for p in frames["velodyne"] + frames["calib"]])
    assert page.get_by_test_id("upload-name").input_value() == "000000"  # suggested from the first file
    page.get_by_test_id("upload-name").fill("bare")
    page.get_by_test_id("upload-notes").fill(notes)
    page.get_by_test_id("upload-submit").click()
    warning = page.get_by_test_id("upload-labels-warning")
    warning.wait_for()
    assert warning.inner_text() == NO_LABELS
    assert page.get_by_test_id("upload-labels").inner_text() == "0 of 2 frames have labels."
    row = page.locator("[data-testid=dataset-row][data-name=bare]")
    row.wait_for()
    cell = row.get_by_test_id("notes-cell")
    assert cell.get_attribute("title") == notes.strip()
    # two lines of ~13 px: the clamp keeps the cell far shorter than the 220 characters would need
    assert cell.locator(".clamp").bounding_box()["height"] < 45
    no_horizontal_scroll(page)
    page.screenshot(path=str(artifacts / "inventory-upload-no-labels.png"), full_page=True)


def test_a_partly_labelled_upload_says_how_many_frames_have_labels(page: Any, server: Server,
                                                                   frames: dict[str, list[Path]]) -> None:
    page.goto(server.url + "/#/datasets")
    files = frames["velodyne"] + frames["calib"] + frames["label_2"][:1]  # 000001 has no label file
    page.get_by_test_id("upload-files").set_input_files([str(p) for p in files])
    page.get_by_test_id("upload-name").fill("half")
    page.get_by_test_id("upload-submit").click()
    page.get_by_test_id("upload-labels-warning").wait_for()
    assert page.get_by_test_id("upload-labels").inner_text() == "1 of 2 frames have a label file."
    assert page.get_by_test_id("upload-labels-warning").inner_text() == (
        "Only 1 of 2 frames have labels: AP is scored on the labelled frames; the relations run on all.")


def test_a_fully_labelled_upload_has_no_warning(page: Any, server: Server, frames: dict[str, list[Path]]) -> None:
    page.goto(server.url + "/#/datasets")
    page.get_by_test_id("upload-folder").set_input_files(str(frames["velodyne"][0].parent.parent))
    page.get_by_test_id("upload-name").fill("full")
    page.get_by_test_id("upload-submit").click()
    page.get_by_test_id("upload-ok").wait_for()
    message = page.get_by_test_id("upload-message").inner_text()
    assert message == "Added full (2 frames). 2 of 2 frames have a label file."
    assert page.get_by_test_id("upload-labels-warning").count() == 0


def test_a_data_sets_page_shows_its_labels_tasks_and_edits_its_notes(page: Any, server: Server,
                                                                     artifacts: Path) -> None:
    page.goto(server.url + "/#/datasets")
    page.locator("[data-testid=dataset-row][data-name=world] [data-testid=dataset-link]").click()
    page.get_by_test_id("fact-labels").wait_for()
    assert page.url.endswith("#/datasets/world")
    assert page.get_by_test_id("fact-labels").inner_text() == "2 of 2 frames have a label file."
    assert page.get_by_test_id("labels-warning").count() == 0  # every frame labelled: nothing to warn of
    assert page.get_by_test_id("fact-unlabelled").count() == 0  # nor whether unlabelled frames may run
    assert "null" not in page.locator("body").inner_text() and "undefined" not in page.locator("body").inner_text()
    used = page.get_by_test_id("fact-used-by").get_by_test_id("used-by-task")
    assert used.inner_text() == f"#{server.task_id} noise"  # type: ignore[attr-defined]
    assert used.get_attribute("href") == f"#/tasks/{server.task_id}"  # type: ignore[attr-defined]
    editor = page.get_by_test_id("notes-edit")
    assert editor.input_value() == "two HDL-64E frames, seed 0"
    editor.fill("two HDL-64E frames, seed 0; the fog study's baseline")
    page.get_by_test_id("notes-save").click()
    page.get_by_test_id("notes-saved").wait_for()
    page.screenshot(path=str(artifacts / "inventory-dataset-detail.png"), full_page=True)
    # too long (the textarea's maxlength is bypassed by a script): the server's refusal names the field
    page.evaluate("() => { document.querySelector('[data-testid=notes-edit]').value = 'x'.repeat(10001); }")
    page.get_by_test_id("notes-save").click()
    error = page.get_by_test_id("notes-error")
    error.wait_for()
    assert error.inner_text().startswith("notes: ")
    assert server.api("GET", "/api/datasets/world")["notes"] == "two HDL-64E frames, seed 0; the fog study's baseline"
    page.goto(server.url + "/#/datasets")
    cell = page.locator("[data-testid=dataset-row][data-name=world] [data-testid=notes-cell]")
    cell.wait_for()
    assert cell.inner_text() == "two HDL-64E frames, seed 0; the fog study's baseline"


def test_a_bare_data_sets_page_warns_that_ap_needs_labels(page: Any, server: Server, artifacts: Path) -> None:
    page.goto(server.url + "/#/datasets/bare")  # uploaded by the first test
    page.get_by_test_id("labels-warning").wait_for()
    assert page.get_by_test_id("labels-warning").inner_text() == NO_LABELS
    assert page.get_by_test_id("fact-labels").inner_text() == "0 of 2 frames have labels."
    page.screenshot(path=str(artifacts / "inventory-dataset-no-labels.png"), full_page=True)


def test_a_refused_delete_stays_under_its_row_until_the_next_action(page: Any, server: Server,
                                                                    artifacts: Path) -> None:
    task_id = server.task_id  # type: ignore[attr-defined]
    page.on("dialog", lambda dialog: dialog.accept())
    page.goto(server.url + "/#/datasets")
    page.locator("[data-testid=dataset-row][data-name=world] [data-testid=delete-dataset]").click()
    refusal = page.locator("[data-testid=refusal-row][data-name=world]")
    refusal.wait_for()
    assert refusal.get_by_test_id("refusal").inner_text().startswith(
        f"data set 'world' is used by 1 task (#{task_id} noise); delete it first")
    assert refusal.get_by_test_id("used-by-task").get_attribute("href") == f"#/tasks/{task_id}"
    # the refusal row sits right under the refused data set's row
    assert page.evaluate("() => document.querySelector('[data-testid=refusal-row]').previousElementSibling"
                         ".dataset.name") == "world"
    no_horizontal_scroll(page)  # the 100-character name wraps
    page.screenshot(path=str(artifacts / "inventory-dataset-refusal.png"), full_page=True)
    # the next action (an upload with no files chosen) clears it
    page.get_by_test_id("upload-name").fill("nothing")
    page.get_by_test_id("upload-submit").click()
    page.get_by_test_id("upload-error").wait_for()
    assert page.locator("[data-testid=refusal-row]").count() == 0
    # the same on the models page
    page.goto(server.url + "/#/models")
    page.locator("[data-testid=model-row][data-name=classic] [data-testid=delete-model]").click()
    refusal = page.locator("[data-testid=refusal-row][data-name=classic]")
    refusal.wait_for()
    assert refusal.inner_text().startswith(f"model 'classic' is used by 1 task (#{task_id} noise); delete it first")
    page.screenshot(path=str(artifacts / "inventory-model-refusal.png"), full_page=True)
    page.locator("[data-testid=model-row][data-name=spare] [data-testid=delete-model]").click()
    page.locator("[data-testid=model-row][data-name=spare]").wait_for(state="detached")
    assert page.locator("[data-testid=refusal-row]").count() == 0  # deleting another model was the next action


def test_models_show_their_type_modality_and_notes(page: Any, server: Server, artifacts: Path) -> None:
    pytest.importorskip("torch")
    server.api("POST", "/api/models", json={"name": "steer", "spec": "dave2", "modality": "camera"})
    page.goto(server.url + "/#/models")
    page.get_by_test_id("model-name").fill("plain")
    page.get_by_test_id("model-spec").fill("classic")
    page.get_by_test_id("model-notes").fill("the correct pipeline, as shipped")
    page.get_by_test_id("model-submit").click()
    row = page.locator("[data-testid=model-row][data-name=plain]")
    row.wait_for()
    types = {name: page.locator(f"[data-testid=model-row][data-name={name}] [data-testid=model-type]").inner_text()
             for name in ("classic", "plain", "steer")}
    assert types == {"classic": "bug-zoo variant of the classic pipeline", "plain": "classic pipeline",
                     "steer": "built-in steering network"}
    assert row.get_by_test_id("model-modality").inner_text() == "LiDAR"
    assert page.locator("[data-testid=model-row][data-name=steer] [data-testid=model-modality-badge]").inner_text() \
        == "camera"
    assert row.get_by_test_id("notes-cell").inner_text() == "the correct pipeline, as shipped"
    page.screenshot(path=str(artifacts / "inventory-models.png"), full_page=True)
    row.get_by_test_id("model-link").click()
    page.get_by_test_id("fact-type").wait_for()
    assert page.get_by_test_id("fact-type").inner_text() == "classic pipeline"
    assert page.get_by_test_id("fact-used-by").inner_text() == "no task yet"
    page.get_by_test_id("notes-edit").fill("the correct pipeline; the baseline of every comparison")
    page.get_by_test_id("notes-save").click()
    page.get_by_test_id("notes-saved").wait_for()
    assert server.api("GET", "/api/models/plain")["notes"] == "the correct pipeline; the baseline of every comparison"
    page.screenshot(path=str(artifacts / "inventory-model-detail.png"), full_page=True)


def test_upload_a_folder_on_the_visualisation_page_and_view_it(page: Any, server: Server,
                                                               frames: dict[str, list[Path]], artifacts: Path) -> None:
    page.goto(server.url + "/#/browse")
    page.get_by_test_id("upload-form").wait_for()
    folder = frames["velodyne"][0].parent.parent  # velodyne/, calib/, label_2/
    page.get_by_test_id("upload-folder").set_input_files(str(folder))
    assert page.get_by_test_id("upload-picked").inner_text() == f"6 files: {folder.name}"
    page.get_by_test_id("upload-name").fill("rig")
    page.screenshot(path=str(artifacts / "inventory-browse-upload.png"), full_page=True)
    page.get_by_test_id("upload-submit").click()
    page.get_by_test_id("frame-list").wait_for()
    assert page.url.endswith("#/browse/rig?uploaded=1")
    assert page.get_by_test_id("frame-link").all_inner_texts() == ["000000", "000001"]
    assert page.get_by_test_id("upload-ok").inner_text() == \
        "Uploaded rig (2 frames). 2 of 2 frames have a label file."
    page.screenshot(path=str(artifacts / "inventory-browse-uploaded.png"), full_page=True)


def test_files_dropped_on_the_visualisation_page_are_uploaded(page: Any, server: Server,
                                                              frames: dict[str, list[Path]]) -> None:
    page.goto(server.url + "/#/browse")
    page.get_by_test_id("upload-drop").wait_for()
    files = [{"name": p.name, "data": base64.b64encode(p.read_bytes()).decode()}
             for p in frames["velodyne"] + frames["calib"]]
    page.evaluate("""files => {
        const transfer = new DataTransfer();
        for (const f of files) {
            const bytes = Uint8Array.from(atob(f.data), c => c.charCodeAt(0));
            transfer.items.add(new File([bytes], f.name));
        }
        const zone = document.querySelector('[data-testid=upload-drop]');
        zone.dispatchEvent(new DragEvent('drop', {dataTransfer: transfer, bubbles: true, cancelable: true}));
    }""", files)
    page.get_by_test_id("upload-picked").get_by_text("4 files: 000000.bin").wait_for()
    page.get_by_test_id("upload-name").fill("dropped")
    page.get_by_test_id("upload-submit").click()
    page.get_by_test_id("frame-list").wait_for()
    assert page.url.endswith("#/browse/dropped?uploaded=1")
    assert page.get_by_test_id("upload-labels-warning").inner_text() == NO_LABELS
