#!/usr/bin/env python3
"""A small external detector speaking lidarfuzz's subprocess protocol (docs/suts.md).

It needs only numpy. Points above the ground are rasterised into a 0.5 m bird's-eye grid,
8-connected occupied cells are grouped, and each group of car-like extent becomes an
axis-aligned "Car" box. It is deliberately simple: the point is the protocol.

One-shot:  grid_detector.py POINTS.bin OUTPUT.json
Worker:    grid_detector.py --worker        (one JSON request per stdin line, each answer echoing its "id")

For tests of failure handling, ``--fail-on ID:MODE`` makes frame ``ID`` crash (``crash``),
hang (``hang``), or answer garbage (``garbage``).
"""

from __future__ import annotations

import json
import sys
import time

import numpy as np

CELL = 0.5
GROUND_Z = -1.3


def groups(occupied: np.ndarray) -> np.ndarray:
    """Label 8-connected occupied cells by iterative min-propagation of cell indices."""
    h, w = occupied.shape
    labels = np.where(occupied, np.arange(h * w).reshape(h, w), h * w)
    while True:
        padded = np.pad(labels, 1, constant_values=h * w)
        neighbours = [padded[1 + dy : 1 + dy + h, 1 + dx : 1 + dx + w] for dy in (-1, 0, 1) for dx in (-1, 0, 1)]
        updated = np.where(occupied, np.min(neighbours, axis=0), h * w)
        if np.array_equal(updated, labels):
            return labels
        labels = updated


def detect(points: np.ndarray) -> list[dict]:
    keep = (points[:, 2] > GROUND_Z) & (points[:, 2] < 1.0) & (np.abs(points[:, 1]) < 30) & (points[:, 0] > 0)
    keep &= points[:, 0] < 60
    p = points[keep]
    if len(p) == 0:
        return []
    ix = ((p[:, 0]) / CELL).astype(int)
    iy = ((p[:, 1] + 30) / CELL).astype(int)
    grid = np.zeros((int(60 / CELL) + 1, int(60 / CELL) + 1), dtype=bool)
    grid[ix, iy] = True
    labels = groups(grid)
    point_group = labels[ix, iy]
    out = []
    for g in np.unique(point_group):
        member = p[point_group == g]
        if len(member) < 30:
            continue
        lo, hi = member[:, :3].min(axis=0), member[:, :3].max(axis=0)
        size = hi - lo
        if not (1.5 < max(size[0], size[1]) < 6.0 and 0.8 < min(size[0], size[1]) < 2.5):
            continue
        centre = (lo + hi) / 2
        length, width = (size[0], size[1]) if size[0] >= size[1] else (size[1], size[0])
        yaw = 0.0 if size[0] >= size[1] else np.pi / 2
        score = float(min(1.0, len(member) / 300.0))
        box = [float(centre[0]), float(centre[1]), float(centre[2]), float(length), float(width), float(size[2]), yaw]
        out.append({"label": "Car", "box": box, "score": score})
    return out


def load(path: str) -> np.ndarray:
    return np.fromfile(path, dtype=np.float32).reshape(-1, 4)


def failure(frame_id: str, fail_on: dict[str, str]) -> str | None:
    return fail_on.get(frame_id)


def main(argv: list[str]) -> int:
    fail_on: dict[str, str] = {}
    while "--fail-on" in argv:
        i = argv.index("--fail-on")
        frame_id, mode = argv[i + 1].split(":")
        fail_on[frame_id] = mode
        del argv[i : i + 2]
    if argv[:1] == ["--worker"]:
        for line in sys.stdin:
            if not line.strip():
                return 0
            request = json.loads(line)
            mode = failure(request["frame_id"], fail_on)
            if mode == "crash":
                return 3
            if mode == "hang":
                time.sleep(3600)
            if mode == "garbage":
                print("this is not json", flush=True)
                continue
            answer = {"id": request["id"], "detections": detect(load(request["points"]))}  # echo the id
            print(json.dumps(answer), flush=True)
        return 0
    points_path, output_path = argv[0], argv[1]
    frame_id = argv[2] if len(argv) > 2 else ""
    mode = failure(frame_id, fail_on)
    if mode == "crash":
        print("simulated crash", file=sys.stderr)
        return 3
    if mode == "hang":
        time.sleep(3600)
    with open(output_path, "w") as handle:
        if mode == "garbage":
            handle.write("{not json")
        else:
            json.dump({"detections": detect(load(points_path))}, handle)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
