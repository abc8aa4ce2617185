"""Systems under test in another process, in any language: a documented file + line protocol.

**One-shot** (``subprocess:COMMAND``): for every sample lidarfuzz writes the points to a
temporary file and runs ``COMMAND`` with these placeholders replaced (shell-style quoting
applies; the command is not run through a shell):

* ``{points}`` — the cloud: KITTI ``.bin`` (float32 x, y, z, intensity) or, with
  ``points_format="pcd"``, a binary PCD with every channel;
* ``{calib}`` — the frame's KITTI calibration file (a default rig when the frame has none);
* ``{output}`` — where the program writes its detections;
* ``{frame_id}`` — the frame's id.

The output file holds either JSON — ``{"detections": [{"label": "Car", "box": [x, y, z, l,
w, h, yaw], "score": 0.9}, ...]}`` in the LiDAR frame (``"convention"`` may name another
box convention, see :mod:`lidarfuzz.suts.conventions`) — or, with ``output_format="kitti"``,
KITTI label lines with the score as 16th column (camera frame, converted with ``{calib}``).
A non-zero exit or death by a signal is a ``crash`` (with the tail of stderr), a run longer
than ``timeout`` a ``timeout``. The program's exit ends the frame: children it leaves behind
(holding its pipes or not) are killed with it.

**Worker** (``worker:COMMAND``): the program is started once and serves frames over its
standard streams. For each frame lidarfuzz writes one line of JSON to its stdin,
``{"id": "000042#7", "frame_id": "000042", "points": "/tmp/…/000042.bin", "format": "bin",
"channels": ["x", "y", "z", "intensity"], "calib": "/tmp/…/000042.txt"}``, and reads one line
from its stdout: the same JSON as the one-shot output file, ``{"kitti": ["Car 0 0 …", …]}``,
or ``{"error": "message"}`` — each **echoing the request's** ``"id"``. The id (the frame id and
a sequence number) frames the exchange: an answer line that is not JSON, is too long, has no
``"id"`` or another request's id (a stray line on stdout, a late answer) is the frame's
``invalid_output`` and the program is restarted, so that no later frame is given another
frame's answer. An empty line (or end of input) asks it to exit. A worker that exits is a
``crash``; one that does not answer within ``timeout`` is killed (``timeout``) and restarted
for the next frame.

**Worker for a system that consumes logs in order** (a sequence system,
:mod:`lidarfuzz.suts.sequence`): the same program and requests, with two additions. Before
each log lidarfuzz writes ``{"reset": true, "id": …}``; the program clears its state (speed,
histories, filters) and answers ``{"ok": true, "id": …}``. Each frame request also carries
``"index"``, the frame's position in the log, ``"timestamp"`` (seconds or null) and the frame's
``"metadata"`` (e.g. a ``goal_direction``), and the answer is a decision — ``{"steering": 0.05,
"speed": 7.5, "emergency_stop": false}``, optionally with ``"obstacles"`` (a ``detections`` list
as above) and ``"path"`` (``[[x, y], ...]``) — or ``{"error": "message"}``. A detection worker
never receives a reset, so existing programs are unaffected.

Every program runs fenced (:mod:`lidarfuzz.suts.processes`): in a session of its own, under
``memory_limit`` (default 8 GiB of address space) and ``cpu_limit`` (default none); an answer
longer than ``max_answer_bytes`` (4 MiB) or holding more than ``max_boxes`` (10,000)
detections is an ``invalid_output``; every process of its group is killed on a timeout, a
restart and at the end.

Both are fingerprinted by their code too: the program's executable (a command name resolved
on ``PATH``) and every file an argument names, such as the script of ``python3 detector.py``
(:func:`lidarfuzz.suts.code.program_code`).
"""

from __future__ import annotations

import contextlib
import json
import os
import selectors
import shlex
import subprocess
import tempfile
import time
from pathlib import Path
from typing import Any, Literal

import numpy as np

