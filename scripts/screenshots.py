"""The README's screenshots of the web app, regenerated: a workspace with the built-in world, two
finished tasks (the same operators on the classic pipeline and on a bug-zoo variant of it) and the
pages a user opens, captured by headless Chromium into ``docs/images/web/``.

Usage::

    .venv/bin/python scripts/screenshots.py [--out docs/images/web] [--frames 4] [--chromium /usr/bin/chromium]

Needs the web extra, Playwright and Chromium (as the browser tests do). Each picture is a 1400 x 900
view (the viewer pages at the size a user sees them), saved as JPEG to keep the repository small.
Deterministic data (seeded world, seeded campaigns); the pictures differ only where the pages do.
"""

from __future__ import annotations

import argparse
import socket
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import uvicorn

from lidarfuzz.campaign.executor import InlineExecutor
from lidarfuzz.campaign.runner import run_task
from lidarfuzz.campaign.spec import parse_campaign
from lidarfuzz.campaign.tasks import create_task
from lidarfuzz.sim.dataset import GenerationConfig, generate_dataset
from lidarfuzz.store import Finding, Store
from lidarfuzz.store.inventory import add_dataset, add_model
from lidarfuzz.web import create_app

OPERATORS = [{"name": "rotate_z", "severities": [1, 3]}, {"name": "fog", "severities": [3]},
             {"name": "gaussian_noise_addition", "severities": [5]}]
SWIFTSHADER = ["--use-angle=swiftshader", "--enable-unsafe-swiftshader"]


@dataclass(frozen=True)
class Shot:
    """One picture: its file name, the page (after ``#``) and what to wait for before taking it."""

    name: str
    path: str
    ready: str  # a CSS selector, or "viewer" for the point-cloud viewer's first drawn frame
    full_page: bool = False


def workspace(root: Path, frames: int) -> tuple[Path, list[int], int]:
    """The built-in world, registered, and two tasks run to the end: the workspace, the task ids and a finding."""
    generate_dataset(root / "world", GenerationConfig(frames=frames, seed=0), workers=1, overwrite=True)
    store = Store(root / "ws")
    add_dataset(store, "world", root / "world", notes="the built-in simulator: HDL-64E street scenes, seed 0")
    add_model(store, "classic", "classic", notes="the classic pipeline (ground removal, clustering, boxes)")
    add_model(store, "classic-roi-bug", "classic-bug-roi-cache",
              notes="bug zoo: the ROI is cached and does not turn with the scene")
    tasks = []
    for name, sut in (("classic, three operators", "classic"), ("roi bug, three operators", "classic-roi-bug")):
        task_id = create_task(store, parse_campaign({"name": name, "dataset": "world", "sut": sut,
                                                     "operators": OPERATORS, "seed": 0}))
        run_task(store, task_id, executor=InlineExecutor())
        tasks.append(task_id)
    with store.session() as s:
        finding = s.query(Finding.id).filter(Finding.task_id == tasks[1]).order_by(Finding.id).first()
    store.close()
    if finding is None:
        raise SystemExit("the bug-zoo task raised no finding: nothing to show in the viewer")
    return root / "ws", tasks, int(finding[0])


def shots(tasks: list[int], finding: int) -> list[Shot]:
    first, second = tasks
    return [
        Shot("tasks", "/tasks", "[data-testid=task-row]"),
        Shot("new-task", "/tasks/new", "[data-testid=task-dataset]", full_page=True),
        Shot("task", f"/tasks/{second}", "[data-testid=subtasks-body] tr", full_page=True),
        Shot("findings", f"/tasks/{second}/findings", "[data-testid=finding-row]"),
        Shot("finding-viewer", f"/findings/{finding}", "viewer"),
        Shot("compare", f"/compare?tasks={first},{second}", "[data-testid=compare-ap]", full_page=True),
        Shot("rating", f"/tasks/{second}/rate?rater=alice&n=4", "[data-testid=pair-picture][src]"),
        Shot("datasets", "/datasets", "[data-testid=dataset-row]"),
        Shot("dataset", "/datasets/world", "[data-testid=notes-form]"),
        Shot("models", "/models", "[data-testid=model-row]"),
        Shot("frame-viewer", "/browse/world/000000", "viewer"),
    ]


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def capture(base: str, out: Path, pictures: list[Shot], chromium: str) -> list[str]:
    """Takes each picture; returns the names of the pages that did not show what they should."""
    from playwright.sync_api import sync_playwright

    missed = []
    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=chromium, args=["--no-sandbox", *SWIFTSHADER])
        try:
            for shot in pictures:
                page = browser.new_page(viewport={"width": 1400, "height": 900})
                page.goto(f"{base}/#{shot.path}")
                try:
                    if shot.ready == "viewer":
                        page.wait_for_function("window.__viewer && window.__viewer.firstRenderMs !== null",
                                               timeout=60_000)
                    else:
                        page.wait_for_selector(shot.ready, timeout=30_000)
                except Exception:  # a page without its content is named; the rest are still taken
                    missed.append(shot.name)
                # lazily loaded pictures (thumbnails, a rating pair) drawn before the shot
                page.evaluate("() => document.querySelectorAll('img[loading=lazy]')"
                              ".forEach(i => { i.loading = 'eager'; })")
                page.wait_for_function("[...document.images].every(i => !i.getAttribute('src') || i.complete)",
                                       timeout=30_000)
                page.wait_for_timeout(300)  # charts and fonts settle
                page.screenshot(path=str(out / f"{shot.name}.jpg"), type="jpeg", quality=82,
                                full_page=shot.full_page)
                page.close()
        finally:
            browser.close()
    return missed


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("docs/images/web"))
    parser.add_argument("--frames", type=int, default=4)
    parser.add_argument("--chromium", default="/usr/bin/chromium")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="lidarfuzz-screenshots-") as tmp:
        ws, tasks, finding = workspace(Path(tmp), args.frames)
        port = free_port()
        server = uvicorn.Server(uvicorn.Config(create_app(ws, workers=0), host="127.0.0.1", port=port,
                                               log_level="warning"))
        thread = threading.Thread(target=server.run, daemon=True)
        thread.start()
        while not server.started:
            time.sleep(0.05)
        try:
            missed = capture(f"http://127.0.0.1:{port}", args.out, shots(tasks, finding), args.chromium)
        finally:
            server.should_exit = True
            thread.join(10)
    print(f"screenshots in {args.out}")
    if missed:
        print(f"pages that did not show their content: {', '.join(missed)}", file=sys.stderr)
        raise SystemExit(1)


if __name__ == "__main__":
    main()
