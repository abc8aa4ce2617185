"""The web app's list pages with 1,000 tasks in the store, and a frame's transfer (and first render).

Usage: ``.venv/bin/python benchmarks/web.py [--tasks N] [--requests R] [--repeat K] [--page-runs P] [--no-pages]``

A store is filled with ``--tasks`` finished tasks (rows inserted directly, each with 40 frame ids,
eight subtasks and a 20 kB summary, as a real task has), 20 data sets and 10 models; the app is
served by a real uvicorn server on 127.0.0.1 and called over HTTP with one keep-alive client,
as a browser does. Per endpoint: p50 and p95 latency of ``--requests`` calls after a warm-up,
median over ``--repeat`` runs. Target (issue 9): p95 < 100 ms.

Frame transfer: one HDL-64E frame (about 120,000 points, every channel) of a simulated data set
as the ``LFZ1`` binary payload, request to last byte, median of 20; and a finding's pair (the
original and its mutant rebuilt from the stored params, with the change channel and boxes) of a
task run for real on two frames. The browser part (parse and
first render in the three.js viewer) is :func:`frame_first_render`, measured with a browser. The
pair's transfer is measured uncompressed and gzip-compressed (bytes on the wire, request to last byte).

Cold first load of every page (:mod:`web_pages`): a fresh browser context per load, from navigation
to the page's own content on screen, median of ``--page-runs``; target (issue 22) < 1 s.
"""

from __future__ import annotations

import argparse
import json
import socket
import statistics
import tempfile
import threading
import time
from collections.abc import Callable
from datetime import UTC, datetime, timedelta
from pathlib import Path

import httpx
import uvicorn
from sqlalchemy import insert

from lidarfuzz.campaign.executor import InlineExecutor
from lidarfuzz.campaign.runner import run_task
from lidarfuzz.campaign.spec import parse_campaign
from lidarfuzz.campaign.tasks import create_task
from lidarfuzz.sim.dataset import GenerationConfig, generate_dataset
from lidarfuzz.store import Dataset, Model, Status, Store, Subtask, Task
from lidarfuzz.store.inventory import add_dataset, add_model
from lidarfuzz.web import create_app

TARGET_MS = 100.0
ENDPOINTS = ("/api/tasks", "/api/tasks?limit=50&offset=500", "/api/tasks?status=done", "/api/tasks?sort=-map",
             "/api/tasks?sort=violations&tag=bench", "/api/tasks?q=task%209", "/api/datasets", "/api/models")


def finding_task(store: Store) -> int:
    """A real task with findings (the scene turned, on a bug-zoo pipeline whose ROI does not turn with
    it: equivariance findings on the simulated frames): its id."""
    task_id = create_task(store, parse_campaign({"dataset": "sim", "sut": "classic-bug-roi-cache", "operators": [
        {"name": "rotate_z", "severities": [3]}]}))
    run_task(store, task_id, executor=InlineExecutor())
    return task_id


