"""Frame transfer + first render in the browser: a ~120k-point HDL-64E frame with its boxes, from
the request to the first frame drawn by the viewer, in headless Chromium on localhost.

Usage: ``.venv/bin/python benchmarks/web_render.py [--runs N] [--chromium PATH] [--gl swiftshader|egl]``

A real server (``create_app`` under uvicorn) serves a simulated data set of ``N + 1`` frames; the
viewer opens each frame once (so every frame crosses the wire; the first is a warm-up):

* **warm**: one tab, the app and the viewer's code already loaded, moving from frame to frame —
  what a user browsing a data set or a task's findings sees;
* **cold**: a fresh browser context per frame (empty cache): the page, the app, the viewer's
  code (three.js) and the frame.

``first render`` is the viewer's own figure (``window.__viewer.firstRenderMs``): from just
before the frame is requested to the end of its first draw, read back from the GPU (one
pixel, so the time includes the GPU's work). ``transfer`` is the frame request's Resource
Timing (request start to last byte). Medians of the runs; target (issue 9): < 500 ms.

:func:`first_render_ms` (one frame, opened again and again in one tab with the HTTP cache off) is
what ``benchmarks/web.py`` calls with its own server; :func:`render_times` is this script's.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import threading
import time
import zipfile
from pathlib import Path
from typing import Any

TARGET_MS = 500.0
SWIFTSHADER = ["--use-angle=swiftshader", "--enable-unsafe-swiftshader"]


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _viewer_state(page: Any) -> dict[str, Any]:
    page.wait_for_function("window.__viewer && window.__viewer.firstRenderMs !== null && !window.__viewer.disposed",
                           timeout=60_000)
    return page.evaluate("""() => {
        const frames = performance.getEntriesByType('resource').filter(e => e.name.includes('/frames/'));
        const last = frames[frames.length - 1];
        return {...window.__viewer, transferMs: last ? last.responseEnd - last.startTime : null,
                bytes: last ? last.encodedBodySize : null};
    }""")


def render_times(base_url: str, dataset: str, frame_ids: list[str], *, chromium: str = "/usr/bin/chromium",
                 gl_args: list[str] | None = None, token: str | None = None) -> dict[str, list[dict[str, Any]]]:
    """Open each frame of ``dataset`` once in the viewer, warm (one tab) and cold (a fresh context
    each); returns ``{"warm": [...], "cold": [...]}``, one record per frame (the first is a warm-up
    and is left out): firstRenderMs, transferMs, bytes, pointsDrawn, boxesDrawn."""
    from playwright.sync_api import sync_playwright

    query = f"?token={token}" if token else ""
    args = ["--no-sandbox", *(SWIFTSHADER if gl_args is None else gl_args)]
    out: dict[str, list[dict[str, Any]]] = {"warm": [], "cold": []}
    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=chromium, args=args)
        try:
            # warm: one document, the next frame by a hash change (the old viewer marked, so the
            # wait is for the new one)
            context = browser.new_context(viewport={"width": 1400, "height": 900})
            page = context.new_page()
            page.goto(f"{base_url}/{query}#/browse/{dataset}/{frame_ids[0]}")
            _viewer_state(page)
            for frame_id in frame_ids[1:]:
                page.evaluate("window.__viewer.disposed = true")
                page.evaluate(f"location.hash = '#/browse/{dataset}/{frame_id}'")
                out["warm"].append(_viewer_state(page))
            context.close()
            for k, frame_id in enumerate(frame_ids):
                context = browser.new_context(viewport={"width": 1400, "height": 900})
                page = context.new_page()
                page.goto(f"{base_url}/{query}#/browse/{dataset}/{frame_id}")
                state = _viewer_state(page)
                if k:
                    out["cold"].append(state)
                context.close()
        finally:
            browser.close()
    return out


def repeated_first_render(base_url: str, dataset: str, frame_id: str, *, runs: int = 7,
                          chromium: str = "/usr/bin/chromium", gl_args: list[str] | None = None,
                          token: str | None = None) -> list[dict[str, Any]]:
    """One frame opened ``runs`` times in one tab (the app and the viewer's code loaded, the HTTP
    cache off so the frame crosses the wire each time), after one warm-up; the viewer's records."""
    from playwright.sync_api import sync_playwright

    query = f"?token={token}" if token else ""
    args = ["--no-sandbox", *(SWIFTSHADER if gl_args is None else gl_args)]
    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=chromium, args=args)
        try:
            page = browser.new_page(viewport={"width": 1400, "height": 900})
            cdp = page.context.new_cdp_session(page)
            cdp.send("Network.enable")
            cdp.send("Network.setCacheDisabled", {"cacheDisabled": True})
            route = f"#/browse/{dataset}/{frame_id}"
            page.goto(f"{base_url}/{query}{route}")
            _viewer_state(page)
            records = []
            for _ in range(runs):
                page.evaluate("window.__viewer.disposed = true; location.hash = '#/tasks'")
                page.wait_for_function("!!document.querySelector('[data-testid=tasks-table]')")
                page.evaluate(f"location.hash = '{route}'")
                records.append(_viewer_state(page))
            return records
        finally:
            browser.close()


