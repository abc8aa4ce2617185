"""Operator previews (``GET /api/operators/{name}/preview.png``, the New task form's pictures): cold and warm.

Usage: ``.venv/bin/python benchmarks/web_previews.py [--severity S] [--operators a,b,...]``

A real uvicorn server on a fresh workspace (nothing cached) is called over HTTP, request to last
byte. *First*: the very first preview the server draws, which also renders the simulator's preview
frame (then cached on disk for every later one). *Cold*: each LiDAR operator's first request at
``--severity`` (drawn: the operator applied to the cached frame, the change flags, the picture),
median and worst over the operators. *Warm*: the same requests again (read from the disk cache),
median and worst. *Form*: the first preview of a fresh server again, right after the operator
catalogue (as the New task form asks for them; the catalogue starts rendering the frame in the
background). Target (issue 22): every preview under 1 s, cold.

:func:`preview_times` is the measurement, for ``benchmarks/web.py`` to call on its own server.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

import httpx

sys.path.insert(0, str(Path(__file__).resolve().parent))

from lidarfuzz.web import create_app
from web import Server


def _get(client: httpx.Client, path: str) -> float:
    start = time.perf_counter()
    reply = client.get(path)
    seconds = time.perf_counter() - start
    reply.raise_for_status()
    return seconds


def preview_times(base_url: str, operators: list[str], severity: int = 3, form: bool = False) -> dict[str, object]:
    """Seconds per preview of ``operators`` at ``severity`` on the server at ``base_url`` (its cache
    empty): ``{"first", "cold": {name: s}, "warm": {name: s}}`` — ``first`` is the first operator's
    cold request (it also renders the preview frame), not counted in ``cold``. ``form``: as the New
    task form does, the operator catalogue is asked for first (which starts rendering the frame in the
    background) and the first preview right after it."""
    with httpx.Client(base_url=base_url, timeout=120) as client:
        if form:
            client.get("/api/operators").raise_for_status()
        first = _get(client, f"/api/operators/{operators[0]}/preview.png?severity={severity}")
        cold = {name: _get(client, f"/api/operators/{name}/preview.png?severity={severity}")
                for name in operators[1:]}
        warm = {name: _get(client, f"/api/operators/{name}/preview.png?severity={severity}") for name in operators}
    return {"first": first, "cold": cold, "warm": warm}


def lidar_operators(severity: int) -> list[str]:
    """Every registered LiDAR operator that has ``severity`` (sorted by name)."""
    from lidarfuzz.operators import available

    return sorted(name for name, cls in available().items() if cls.modality == "lidar" and severity in cls.SEVERITIES)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n", 1)[0])
    parser.add_argument("--severity", type=int, default=3)
    parser.add_argument("--operators", default="", help="comma-separated names (default: every LiDAR operator)")
    args = parser.parse_args()
    names = [n for n in args.operators.split(",") if n] or lidar_operators(args.severity)
    with tempfile.TemporaryDirectory() as folder, Server(create_app(Path(folder) / "ws", inline=True)) as url:
        times = preview_times(url, names, args.severity)
    with tempfile.TemporaryDirectory() as folder, Server(create_app(Path(folder) / "ws", inline=True)) as url:
        form = preview_times(url, names[:1], args.severity, form=True)
    cold, warm = list(times["cold"].values()), list(times["warm"].values())  # type: ignore[union-attr]
    print(f"{len(names)} operators at severity {args.severity}")
    print(f"first preview (renders the frame too): {times['first']:.3f} s; "
          f"right after the operator catalogue, as the New task form asks: {form['first']:.3f} s")
    if cold:
        worst = max(times["cold"].items(), key=lambda kv: kv[1])  # type: ignore[union-attr]
        print(f"cold: median {statistics.median(cold):.3f} s, worst {worst[1]:.3f} s ({worst[0]})")
    print(f"warm: median {statistics.median(warm) * 1000:.1f} ms, worst {max(warm) * 1000:.1f} ms")


if __name__ == "__main__":
    main()
