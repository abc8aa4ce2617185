#!/usr/bin/env python3
"""A steering program speaking lidarfuzz's worker protocol for camera frames (lidarfuzz.suts.steering.worker).

lidarfuzz starts it once (``worker:python3 examples/suts/steering_worker.py``) and writes one JSON
line per frame to its stdin::

    {"frame_id": "000042", "image": "/tmp/…/000042.png", "format": "png", "height": 480, "width": 640,
     "channels": "rgb"}

(``"format": "raw"``: height × width × 3 bytes, RGB, row after row). It answers one line,
``{"steering": angle}``, or ``{"error": "message"}``, echoing the request's ``"id"`` (the frame id
and a sequence number; an answer without it is an invalid output); an empty line (or end of
input) ends it.

Its "network" is a rule a test can work out by hand: the bottom half of the frame is split into
a left and a right half, and the answer is ``gain · (mean(right) − mean(left)) / 255`` over all
three channels (``--gain``, default 0.5): brighter on the right (the kerb, the lane markings of
a left bend in the built-in world) steers left. A program in another language does the same
with its own network; only numpy and OpenCV are needed here, not lidarfuzz.

For tests of failure handling, ``--fail-on FRAME_ID:MODE`` makes the frame with that id exit
(``crash``), hang (``hang``), answer ``{"error": ...}`` (``error``), a line that is not JSON
(``garbage``), NaN (``nan``) or 10 (``huge``, outside any declared steering range).
"""

from __future__ import annotations

import json
import sys
import time

import cv2
import numpy as np


def read_image(request: dict) -> np.ndarray:
    """The frame as height × width × 3 uint8 RGB."""
    if request["format"] == "raw":
        return np.fromfile(request["image"], np.uint8).reshape(int(request["height"]), int(request["width"]), 3)
    if request["format"] == "png":
        bgr = cv2.imread(request["image"], cv2.IMREAD_COLOR)
        if bgr is None:
            raise ValueError(f"cannot read {request['image']}")
        return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
    raise ValueError(f"unknown image format {request['format']!r}")


def steer(image: np.ndarray, gain: float) -> float:
    """``gain · (mean of the bottom-right quarter − mean of the bottom-left quarter) / 255``."""
    height, width = image.shape[:2]
    bottom = image[height // 2:].astype(np.float64)
    left, right = bottom[:, : width // 2].mean(), bottom[:, width // 2:].mean()
    return gain * (right - left) / 255.0


def main(argv: list[str]) -> None:
    gain, fail_on = 0.5, {}
    while argv:
        flag, value = argv.pop(0), argv.pop(0)
        if flag == "--gain":
            gain = float(value)
        elif flag == "--fail-on":
            frame_id, _, mode = value.rpartition(":")
            fail_on[frame_id] = mode
        else:
            raise SystemExit(f"unknown option {flag}")
    for line in sys.stdin:
        if not line.strip():
            break
        request = json.loads(line)
        mode = fail_on.get(str(request.get("frame_id")))
        if mode == "crash":
            sys.stderr.write("steering_worker: crashing as asked\n")
            sys.exit(3)
        if mode == "hang":
            time.sleep(3600)
        if mode == "garbage":
            print("this is not JSON", flush=True)
            continue
        try:
            if mode == "error":
                raise RuntimeError("failing as asked")
            value = float("nan") if mode == "nan" else 10.0 if mode == "huge" else steer(read_image(request), gain)
            answer: dict[str, object] = {"steering": value}
        except Exception as exc:  # the protocol's error answer
            answer = {"error": f"{type(exc).__name__}: {exc}"}
        answer["id"] = request["id"]  # every answer echoes its request's id
        print(json.dumps(answer), flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