from lidarfuzz.errors import DataFormatError
from lidarfuzz.io.frames import write_frame
from lidarfuzz.io.kitti.labels import parse_labels
from lidarfuzz.scene.boxes import Boxes3D
from lidarfuzz.scene.calib import KittiCalibration
from lidarfuzz.scene.scene import Scene
from lidarfuzz.suts.base import FailureKind, SystemUnderTest
from lidarfuzz.suts.code import program_code
from lidarfuzz.suts.conventions import CONVENTIONS, detections
from lidarfuzz.suts.errors import SutError
from lidarfuzz.suts.processes import (
    MAX_ANSWER_BYTES,
    MAX_BOXES,
    MEMORY_LIMIT,
    Limits,
    StreamTail,
    death,
    format_size,
    kill_group,
    start,
)

PointsFormat = Literal["bin", "pcd"]

#: How the protocol asks a worker to echo a request's id (in invalid_output messages).
ECHO_ID = 'every answer must echo the request\'s "id" field (worker protocol, docs/suts.md)'


def _write_inputs(scene: Scene, folder: Path, points_format: PointsFormat) -> tuple[Path, Path]:
    stem = scene.frame_id or "frame"
    points = write_frame(folder / f"{stem}.{points_format}", scene, overwrite=True)
    calib = folder / f"{stem}.calib.txt"
    calib.write_text((scene.calib or KittiCalibration.default()).to_text())
    return points, calib


def parse_response(data: Any, calib: KittiCalibration | None, where: str, *, max_boxes: int = MAX_BOXES) -> Boxes3D:
    """Detections from the protocol's JSON answer (see the module docstring); more than
    ``max_boxes`` of them are an ``invalid_output``, refused before any array is built."""
    if not isinstance(data, dict):
        raise SutError(FailureKind.INVALID_OUTPUT, f"{where}: expected a JSON object, got {type(data).__name__}")
    if "error" in data:
        raise SutError(FailureKind.CRASH, f"{where}: the system reported an error: {str(data['error'])[:500]}")
    if "kitti" in data:
        lines = data["kitti"]
        if not isinstance(lines, list):
            raise SutError(FailureKind.INVALID_OUTPUT, f"{where}: 'kitti' must be a list of label lines")
        _check_count(len(lines), max_boxes, where)
        return _parse_kitti("\n".join(map(str, lines)), calib, where)
    if "detections" not in data or not isinstance(data["detections"], list):
        raise SutError(FailureKind.INVALID_OUTPUT, f"{where}: expected a 'detections' list, 'kitti' lines or 'error'")
    convention = data.get("convention", "lidarfuzz")
    if not isinstance(convention, str) or convention not in CONVENTIONS:
        raise SutError(FailureKind.INVALID_OUTPUT, f"{where}: unknown convention {str(convention)[:100]!r}")
    rows = data["detections"]
    _check_count(len(rows), max_boxes, where)
    try:
        boxes = np.array([[float(v) for v in row["box"]] for row in rows], dtype=np.float64).reshape(-1, 7)
        labels = [str(row["label"]) for row in rows]
        scores = [float(row["score"]) for row in rows]
    except (KeyError, TypeError, ValueError, OverflowError) as exc:
        message = f"{where}: each detection needs 'label', 'box' (7 numbers) and 'score' ({str(exc)[:200]})"
        raise SutError(FailureKind.INVALID_OUTPUT, message) from None
    try:
        return detections(boxes, labels, scores, convention)  # type: ignore[arg-type]  # checked above
    except (ValueError, TypeError) as exc:  # e.g. a negative size
        raise SutError(FailureKind.INVALID_OUTPUT, f"{where}: {str(exc)[:300]}") from None


def _check_count(count: int, max_boxes: int, where: str) -> None:
    if count > max_boxes:
        raise SutError(FailureKind.INVALID_OUTPUT,
                       f"{where}: {count} detections, more than max_boxes={max_boxes} (a SUT option)")


def _parse_kitti(text: str, calib: KittiCalibration | None, where: str) -> Boxes3D:
    try:
        return parse_labels(text, calib or KittiCalibration.default(), where)
    except DataFormatError as exc:
        raise SutError(FailureKind.INVALID_OUTPUT, str(exc)) from None


