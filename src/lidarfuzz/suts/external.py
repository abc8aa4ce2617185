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
than ``timeout`` a ``timeout``.

**Worker** (``worker:COMMAND``): the program is started once and serves frames over its
standard streams. For each frame lidarfuzz writes one line of JSON to its stdin,
``{"frame_id": "000042", "points": "/tmp/…/000042.bin", "format": "bin", "channels":
["x", "y", "z", "intensity"], "calib": "/tmp/…/000042.txt"}``, and reads one line from its
stdout: the same JSON as the one-shot output file, ``{"kitti": ["Car 0 0 …", …]}``, or
``{"error": "message"}``. An empty line (or end of input) asks it to exit. A worker that
exits is a ``crash``; one that does not answer within ``timeout`` is killed (``timeout``)
and restarted for the next frame.

**Worker for a system that consumes logs in order** (a sequence system,
:mod:`lidarfuzz.suts.sequence`): the same program and requests, with two additions. Before
each log lidarfuzz writes ``{"reset": true}``; the program clears its state (speed, histories,
filters) and answers ``{"ok": true}``. Each frame request also carries ``"index"``, the frame's
position in the log, ``"timestamp"`` (seconds or null) and the frame's ``"metadata"`` (e.g. a
``goal_direction``), and the answer is a decision — ``{"steering": 0.05, "speed": 7.5,
"emergency_stop": false}``, optionally with ``"obstacles"`` (a ``detections`` list as above)
and ``"path"`` (``[[x, y], ...]``) — or ``{"error": "message"}``. A detection worker never
receives a reset, so existing programs are unaffected.

Both are fingerprinted by their code too: the program's executable (a command name resolved
on ``PATH``) and every file an argument names, such as the script of ``python3 detector.py``
(:func:`lidarfuzz.suts.code.program_code`).
"""

from __future__ import annotations

import contextlib
import json
import queue
import shlex
import subprocess
import tempfile
import threading
from collections import deque
from pathlib import Path
from typing import IO, Any, Literal

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

PointsFormat = Literal["bin", "pcd"]


def _write_inputs(scene: Scene, folder: Path, points_format: PointsFormat) -> tuple[Path, Path]:
    stem = scene.frame_id or "frame"
    points = write_frame(folder / f"{stem}.{points_format}", scene, overwrite=True)
    calib = folder / f"{stem}.calib.txt"
    calib.write_text((scene.calib or KittiCalibration.default()).to_text())
    return points, calib


def parse_response(data: Any, calib: KittiCalibration | None, where: str) -> Boxes3D:
    """Detections from the protocol's JSON answer (see the module docstring)."""
    if not isinstance(data, dict):
        raise SutError(FailureKind.INVALID_OUTPUT, f"{where}: expected a JSON object, got {type(data).__name__}")
    if "error" in data:
        raise SutError(FailureKind.CRASH, f"{where}: the system reported an error: {data['error']}")
    if "kitti" in data:
        lines = data["kitti"]
        if not isinstance(lines, list):
            raise SutError(FailureKind.INVALID_OUTPUT, f"{where}: 'kitti' must be a list of label lines")
        return _parse_kitti("\n".join(map(str, lines)), calib, where)
    if "detections" not in data or not isinstance(data["detections"], list):
        raise SutError(FailureKind.INVALID_OUTPUT, f"{where}: expected a 'detections' list, 'kitti' lines or 'error'")
    convention = data.get("convention", "lidarfuzz")
    if convention not in CONVENTIONS:
        raise SutError(FailureKind.INVALID_OUTPUT, f"{where}: unknown convention {convention!r}")
    rows = data["detections"]
    try:
        boxes = np.array([[float(v) for v in row["box"]] for row in rows], dtype=np.float64).reshape(-1, 7)
        labels = [str(row["label"]) for row in rows]
        scores = [float(row["score"]) for row in rows]
    except (KeyError, TypeError, ValueError) as exc:
        message = f"{where}: each detection needs 'label', 'box' (7 numbers) and 'score' ({exc})"
        raise SutError(FailureKind.INVALID_OUTPUT, message) from None
    return detections(boxes, labels, scores, convention)


def _parse_kitti(text: str, calib: KittiCalibration | None, where: str) -> Boxes3D:
    try:
        return parse_labels(text, calib or KittiCalibration.default(), where)
    except DataFormatError as exc:
        raise SutError(FailureKind.INVALID_OUTPUT, str(exc)) from None


def _tail(text: str | bytes | None, limit: int = 2000) -> str:
    if text is None:
        return ""
    if isinstance(text, bytes):
        text = text.decode("utf-8", "replace")
    return text[-limit:]


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

    def config(self) -> dict[str, Any]:
        return {"command": self.command, "points_format": self.points_format, "output_format": self.output_format}

    def code(self) -> dict[str, str]:
        """The adapter's Python code, the program's executable and every file its arguments name."""
        return {**super().code(), **program_code(self.argv, self.cwd)}

    def detect(self, sample: Scene) -> Boxes3D:
        with tempfile.TemporaryDirectory(prefix="lidarfuzz-sut-") as tmp:
            folder = Path(tmp)
            points, calib = _write_inputs(sample, folder, self.points_format)
            output = folder / ("detections.json" if self.output_format == "json" else "detections.txt")
            values = {"points": str(points), "calib": str(calib), "output": str(output), "frame_id": sample.frame_id}
            argv = [a.format(**values) for a in self.argv]
            try:
                done = subprocess.run(argv, capture_output=True, timeout=self.timeout, cwd=self.cwd, check=False)
            except subprocess.TimeoutExpired as exc:
                raise SutError(FailureKind.TIMEOUT, f"no answer within {self.timeout:g} s", _tail(exc.stderr)) from None
            except OSError as exc:
                raise SutError(FailureKind.CRASH, f"could not start {self.argv[0]!r}: {exc}") from None
            if done.returncode != 0:
                how = f"killed by signal {-done.returncode}" if done.returncode < 0 else f"exit code {done.returncode}"
                raise SutError(FailureKind.CRASH, f"{self.name}: {how}", _tail(done.stderr))
            if not output.exists():
                raise SutError(FailureKind.INVALID_OUTPUT, f"{self.name} wrote no {output.name}", _tail(done.stderr))
            text = output.read_text(encoding="utf-8", errors="replace")
            frame_calib = sample.calib or KittiCalibration.default()
            if self.output_format == "kitti":
                return _parse_kitti(text, frame_calib, f"{self.name} output")
            try:
                data = json.loads(text)
            except json.JSONDecodeError as exc:
                raise SutError(FailureKind.INVALID_OUTPUT, f"{self.name} output is not JSON: {exc}") from None
            return parse_response(data, frame_calib, f"{self.name} output")


