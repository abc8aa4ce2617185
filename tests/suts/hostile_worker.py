#!/usr/bin/env python3
"""A hostile system under test: a detector that misbehaves in one chosen way on chosen frames.

Worker:    hostile_worker.py KIND [--on ID,ID,...] [--tag TEXT]
One-shot:  hostile_worker.py KIND [--on ID,...] [--tag TEXT] --oneshot POINTS OUTPUT FRAME_ID

On a frame not listed in ``--on`` (every frame when ``--on`` is absent) it answers correctly
and in the worker protocol's framing: one ``Car`` whose box is a function of the frame id
alone (``x = 10 + int(frame_id)``), so that a test knows, without running anything, which
answer belongs to which frame. On a listed frame it does KIND (see :data:`KINDS`). It needs
only the standard library (and starts in a few tens of milliseconds).
"""

from __future__ import annotations

import json
import os
import signal
import sys
import time

#: What each kind does on a listed frame.
KINDS = {
    "none": "answers correctly",
    "crash": "exits with code 3 after a line on stderr",
    "segfault": "dies of a segmentation fault (SIGSEGV)",
    "abort": "aborts (SIGABRT), as a failed C assertion does",
    "exit0": "exits with code 0 before answering",
    "hang": "sleeps for an hour",
    "slow": "answers after 3 s",
    "spin": "computes forever (a busy loop)",
    "leak": "allocates 32 MiB blocks until its memory runs out (stops at 2 GiB and hangs)",
    "fork-linger": "forks a child that detaches its streams and sleeps for an hour, then answers",
    "fork-holds-pipe": "forks a child that keeps its stdout and stderr and sleeps, then exits with code 3 "
                       "(one-shot: answers and exits 0)",
    "stray": "prints a log line on stdout before its answer",
    "garbage": "answers a line that is not JSON",
    "huge": "answers a 64 MiB line",
    "boxes100k": "answers 100,000 boxes",
    "nan": "answers a box with a NaN centre",
    "inf": "answers a box with an infinite length",
    "negative": "answers a box with a negative width",
    "wrong-id": "answers with the id of another request",
    "no-id": "answers without the id (the protocol before ids)",
    "no-newline": "answers without the final newline, then waits for the next request",
}


def box(frame_id: str) -> dict[str, object]:
    """The correct answer's only detection for ``frame_id``."""
    index = int(frame_id) if frame_id.isdigit() else 0
    return {"label": "Car", "box": [10.0 + index, 0.0, -1.0, 4.0, 1.8, 1.5, 0.0], "score": 0.9}


def fork_child(keep_streams: bool) -> None:
    """A child that sleeps for an hour, holding the parent's streams or not."""
    if os.fork() == 0:
        if not keep_streams:
            null = os.open(os.devnull, os.O_RDWR)
            for fd in (0, 1, 2):
                os.dup2(null, fd)
        time.sleep(3600)
        os._exit(0)


def leak() -> None:
    blocks = []
    for _ in range(64):  # 2 GiB at most, should no memory limit stop it first
        blocks.append(bytearray(32 << 20))
    time.sleep(3600)


def misbehave(kind: str, frame_id: str, oneshot: bool = False) -> dict[str, object]:
    """Do ``kind``; the detections to answer. A one-shot ``fork-holds-pipe`` exits 0 after its
    answer, leaving the child holding its stderr."""
    if kind == "crash":
        sys.stderr.write("hostile_worker: crashing as asked\n")
        sys.exit(3)
    if kind == "segfault":
        os.kill(os.getpid(), signal.SIGSEGV)
    if kind == "abort":
        os.abort()
    if kind == "exit0":
        sys.exit(0)
    if kind == "hang":
        time.sleep(3600)
    if kind == "slow":
        time.sleep(3)
    while kind == "spin":
        pass
    if kind == "leak":
        leak()
    if kind in ("fork-linger", "fork-holds-pipe"):
        fork_child(kind == "fork-holds-pipe")
        if kind == "fork-holds-pipe" and not oneshot:
            sys.exit(3)
    good = box(frame_id)
    values: dict[str, list[float]] = {"nan": [float("nan")] * 3, "inf": [10.0, 0.0, -1.0, float("inf")],
                                      "negative": [10.0, 0.0, -1.0, 4.0, -1.8]}
    if kind in values:
        start = values[kind]
        return {"detections": [{**good, "box": start + list(good["box"])[len(start):]}]}  # type: ignore[arg-type]
    if kind == "boxes100k":
        return {"detections": [good] * 100_000}
    return {"detections": [good]}


def serve(kind: str, listed: set[str] | None) -> int:
    for line in sys.stdin:
        if not line.strip():
            return 0
        request = json.loads(line)
        frame_id = str(request.get("frame_id", ""))
        chosen = listed is None or frame_id in listed
        answer = misbehave(kind, frame_id) if chosen else {"detections": [box(frame_id)]}
        answer["id"] = request["id"]
        if chosen and kind == "stray":
            print("loading weights ... done", flush=True)
        if chosen and kind == "garbage":
            print("this is not json", flush=True)
            continue
        if chosen and kind == "huge":
            chunk = "x" * (1 << 20)
            for _ in range(64):
                sys.stdout.write(chunk)
            print(flush=True)
            continue
        if chosen and kind == "wrong-id":
            answer["id"] = "someone-else#0"
        if chosen and kind == "no-id":
            del answer["id"]
        if chosen and kind == "no-newline":
            sys.stdout.write(json.dumps(answer))
            sys.stdout.flush()
            continue
        print(json.dumps(answer), flush=True)
    return 0


def oneshot(kind: str, listed: set[str] | None, output: str, frame_id: str) -> int:
    chosen = listed is None or frame_id in listed
    answer = misbehave(kind, frame_id, oneshot=True) if chosen else {"detections": [box(frame_id)]}
    with open(output, "w") as handle:
        if chosen and kind == "garbage":
            handle.write("this is not json")
        elif chosen and kind == "huge":
            handle.write("x" * (64 << 20))
        else:
            json.dump(answer, handle)
    return 0


def main(argv: list[str]) -> int:
    kind = argv.pop(0)
    if kind not in KINDS:
        raise SystemExit(f"unknown kind {kind!r}; one of {', '.join(KINDS)}")
    listed = None
    if "--tag" in argv:  # ignored: makes the command line findable in /proc by whoever started it
        i = argv.index("--tag")
        del argv[i:i + 2]
    if "--on" in argv:
        i = argv.index("--on")
        listed = set(argv[i + 1].split(","))
        del argv[i:i + 2]
    if argv[:1] == ["--oneshot"]:
        return oneshot(kind, listed, argv[2], argv[3])
    return serve(kind, listed)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