class SubprocessSut(SystemUnderTest[Scene, Boxes3D]):
    """A program run once per frame (see the module docstring for the protocol).

    Args:
        command: The command line with ``{points}``, ``{output}`` (required), ``{calib}``
            and ``{frame_id}`` placeholders.
        name: Report name (default: the program's file name).
        version: Its version (part of the fingerprint).
        timeout: Seconds per frame.
        points_format: ``bin`` or ``pcd``.
        output_format: ``json`` or ``kitti``.
        cwd: Working directory of the program.
        memory_limit: Address space per process (bytes or a size such as ``"2GiB"``; default
            8 GiB; 0 or None: unlimited).
        cpu_limit: CPU seconds per run (default: none).
        max_answer_bytes: Largest output file read (default 4 MiB).
        max_boxes: Most detections accepted per frame (default 10,000).
    """

    def __init__(
        self,
        command: str,
        *,
        name: str | None = None,
        version: str = "0",
        timeout: float = 60.0,
        points_format: PointsFormat = "bin",
        output_format: Literal["json", "kitti"] = "json",
        cwd: str | None = None,
        memory_limit: int | str | None = MEMORY_LIMIT,
        cpu_limit: float | None = None,
        max_answer_bytes: int | str = MAX_ANSWER_BYTES,
        max_boxes: int = MAX_BOXES,
    ) -> None:
        self.argv = shlex.split(command)
        if not self.argv:
            raise ValueError("subprocess SUT: empty command")
        if not any("{points}" in a for a in self.argv) or not any("{output}" in a for a in self.argv):
            raise ValueError(f"subprocess SUT: the command needs {{points}} and {{output}} placeholders: {command!r}")
        self.command = command
        self.name = name or Path(self.argv[0]).name  # type: ignore[misc]
        self.version = version  # type: ignore[misc]
        self.timeout = timeout
        self.points_format = points_format
        self.output_format = output_format
        self.cwd = cwd
        self.limits = Limits.of(memory_limit, cpu_limit, max_answer_bytes, max_boxes)
        self.max_boxes = self.limits.boxes

    def config(self) -> dict[str, Any]:
        return {"command": self.command, "points_format": self.points_format, "output_format": self.output_format}

    def code(self) -> dict[str, str]:
        """The adapter's Python code, the program's executable and every file its arguments name."""
        return {**super().code(), **program_code(self.argv, self.cwd)}

    def _run(self, argv: list[str]) -> tuple[int, str]:
        """Run the program to its exit (its exit code and stderr's tail); its group is killed after."""
        try:
            process = start(argv, self.limits, cwd=self.cwd, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE)
        except (OSError, subprocess.SubprocessError) as exc:
            raise SutError(FailureKind.CRASH, f"could not start {self.argv[0]!r}: {exc}") from None
        assert process.stderr is not None
        tail = StreamTail(process.stderr)
        try:
            code = process.wait(timeout=self.timeout)
        except subprocess.TimeoutExpired:
            kill_group(process)
            raise SutError(FailureKind.TIMEOUT, f"no answer within {self.timeout:g} s", tail.text(0.5)) from None
        kill_group(process)  # children it left behind: the frame is over
        return code, tail.text(0.5)

    def detect(self, sample: Scene) -> Boxes3D:
        with tempfile.TemporaryDirectory(prefix="lidarfuzz-sut-") as tmp:
            folder = Path(tmp)
            points, calib = _write_inputs(sample, folder, self.points_format)
            output = folder / ("detections.json" if self.output_format == "json" else "detections.txt")
            values = {"points": str(points), "calib": str(calib), "output": str(output), "frame_id": sample.frame_id}
            code, stderr = self._run([a.format(**values) for a in self.argv])
            if code != 0:
                message, timed_out = death(self.name, code, stderr, self.limits)
                raise SutError(FailureKind.TIMEOUT if timed_out else FailureKind.CRASH, message, stderr)
            if not output.is_file():
                raise SutError(FailureKind.INVALID_OUTPUT, f"{self.name} wrote no {output.name}", stderr)
            size = output.stat().st_size
            if size > self.limits.answer_bytes:
                raise SutError(FailureKind.INVALID_OUTPUT, f"{self.name} wrote {format_size(size)} to {output.name}, "
                               f"more than max_answer_bytes ({format_size(self.limits.answer_bytes)})")
            text = output.read_text(encoding="utf-8", errors="replace")
            frame_calib = sample.calib or KittiCalibration.default()
            where = f"{self.name} output"
            if self.output_format == "kitti":
                _check_count(sum(1 for line in text.splitlines() if line.strip()), self.limits.boxes, where)
                return _parse_kitti(text, frame_calib, where)
            try:
                data = json.loads(text)
            except (ValueError, RecursionError) as exc:
                raise SutError(FailureKind.INVALID_OUTPUT, f"{where} is not JSON: {str(exc)[:200]}") from None
            return parse_response(data, frame_calib, where, max_boxes=self.limits.boxes)