def fill(store: Store, tasks: int, data: Path, real: int) -> None:
    """``tasks`` more finished tasks, 19 more data sets and 9 more models, inserted as rows; each task
    carries the real task ``real``'s summary and seven subtasks with its figures, as a real task has."""
    now = datetime.now(UTC)
    with store.session() as s:
        template = s.get(Task, real)
        summary = template.summary.model_dump(mode="json")
        results = [sub.results.model_dump(mode="json") for sub in template.subtasks]
        headline = template.headline
        options = {**template.options.model_dump(mode="json"), "frame_ids": [f"{f:06d}" for f in range(40)]}
        s.execute(insert(Dataset), [{"name": f"set-{i:02d}", "path": str(data), "format": "kitti", "frame_count": 2,
                                     "notes": "benchmark", "added_at": now} for i in range(19)])
        s.execute(insert(Model), [{"name": f"classic-{i}", "spec": "classic", "options": {"min_points": 8 + i},
                                   "fingerprint": f"{i:016x}", "notes": "", "added_at": now} for i in range(9)])
        dataset_id = s.query(Dataset.id).filter(Dataset.name == "sim").scalar()
        model_id = s.query(Model.id).filter(Model.name == "classic").scalar()
        operators = [{"name": "fog", "severities": [1, 3, 5], "config": None},
                     {"name": "rotate_z", "severities": [1, 3, 5], "config": None}]
        rows = []
        for i in range(tasks):
            start = now - timedelta(hours=tasks - i)
            rows.append({"name": f"task {i}", "dataset_id": dataset_id, "model_id": model_id, "operators": operators,
                         "relations": ["auto"], "seed": i, "status": Status.DONE, "done": 280, "total": 280,
                         "created_at": start, "started_at": start, "finished_at": start + timedelta(minutes=5),
                         "summary": summary, "headline": headline, "error": "", "worker": "bench:1",
                         "heartbeat_at": start, "tags": ["bench"] if i % 2 else [], "notes": "",
                         "options": options})
        s.execute(insert(Task), rows)
        ids = [row[0] for row in s.query(Task.id).filter(Task.id != real).all()]
        s.execute(insert(Subtask), [{"task_id": task_id, "operator_key": f"k{j}", "operator": {}, "name": "fog",
                                     "op_index": j, "severity": j, "status": Status.DONE, "done": 40, "total": 40,
                                     "results": results[j % len(results)]} for task_id in ids for j in range(7)])
    print(f"  each task's summary: {len(json.dumps(summary)) / 1e3:.0f} kB of JSON")


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


class Server:
    """A uvicorn server on 127.0.0.1 in a thread."""

    def __init__(self, app: object) -> None:
        self.port = free_port()
        self.server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=self.port, log_level="warning"))
        self.thread = threading.Thread(target=self.server.run, daemon=True)

    def __enter__(self) -> str:
        self.thread.start()
        while not self.server.started:
            time.sleep(0.05)
        return f"http://127.0.0.1:{self.port}"

    def __exit__(self, *exc: object) -> None:
        self.server.should_exit = True
        self.thread.join(10)


def latencies(call: Callable[[], httpx.Response], count: int) -> list[float]:
    out = []
    for _ in range(count):
        start = time.perf_counter()
        reply = call()
        reply.read()
        out.append((time.perf_counter() - start) * 1000)
        reply.raise_for_status()
    return out


def percentile(values: list[float], share: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, round(share * (len(ordered) - 1)))]


def wire_transfer(client: httpx.Client, path: str, encoding: str, count: int = 10) -> tuple[int, float]:
    """Bytes on the wire and median milliseconds (request to last byte) of ``path`` asked for with
    ``Accept-Encoding: encoding``."""
    times, size = [], 0
    for _ in range(count):
        start = time.perf_counter()
        with client.stream("GET", path, headers={"Accept-Encoding": encoding}) as reply:
            reply.raise_for_status()
            size = sum(len(chunk) for chunk in reply.iter_raw())
        times.append((time.perf_counter() - start) * 1000)
    return size, statistics.median(times)