def first_render_ms(base_url: str, dataset: str, frame_id: str, **kwargs: Any) -> float | None:
    """The median of :func:`repeated_first_render` (None when Chromium or Playwright is missing)."""
    chromium = kwargs.get("chromium", "/usr/bin/chromium")
    try:
        import playwright  # noqa: F401
    except ImportError:
        return None
    if not Path(chromium).exists():
        return None
    return statistics.median(r["firstRenderMs"] for r in repeated_first_render(base_url, dataset, frame_id, **kwargs))


def _table(results: dict[str, list[dict[str, Any]]]) -> str:
    head = f"{'mode':<6} {'frame':>5} {'points':>9} {'boxes':>5} {'MB':>6} {'transfer ms':>12} {'first render ms':>16}"
    lines = [head]
    for mode, runs in results.items():
        for k, run in enumerate(runs, 1):
            mb = (run.get("bytes") or 0) / 1e6
            transfer = run.get("transferMs")
            lines.append(f"{mode:<6} {k:>5} {run['pointsDrawn']:>9,} {run['boxesDrawn']:>5} {mb:>6.2f} "
                         f"{transfer if transfer is None else f'{transfer:.0f}':>12} {run['firstRenderMs']:>16.0f}")
    lines.append("")
    for mode, runs in results.items():
        steps = [r.get("timings") or {} for r in runs]
        if all(steps):
            parts = ", ".join(f"{key} {statistics.median(t[key] for t in steps):.0f}" for key in steps[0])
            built = statistics.median(r.get("builtMs") or 0 for r in runs)
            submitted = statistics.median(r.get("submittedMs") or 0 for r in runs)
            lines.append(f"{mode}: median ms from the request when each step was done: {parts}, scene built "
                         f"{built:.0f}, draw submitted {submitted:.0f}, "
                         f"drawn {statistics.median(r['firstRenderMs'] for r in runs):.0f}")
    lines.append("")
    for mode, runs in results.items():
        renders = [r["firstRenderMs"] for r in runs]
        transfers = [r["transferMs"] for r in runs if r.get("transferMs") is not None]
        median = statistics.median(renders)
        verdict = "meets" if median < TARGET_MS else "misses"
        transfer = f"transfer {statistics.median(transfers):.0f} ms, " if transfers else ""
        lines.append(f"{mode}: median first render {median:.0f} ms ({transfer}max {max(renders):.0f} ms, "
                     f"{len(renders)} runs) — {verdict} the {TARGET_MS:.0f} ms target")
    return "\n".join(lines)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=7, help="frames measured (one more is a warm-up)")
    parser.add_argument("--chromium", default="/usr/bin/chromium")
    parser.add_argument("--gl", choices=["swiftshader", "egl"], default="swiftshader",
                        help="swiftshader: software WebGL (any machine); egl: the GPU, where Chromium has one")
    args = parser.parse_args()
    if not Path(args.chromium).exists():
        print(f"{args.chromium} is missing (apt-get install chromium)", file=sys.stderr)
        return 2

    import uvicorn

    from lidarfuzz.sim.dataset import GenerationConfig, generate_dataset
    from lidarfuzz.web.app import create_app

    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp) / "frames"
        started = time.perf_counter()
        generate_dataset(root, GenerationConfig(frames=args.runs + 1, seed=0), workers=1, overwrite=True)
        print(f"simulated {args.runs + 1} HDL-64E frames in {time.perf_counter() - started:.1f} s")
        archive = Path(tmp) / "frames.zip"
        with zipfile.ZipFile(archive, "w", zipfile.ZIP_STORED) as zipped:
            for path in sorted(root.rglob("*")):
                if path.is_file():
                    zipped.write(path, path.relative_to(root).as_posix())

        port = _free_port()
        app = create_app(Path(tmp) / "workspace", workers=0)
        server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning"))
        thread = threading.Thread(target=server.run, daemon=True)
        thread.start()
        while not server.started:
            time.sleep(0.05)
        try:
            import httpx

            base = f"http://127.0.0.1:{port}"
            with archive.open("rb") as handle:
                httpx.post(f"{base}/api/datasets/upload", data={"name": "bench"}, headers={"Origin": base},
                           files={"files": ("frames.zip", handle, "application/zip")}, timeout=120).raise_for_status()
            ids = httpx.get(f"{base}/api/datasets/bench/frames").json()["frame_ids"]
            gl = SWIFTSHADER if args.gl == "swiftshader" else ["--use-gl=egl", "--ignore-gpu-blocklist"]
            results = render_times(base, "bench", ids, chromium=args.chromium, gl_args=gl)
        finally:
            server.should_exit = True
            thread.join(timeout=30)
    print(f"headless Chromium ({args.gl}), localhost, viewport 1400×900\n")
    print(_table(results))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
