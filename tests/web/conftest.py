"""Fixtures of the web tests: a tiny simulated world, apps on fresh workspaces, and one finished
task (with findings) that read-only tests share.

Tasks run in the app's worker thread with the inline executor (no process pool to start), on
two HDL-64E frames with the classic pipeline: enough for the gaussian noise operator at
severity 5 to make the pipeline lose a car (findings to open), and fast (well under a second).
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from lidarfuzz.sim.dataset import GenerationConfig, generate_dataset
from lidarfuzz.store import Store
from lidarfuzz.store.inventory import add_dataset, add_model
from lidarfuzz.web import create_app

BASE = "http://127.0.0.1"
#: What a browser sends with every write from the app's own page (a tokenless server refuses writes without it)
ORIGIN = {"Origin": BASE}
#: The tasks' operator: the scene turned by 15-45 degrees, harmless to a correct system; the model
#: registered as ``classic`` is a bug-zoo variant of the classic pipeline whose ROI does not turn with
#: the scene, so that tasks have findings to show (the correct pipeline raises none here)
TURN = [{"name": "rotate_z", "severities": [3]}]


def simulated_world(factory: pytest.TempPathFactory, frames: int) -> Path:
    """``frames`` independent HDL-64E frames of seed 0 in KITTI layout, in a new temporary folder."""
    root = factory.mktemp("web-world") / "sim"
    generate_dataset(root, GenerationConfig(frames=frames, seed=0), workers=1, overwrite=True)
    return root


@pytest.fixture(scope="session")
def world(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Two independent HDL-64E frames in KITTI layout (read-only)."""
    return simulated_world(tmp_path_factory, 2)


def register(workspace: Path, world: Path) -> None:
    """The world as data set ``world`` and the classic pipeline as model ``classic``."""
    store = Store(workspace)
    add_dataset(store, "world", world)
    add_model(store, "classic", "classic-bug-roi-cache")
    store.close()


def wait_for(client: TestClient, task_id: int, states: tuple[str, ...] = ("done", "failed", "cancelled"),
             timeout: float = 60.0) -> dict[str, Any]:
    """Poll a task until it reaches one of ``states``."""
    deadline = time.monotonic() + timeout
    while True:
        task: dict[str, Any] = client.get(f"/api/tasks/{task_id}").json()
        if task["status"] in states:
            return task
        if time.monotonic() > deadline:
            raise AssertionError(f"task {task_id} still {task['status']} after {timeout} s: {task}")
        time.sleep(0.1)


@pytest.fixture
def make_client(tmp_path: Path) -> Iterator[Callable[..., TestClient]]:
    """``make_client(**create_app options)``: a started app on ``tmp_path/ws`` (inline tasks by default)."""
    clients: list[TestClient] = []

    def make(workspace: Path | None = None, base_url: str = BASE, **options: Any) -> TestClient:
        options.setdefault("inline", True)
        client = TestClient(create_app(workspace or tmp_path / "ws", **options), base_url=base_url,
                            headers={"Origin": base_url})  # as the app's own page: writes need it
        client.__enter__()
        clients.append(client)
        return client

    yield make
    for client in reversed(clients):
        client.__exit__(None, None, None)


@pytest.fixture
def client(make_client: Callable[..., TestClient], tmp_path: Path, world: Path) -> TestClient:
    """An app whose store knows data set ``world`` and model ``classic``."""
    register(tmp_path / "ws", world)
    return make_client()


@pytest.fixture(scope="module")
def finished(tmp_path_factory: pytest.TempPathFactory, world: Path) -> Iterator[tuple[TestClient, int]]:
    """A client and a task run to the end through the API (originals and gaussian noise @5 on the
    world): shared by read-only tests."""
    yield from finished_task(tmp_path_factory.mktemp("web-finished") / "ws", world,
                             {"name": "noise", "dataset": "world", "sut": "classic", "operators": TURN})


def finished_task(workspace: Path, world: Path, campaign: dict[str, Any]) -> Iterator[tuple[TestClient, int]]:
    """A client on a new ``workspace`` knowing ``world`` and ``classic``, and ``campaign`` run to the
    end through the API (the body of a module-scoped fixture: ``yield from``)."""
    register(workspace, world)
    with TestClient(create_app(workspace, inline=True), base_url=BASE, headers=ORIGIN) as client:
        reply = client.post("/api/tasks", json=campaign)
        assert reply.status_code == 201, reply.text
        task_id = reply.json()["id"]
        assert wait_for(client, task_id)["status"] == "done"
        yield client, task_id


# -- the browser tests' fixtures (tests/web/test_browser*.py): Debian's Chromium through Playwright ---------
@pytest.fixture(scope="module")
def artifacts() -> Path:
    """Where the browser tests' screenshots go: ``test-artifacts/web`` or ``$LIDARFUZZ_TEST_ARTIFACTS/web``."""
    from tests.web.test_browser import ROOT

    folder = Path(os.environ.get("LIDARFUZZ_TEST_ARTIFACTS", ROOT / "test-artifacts")) / "web"
    folder.mkdir(parents=True, exist_ok=True)
    return folder


@pytest.fixture(scope="module")
def browser() -> Iterator[Any]:
    """Headless Chromium, one per test module."""
    from tests.web.test_browser import CHROMIUM, CHROMIUM_ARGS, sync_api

    with sync_api.sync_playwright() as playwright:
        launched = playwright.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)
        yield launched
        launched.close()


@pytest.fixture
def page(browser: Any, artifacts: Path, request: pytest.FixtureRequest) -> Iterator[Any]:
    """A fresh tab; uncaught script errors fail the test. Its last view is kept as a screenshot."""
    from tests.web.test_browser import TIMEOUT_MS

    context = browser.new_context(viewport={"width": 1400, "height": 900}, accept_downloads=True)
    tab = context.new_page()
    tab.set_default_timeout(TIMEOUT_MS)
    errors: list[str] = []
    tab.on("pageerror", lambda exc: errors.append(str(exc)))
    yield tab
    tab.screenshot(path=str(artifacts / f"last-{request.node.name}.png"), full_page=True)
    context.close()
    assert not errors, f"uncaught errors in the page: {errors}"