class WorkerSut(SystemUnderTest[Scene, Boxes3D]):
    """A long-lived program serving frames over stdin/stdout (see the module docstring).

    Args:
        command: The command line (no placeholders).
        name: Report name (default: the program's file name).
        version: Its version.
        timeout: Seconds per frame.
        points_format: ``bin`` or ``pcd``.
        cwd: Working directory.
        memory_limit: Address space per process (bytes or a size such as ``"2GiB"``; default
            8 GiB; 0 or None: unlimited).
        cpu_limit: CPU seconds over the program's life (default: none; past it the kernel
            stops it, a ``timeout``, and it is restarted).
        max_answer_bytes: Longest answer line read (default 4 MiB).
        max_boxes: Most detections accepted per frame (default 10,000).

    Attributes:
        restarts: How often the program was killed or found dead (restarted on the next request).
        close_grace: Seconds :meth:`close` lets the program exit after the empty line.
    """

    close_grace = 5.0

    def __init__(
        self,
        command: str,
        *,
        name: str | None = None,
        version: str = "0",
        timeout: float = 60.0,
        points_format: PointsFormat = "bin",
        cwd: str | None = None,
        memory_limit: int | str | None = MEMORY_LIMIT,
        cpu_limit: float | None = None,
        max_answer_bytes: int | str = MAX_ANSWER_BYTES,
        max_boxes: int = MAX_BOXES,
    ) -> None:
        self.argv = shlex.split(command)
        if not self.argv:
            raise ValueError("worker SUT: empty command")
        self.command = command
        self.name = name or Path(self.argv[0]).name  # type: ignore[misc]
        self.version = version  # type: ignore[misc]
        self.timeout = timeout
        self.points_format = points_format
        self.cwd = cwd
        self.limits = Limits.of(memory_limit, cpu_limit, max_answer_bytes, max_boxes)
        self.max_boxes = self.limits.boxes
        self._process: subprocess.Popen[bytes] | None = None
        self._selector: selectors.BaseSelector | None = None
        self._buffer = bytearray()
        self._stderr: StreamTail | None = None
        self._tmp: tempfile.TemporaryDirectory[str] | None = None
        self._sequence = 0
        self.restarts = 0

    def config(self) -> dict[str, Any]:
        return {"command": self.command, "points_format": self.points_format}

    def code(self) -> dict[str, str]:
        """The adapter's Python code, the program's executable and every file its arguments name."""
        return {**super().code(), **program_code(self.argv, self.cwd)}

    def load(self) -> None:
        if self._process is not None and self._process.poll() is None:
            return
        self._stop(restart=False)
        try:
            process = start(self.argv, self.limits, cwd=self.cwd, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE)
        except (OSError, subprocess.SubprocessError) as exc:
            raise SutError(FailureKind.CRASH, f"could not start {self.argv[0]!r}: {exc}") from None
        assert process.stdin is not None and process.stdout is not None and process.stderr is not None
        os.set_blocking(process.stdin.fileno(), False)  # a program that stops reading cannot block lidarfuzz
        self._process = process
        self._selector = selectors.DefaultSelector()
        self._selector.register(process.stdout.fileno(), selectors.EVENT_READ)
        self._buffer = bytearray()
        self._stderr = StreamTail(process.stderr)
        if self._tmp is None:
            self._tmp = tempfile.TemporaryDirectory(prefix="lidarfuzz-worker-")

    def _stop(self, restart: bool) -> None:
        """Kill the program's whole process group (restarted on the next request when ``restart``)."""
        kill_group(self._process)
        if self._selector is not None:
            self._selector.close()
        self._process, self._selector = None, None
        self._buffer = bytearray()
        if restart:
            self.restarts += 1

    def _stderr_text(self, wait: float = 0.0) -> str:
        return self._stderr.text(wait) if self._stderr is not None else ""

    @property
    def running(self) -> bool:
        """Whether the program is running (it has not exited nor been killed since it started)."""
        return self._process is not None and self._process.poll() is None

    def frame_request(self, sample: Scene) -> dict[str, Any]:
        """Write the frame's input files and return the request line's JSON for it."""
        self.load()
        assert self._tmp is not None
        points, calib = _write_inputs(sample, Path(self._tmp.name), self.points_format)
        return {
            "frame_id": sample.frame_id,
            "points": str(points),
            "format": self.points_format,
            "channels": list(sample.points.channels) if self.points_format == "pcd" else ["x", "y", "z", "intensity"],
            "calib": str(calib),
        }

    def reset_state(self, extra: dict[str, Any] | None = None) -> None:
        """Ask the program to clear its state (``{"reset": true}``, answered ``{"ok": true}``);
        ``extra`` fields go with the request (e.g. ``gcov_dump``).

        Raises:
            SutError: ``crash``, ``timeout`` or ``invalid_output`` as for a frame.
        """
        answer = self.exchange({"reset": True, **(extra or {})})
        if isinstance(answer, dict) and "error" in answer:
            raise SutError(FailureKind.CRASH, f"{self.name}: the reset failed: {str(answer['error'])[:500]}")
        if answer != {"ok": True}:
            text = json.dumps(answer)[:200]
            expected = '{"ok": true}'
            raise SutError(FailureKind.INVALID_OUTPUT, f"{self.name} answered {text} to a reset; expected {expected}")

    def exchange(self, request: dict[str, Any]) -> Any:
        """Send one request line, with its ``"id"``, and return the program's answer line parsed
        as JSON, its ``"id"`` checked and removed.

        Raises:
            SutError: ``crash`` when the program exited, ``timeout`` when it did not answer within
                ``timeout``, ``invalid_output`` when the answer is not JSON, is too long or does
                not echo the request's id — in every case the program is stopped (its whole
                process group) and restarted on the next request.
        """
        self.load()
        self._sequence += 1
        frame = request.get("frame_id")
        ident = f"{frame if frame is not None else ('reset' if request.get('reset') else 'request')}#{self._sequence}"
        deadline = time.monotonic() + self.timeout
        self._send((json.dumps({**request, "id": ident}) + "\n").encode(), deadline)
        line = self._receive(deadline)
        return self._answer(line, ident)

    def _exited(self, what: str) -> SutError:
        """The failure of a program found dead (stopped, restarted next time)."""
        assert self._process is not None
        try:
            code = self._process.wait(timeout=1.0)
        except subprocess.TimeoutExpired:  # closed its stdout but lives on
            self._stop(restart=True)
            return SutError(FailureKind.CRASH, f"{self.name} closed its stdout {what}; restarted",
                            self._stderr_text(0.5))
        self._stop(restart=True)  # first: a child of it may hold its stderr open
        stderr = self._stderr_text(0.5)
        message, timed_out = death(self.name, code, stderr, self.limits)
        return SutError(FailureKind.TIMEOUT if timed_out else FailureKind.CRASH, f"{message} {what}; restarted", stderr)

    def _send(self, data: bytes, deadline: float) -> None:
        assert self._process is not None and self._process.stdin is not None
        fd = self._process.stdin.fileno()
        view = memoryview(data)
        while view:
            try:
                view = view[os.write(fd, view):]
            except BlockingIOError:
                if time.monotonic() >= deadline:
                    self._stop(restart=True)
                    raise SutError(FailureKind.TIMEOUT, f"{self.name} read no request within {self.timeout:g} s; "
                                   "worker restarted") from None
                with selectors.DefaultSelector() as writable:
                    writable.register(fd, selectors.EVENT_WRITE)
                    writable.select(min(0.05, max(0.0, deadline - time.monotonic())))
            except OSError:  # a broken pipe: it is gone
                raise self._exited("before the request") from None

    def _receive(self, deadline: float) -> bytes:
        """One line from the program's stdout, read without ever holding more than
        ``max_answer_bytes`` of it."""
        assert self._process is not None and self._process.stdout is not None and self._selector is not None
        fd = self._process.stdout.fileno()
        limit = self.limits.answer_bytes
        while True:
            end = self._buffer.find(b"\n")
            if end >= 0:
                line = bytes(self._buffer[:end])
                del self._buffer[:end + 1]
                return line
            if len(self._buffer) > limit:
                self._stop(restart=True)
                raise SutError(FailureKind.INVALID_OUTPUT, f"{self.name} answered a line longer than "
                               f"max_answer_bytes ({format_size(limit)}); worker restarted")
            left = deadline - time.monotonic()
            if left <= 0:
                pending = len(self._buffer)
                self._stop(restart=True)
                unfinished = f" ({pending} bytes of an answer without its newline)" if pending else ""
                raise SutError(FailureKind.TIMEOUT,
                               f"no answer within {self.timeout:g} s{unfinished}; worker restarted",
                               self._stderr_text())
            if self._selector.select(min(left, 0.05)):
                chunk = os.read(fd, min(1 << 20, limit + 2 - len(self._buffer)))
                if not chunk:
                    raise self._exited("before answering")
                self._buffer += chunk
            elif self._process.poll() is not None:  # dead, while a child of it may hold its stdout
                raise self._exited("before answering")

    def _answer(self, line: bytes, ident: str) -> Any:
        """The answer line parsed, its id checked; anything else stops the program."""
        problem = None
        data: Any = None
        try:
            data = json.loads(line.decode("utf-8"))
        except (ValueError, RecursionError) as exc:
            problem = f"answered a line that is not JSON ({str(exc)[:200]})"
        if problem is None:
            if not isinstance(data, dict):
                problem = f"answered {type(data).__name__} JSON, not an object"
            elif "id" not in data:
                problem = f"answered without an \"id\" to request {ident!r}: {ECHO_ID}"
            elif data["id"] != ident:
                problem = (f"answered id {str(data['id'])[:100]!r} to request {ident!r} (a stray or late line on "
                           "its stdout)")
        if problem is not None:
            self._stop(restart=True)
            shown = line[:300].decode("utf-8", "replace")
            raise SutError(FailureKind.INVALID_OUTPUT, f"{self.name} {problem}; worker restarted",
                           f"answer line ({len(line)} bytes): {shown}")
        del data["id"]
        return data

    def detect(self, sample: Scene) -> Boxes3D:
        data = self.exchange(self.frame_request(sample))
        return parse_response(data, sample.calib or KittiCalibration.default(), f"{self.name} answer",
                              max_boxes=self.limits.boxes)

    def close(self) -> None:
        process = self._process
        if process is not None and process.poll() is None and process.stdin is not None:
            with contextlib.suppress(OSError):
                os.write(process.stdin.fileno(), b"\n")
            with contextlib.suppress(subprocess.TimeoutExpired):
                process.wait(timeout=self.close_grace)
        self._stop(restart=False)  # its children too, whether it exited or not
        if self._tmp is not None:
            self._tmp.cleanup()
            self._tmp = None