class WorkerSut(SystemUnderTest[Scene, Boxes3D]):
    """A long-lived program serving frames over stdin/stdout (see the module docstring).

    Args:
        command: The command line (no placeholders).
        name: Report name (default: the program's file name).
        version: Its version.
        timeout: Seconds per frame.
        points_format: ``bin`` or ``pcd``.
        cwd: Working directory.
    """

    def __init__(
        self,
        command: str,
        *,
        name: str | None = None,
        version: str = "0",
        timeout: float = 60.0,
        points_format: PointsFormat = "bin",
        cwd: str | None = None,
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
        self._process: subprocess.Popen[str] | None = None
        self._lines: queue.Queue[str | None] = queue.Queue()
        self._stderr: deque[str] = deque(maxlen=50)
        self._tmp: tempfile.TemporaryDirectory[str] | None = None
        self.restarts = 0

    def config(self) -> dict[str, Any]:
        return {"command": self.command, "points_format": self.points_format}

    def code(self) -> dict[str, str]:
        """The adapter's Python code, the program's executable and every file its arguments name."""
        return {**super().code(), **program_code(self.argv, self.cwd)}

    @staticmethod
    def _pump(stream: IO[str], sink: Any, end: bool) -> None:
        for line in stream:
            sink(line)
        if end:
            sink(None)

    def load(self) -> None:
        if self._process is not None and self._process.poll() is None:
            return
        try:
            self._process = subprocess.Popen(
                self.argv, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                text=True, bufsize=1, cwd=self.cwd,
            )
        except OSError as exc:
            raise SutError(FailureKind.CRASH, f"could not start {self.argv[0]!r}: {exc}") from None
        self._lines = queue.Queue()
        self._stderr.clear()
        assert self._process.stdout is not None and self._process.stderr is not None
        pumps = ((self._process.stdout, self._lines.put, True), (self._process.stderr, self._stderr.append, False))
        for stream, sink, end in pumps:
            threading.Thread(target=self._pump, args=(stream, sink, end), daemon=True).start()
        if self._tmp is None:
            self._tmp = tempfile.TemporaryDirectory(prefix="lidarfuzz-worker-")

    def _stop(self, restart: bool) -> None:
        if self._process is not None:
            self._process.kill()
            self._process.wait()
        self._process = None
        if restart:
            self.restarts += 1

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
            raise SutError(FailureKind.CRASH, f"{self.name}: the reset failed: {answer['error']}")
        if answer != {"ok": True}:
            text = json.dumps(answer)[:200]
            expected = '{"ok": true}'
            raise SutError(FailureKind.INVALID_OUTPUT, f"{self.name} answered {text} to a reset; expected {expected}")

    def exchange(self, request: dict[str, Any]) -> Any:
        """Send one request line and return the program's answer line, parsed as JSON.

        Raises:
            SutError: ``crash`` when the program exited (it is restarted on the next request),
                ``timeout`` when it did not answer within ``timeout`` (killed, restarted next time),
                ``invalid_output`` when the answer is not JSON.
        """
        self.load()
        assert self._process is not None and self._process.stdin is not None
        try:
            self._process.stdin.write(json.dumps(request) + "\n")
            self._process.stdin.flush()
        except (BrokenPipeError, OSError):
            code = self._process.wait()
            self._stop(restart=True)
            raise SutError(FailureKind.CRASH, f"{self.name} exited (code {code})", "".join(self._stderr)) from None
        try:
            line = self._lines.get(timeout=self.timeout)
        except queue.Empty:
            self._stop(restart=True)
            raise SutError(FailureKind.TIMEOUT, f"no answer within {self.timeout:g} s; worker restarted") from None
        if line is None:
            code = self._process.wait()
            self._stop(restart=True)
            how = f"killed by signal {-code}" if code < 0 else f"exit code {code}"
            raise SutError(FailureKind.CRASH, f"{self.name} exited ({how}); restarted", "".join(self._stderr))
        try:
            return json.loads(line)
        except json.JSONDecodeError as exc:
            raise SutError(FailureKind.INVALID_OUTPUT, f"{self.name} answered a line that is not JSON: {exc}") from None

    def detect(self, sample: Scene) -> Boxes3D:
        data = self.exchange(self.frame_request(sample))
        return parse_response(data, sample.calib or KittiCalibration.default(), f"{self.name} answer")

    def close(self) -> None:
        if self._process is not None and self._process.poll() is None:
            assert self._process.stdin is not None
            with contextlib.suppress(BrokenPipeError, OSError):
                self._process.stdin.write("\n")
                self._process.stdin.flush()
            try:
                self._process.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self._process.kill()
                self._process.wait()
        self._process = None
        if self._tmp is not None:
            self._tmp.cleanup()
            self._tmp = None