def frame_first_render(base_url: str, dataset: str, frame_id: str) -> float | None:
    """Milliseconds from asking the viewer for a frame to its first drawn picture: headless Chromium
    (Playwright, software WebGL) opens ``{base_url}/#/browse/{dataset}/{frame_id}`` again and again
    in one tab with the HTTP cache off; the median of 7 (``benchmarks/web_render.py`` has the
    breakdown, and cold starts). None when Chromium or Playwright is missing."""
    from web_render import first_render_ms  # benchmarks/ is on sys.path when this script runs

    return first_render_ms(base_url, dataset, frame_id)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", type=int, default=1000)
    parser.add_argument("--requests", type=int, default=200, help="calls per endpoint and run")
    parser.add_argument("--repeat", type=int, default=5, help="runs (the median is shown)")
    parser.add_argument("--page-runs", type=int, default=5, help="cold loads per page (the median is shown)")
    parser.add_argument("--no-pages", action="store_true", help="skip the browser's cold page loads")
    args = parser.parse_args()

    with tempfile.TemporaryDirectory(prefix="lidarfuzz-web-bench-") as tmp:
        root = Path(tmp)
        data = root / "sim"
        generate_dataset(data, GenerationConfig(frames=2, seed=0), workers=1)
        store = Store(root / "ws")
        add_dataset(store, "sim", data)
        add_model(store, "classic", "classic")
        real = finding_task(store)
        start = time.perf_counter()
        fill(store, args.tasks - 1, data, real)
        print(f"store: {args.tasks} tasks (one run for real, with findings), 20 data sets, 10 models "
              f"({time.perf_counter() - start:.1f} s to insert)")
        store.close()
        app = create_app(root / "ws", workers=0)
        with Server(app) as base, httpx.Client(base_url=base) as client:
            total = client.get("/api/tasks").json()["total"]
            assert total == args.tasks, total
            print(f"\nlist pages over HTTP (uvicorn, keep-alive), {args.requests} calls x {args.repeat} runs, "
                  f"median of runs (ms)")
            print(f"{'endpoint':<34} {'p50':>7} {'p95':>7}  target p95 < {TARGET_MS:.0f}")
            for endpoint in ENDPOINTS:
                latencies(lambda e=endpoint: client.get(e), 20)  # warm-up
                runs = [latencies(lambda e=endpoint: client.get(e), args.requests) for _ in range(args.repeat)]
                p50 = statistics.median(percentile(r, 0.50) for r in runs)
                p95 = statistics.median(percentile(r, 0.95) for r in runs)
                verdict = "ok" if p95 < TARGET_MS else "SLOW"
                print(f"{endpoint:<34} {p50:7.1f} {p95:7.1f}  {verdict}")

            frame = client.get("/api/datasets/sim/frames/000000")
            header_length = int.from_bytes(frame.content[4:8], "little")
            points = json.loads(frame.content[8:8 + header_length])["clouds"][0]["count"]
            times = latencies(lambda: client.get("/api/datasets/sim/frames/000000"), 20)
            print(f"\nframe transfer: {points:,} points, {len(frame.content) / 1e6:.1f} MB LFZ1, request to last "
                  f"byte {statistics.median(times):.0f} ms (median of 20)")
            finding = client.get(f"/api/tasks/{real}/findings").json()["items"][0]["id"]
            pair_path = f"/api/findings/{finding}/frames"
            print("finding pair (original + rebuilt mutant, change channel, boxes), request to last byte here "
                  "(median of 10), and the time the bytes alone take on a 20 Mbit/s link:")
            for encoding, what in (("identity", "uncompressed"), ("gzip", "gzip (what a browser asks for)")):
                size, ms = wire_transfer(client, pair_path, encoding)
                seconds_at = size * 8 / 20e6  # a 20 Mbit/s link
                print(f"  {what:<32} {size / 1e6:5.1f} MB on the wire, {ms:4.0f} ms here, "
                      f"{seconds_at:4.1f} s at 20 Mbit/s")
            render = frame_first_render(base, "sim", "000000")
            print("frame first render (browser): " + ("not measured (see frame_first_render)" if render is None
                                                      else f"{render:.0f} ms"))
            start = time.perf_counter()
            client.get(f"/api/tasks/{real}/report", timeout=300).raise_for_status()
            print(f"the report's first writing (charts, pictures; then cached): "
                  f"{(time.perf_counter() - start) * 1000:.0f} ms")
            if not args.no_pages:
                from web_pages import cold_loads, pages, print_table  # benchmarks/ is on sys.path

                checks = pages(real, finding, "sim", "000000", other=real + 1)
                print_table(cold_loads(base, checks, runs=args.page_runs), args.page_runs)


if __name__ == "__main__":
    main()
