#!/usr/bin/env python3
"""The built-in controller as a program speaking lidarfuzz's worker protocol for logs (docs/structural.md).

lidarfuzz starts it once (``worker:python3 examples/suts/sequence_worker.py``) and writes one JSON
line per request to its stdin:

* ``{"reset": true}`` before each log: the controller's state is cleared, the answer is ``{"ok": true}``;
* a frame, ``{"frame_id", "points", "format": "bin", "index", "timestamp", "metadata", ...}``: the
  answer is the decision, ``{"steering": ..., "speed": ..., "emergency_stop": ..., "path": [...]}``;
* an empty line (or end of input): exit.

Every request carries an ``"id"`` (the frame id and a sequence number) that its answer echoes:
an answer with another id, or none, is an invalid output and the program is restarted.

A program in another language does the same with its own controller; this one wraps lidarfuzz's
(:class:`lidarfuzz.suts.controller.ObstacleAvoidance`), so its decisions can be compared with the
controller run in process. Options of the controller are given as ``--option key=value``.

For tests of failure handling, ``--fail-on INDEX:MODE`` makes the step at position ``INDEX`` of a
log exit (``crash``), hang (``hang``), answer ``{"error": ...}`` (``error``) or garbage (``garbage``).
"""

from __future__ import annotations

import json
import sys
import time

import numpy as np

from lidarfuzz.scene.points import PointCloud
from lidarfuzz.scene.scene import Scene
from lidarfuzz.suts.controller import ObstacleAvoidance


def frame_of(request: dict) -> Scene:
    """The scene a frame request describes (KITTI ``.bin`` points: x, y, z, intensity)."""
    if request.get("format", "bin") != "bin":
        raise ValueError(f"this worker reads bin points, got format {request.get('format')!r}")
    points = np.fromfile(request["points"], dtype=np.float32).reshape(-1, 4)
    return Scene(PointCloud(points), frame_id=str(request.get("frame_id", "")), timestamp=request.get("timestamp"),
                 metadata=request.get("metadata") or {})


def parse_options(argv: list[str]) -> tuple[dict[str, object], dict[int, str]]:
    options: dict[str, object] = {}
    fail_on: dict[int, str] = {}
    while argv:
        flag, value = argv.pop(0), argv.pop(0)
        if flag == "--option":
            key, _, text = value.partition("=")
            try:
                options[key] = json.loads(text)
            except json.JSONDecodeError:
                options[key] = text
        elif flag == "--fail-on":
            index, _, mode = value.partition(":")
            fail_on[int(index)] = mode
        else:
            raise SystemExit(f"unknown option {flag}")
    return options, fail_on


def main(argv: list[str]) -> int:
    options, fail_on = parse_options(list(argv))
    controller = ObstacleAvoidance(**options)  # type: ignore[arg-type]
    for line in sys.stdin:
        if not line.strip():
            return 0
        request = json.loads(line)
        if request.get("reset"):
            controller.reset()
            print(json.dumps({"ok": True, "id": request["id"]}), flush=True)  # every answer echoes the id
            continue
        mode = fail_on.get(int(request.get("index", -1)))
        if mode == "crash":
            print("simulated crash", file=sys.stderr, flush=True)
            return 3
        if mode == "hang":
            time.sleep(3600)
        if mode == "error":
            print(json.dumps({"error": "simulated failure", "id": request["id"]}), flush=True)
            continue
        if mode == "garbage":
            print("this is not json", flush=True)
            continue
        try:
            decision = controller.step(frame_of(request))
        except Exception as exc:  # reported to lidarfuzz as this step's failure; the worker goes on
            print(json.dumps({"error": f"{type(exc).__name__}: {exc}", "id": request["id"]}), flush=True)
            continue
        print(json.dumps({**decision.to_dict(), "id": request["id"]}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
