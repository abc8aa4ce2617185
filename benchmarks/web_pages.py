"""Cold first load of every page of the web app: a fresh browser context (empty cache) per load,
from navigation to the page's content on screen, in headless Chromium on localhost.

:func:`cold_loads` is what ``benchmarks/web.py`` calls with its own server and store. A page is
"loaded" when its own content is there (a JavaScript predicate per page: the first row of a list,
the viewer's first drawn frame, the report's frame loaded), not when the network goes quiet.
Target (issue 22): < 1 s per page on this machine.
"""

from __future__ import annotations

import statistics
from dataclasses import dataclass
from typing import Any

TARGET_MS = 1000.0
SWIFTSHADER = ["--use-angle=swiftshader", "--enable-unsafe-swiftshader"]


@dataclass(frozen=True)
class PageCheck:
    """One page: its name, its address (the part after ``#``) and when its content is on screen."""

    name: str
    path: str
    ready: str  # a JavaScript expression, true once the page shows its content
    frame: tuple[str, str] | None = None  # then (an iframe, an element in it) shown: the report's sandboxed frame


def testid(name: str) -> str:
    """Ready when an element with ``data-testid=name`` is in the current view."""
    return f"!!document.querySelector('#page .view [data-testid=\"{name}\"]')"


def viewer_drawn() -> str:
    """Ready when the point-cloud viewer has drawn its first frame."""
    return "window.__viewer && window.__viewer.firstRenderMs !== null && !window.__viewer.disposed"


def report_given() -> str:
    """Ready when the report's frame has been given the report (its content, in an opaque origin, is
    waited for through :attr:`PageCheck.frame`)."""
    return ("(() => { const f = document.querySelector('[data-testid=\"report-frame\"]');"
            " return !!f && f.srcdoc.length > 0; })()")


def picture_loaded(name: str) -> str:
    """Ready when the picture with ``data-testid=name`` has loaded."""
    return (f"(() => {{ const i = document.querySelector('#page .view [data-testid=\"{name}\"]');"
            " return !!i && !!i.getAttribute('src') && i.complete && i.naturalWidth > 0; })()")


def pages(task_id: int, finding_id: int, dataset: str, frame_id: str, other: int) -> list[PageCheck]:
    """The app's pages on a store holding task ``task_id`` with finding ``finding_id`` and data set
    ``dataset``; ``other``: a second finished task to compare it with."""
    return [
        PageCheck("tasks", "/tasks", testid("task-row")),
        PageCheck("new task", "/tasks/new", testid("task-dataset")),
        PageCheck("task", f"/tasks/{task_id}", testid("subtasks-body") + f" && {testid('task-facts')}"),
        PageCheck("report", f"/tasks/{task_id}/report", report_given(), frame=("[data-testid=report-frame]", "h1")),
        PageCheck("compare", f"/compare?tasks={task_id},{other}", testid("compare-ap")),
        PageCheck("rating", f"/tasks/{task_id}/rate?rater=bench&n=2&operators=rotate_z",
                  picture_loaded("pair-picture")),
        PageCheck("findings", f"/tasks/{task_id}/findings", testid("finding-row")),
        PageCheck("finding viewer", f"/findings/{finding_id}", viewer_drawn()),
        PageCheck("data sets", "/datasets", testid("dataset-row")),
        PageCheck("data set", f"/datasets/{dataset}", testid("notes-form")),
        PageCheck("models", "/models", testid("model-row")),
        PageCheck("visualisation", f"/browse/{dataset}", testid("frame-link")),
        PageCheck("frame viewer", f"/browse/{dataset}/{frame_id}", viewer_drawn()),
    ]


def cold_loads(base_url: str, checks: list[PageCheck], *, runs: int = 5, chromium: str = "/usr/bin/chromium",
               gl_args: list[str] | None = None) -> dict[str, dict[str, Any]]:
    """Per page: the median, min and max milliseconds of ``runs`` cold loads (a new browser context each),
    and the bytes that crossed the wire (compressed) against their decoded size on the last load."""
    from playwright.sync_api import sync_playwright

    args = ["--no-sandbox", *(SWIFTSHADER if gl_args is None else gl_args)]
    out: dict[str, dict[str, Any]] = {}
    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=chromium, args=args)
        try:
            for check in checks:
                times: list[float] = []
                sizes: dict[str, int] = {}
                for _ in range(runs):
                    context = browser.new_context(viewport={"width": 1400, "height": 900})
                    page = context.new_page()
                    page.goto(f"{base_url}/#{check.path}", wait_until="commit")
                    try:
                        page.wait_for_function(check.ready, timeout=30_000, polling="raf")
                        if check.frame is not None:
                            page.frame_locator(check.frame[0]).locator(check.frame[1]).first.wait_for(timeout=30_000)
                    except Exception:  # a page that never shows its content is reported, the others still measured
                        context.close()
                        break
                    took = page.evaluate("performance.now()")  # from the navigation's start
                    sizes = page.evaluate("""() => performance.getEntriesByType('resource').concat(
                        performance.getEntriesByType('navigation')).reduce((a, e) => ({
                            wire: a.wire + (e.transferSize || 0), decoded: a.decoded + (e.decodedBodySize || 0)}),
                            {wire: 0, decoded: 0})""")
                    times.append(float(took))
                    context.close()
                if not times:
                    out[check.name] = {"failed": f"its content did not show within 30 s ({check.ready})"}
                    continue
                out[check.name] = {"median_ms": statistics.median(times), "min_ms": min(times), "max_ms": max(times),
                                   "wire_bytes": int(sizes["wire"]), "decoded_bytes": int(sizes["decoded"])}
        finally:
            browser.close()
    return out


def print_table(results: dict[str, dict[str, Any]], runs: int) -> None:
    print(f"\ncold first load per page (fresh browser context each, median of {runs}; ms from navigation to "
          f"the page's content; target < {TARGET_MS:.0f} ms)")
    print(f"{'page':<16} {'median':>7} {'min':>7} {'max':>7} {'on the wire':>12} {'decoded':>9}")
    for name, r in results.items():
        if "failed" in r:
            print(f"{name:<16} FAILED: {r['failed']}")
            continue
        verdict = "ok" if r["median_ms"] < TARGET_MS else "SLOW"
        print(f"{name:<16} {r['median_ms']:7.0f} {r['min_ms']:7.0f} {r['max_ms']:7.0f} "
              f"{r['wire_bytes'] / 1e3:9.0f} kB {r['decoded_bytes'] / 1e3:6.0f} kB  {verdict}")
