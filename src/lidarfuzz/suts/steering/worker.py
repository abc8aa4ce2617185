"""A steering program in any language, over the worker protocol (``worker:COMMAND``).

The program is started once and serves frames over its standard streams, as a LiDAR
detection worker does (:mod:`lidarfuzz.suts.external`; the process handling — start, answer
timeout, kill and restart, stderr kept for the failure's detail — is that module's
:class:`~lidarfuzz.suts.external.WorkerSut`). For each frame lidarfuzz writes the image to a
temporary file and one line of JSON to the program's stdin::

    {"frame_id": "000042", "image": "/tmp/…/000042.png", "format": "png",
     "height": 480, "width": 640, "channels": "rgb"}

``format`` is ``png`` (an ordinary 8-bit PNG; decoders return it in their own channel order,
OpenCV's ``imread`` BGR) or, with ``image_format="raw"``, ``raw``: ``height × width × 3``
bytes, RGB, row after row (``numpy.fromfile(path, numpy.uint8).reshape(height, width, 3)``).
The request also carries an ``"id"`` (the frame id and a sequence number) that the answer
echoes: ``{"id": "000042#7", "steering": 0.05}`` or ``{"id": …, "error": "message"}``. An empty
line (or end of input) asks it to exit.

Failures: a program that exits is a ``crash`` (restarted for the next frame); one that does
not answer within ``timeout`` seconds is killed (``timeout``, restarted next time); an answer
line that is not JSON or does not echo the request's id is an ``invalid_output`` (restarted:
it may be another frame's answer); an answer with no numeric ``steering`` is one too, and so is a number
that :meth:`~lidarfuzz.suts.steering.base.SteeringSystem.validate` rejects (NaN, infinite,
outside ``steering_range``) when the call is guarded.

Example program: ``examples/suts/steering_worker.py``.
"""

from __future__ import annotations

import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Literal

import cv2

from lidarfuzz.scene.image import ImageSample
from lidarfuzz.suts.base import FailureKind
from lidarfuzz.suts.code import program_code
from lidarfuzz.suts.errors import SutError
from lidarfuzz.suts.external import WorkerSut
from lidarfuzz.suts.processes import MAX_ANSWER_BYTES, MEMORY_LIMIT
from lidarfuzz.suts.steering.base import Steering, SteeringSystem, checked_range

ImageFormat = Literal["png", "raw"]


class WorkerSteering(SteeringSystem):
    """A long-lived program answering a steering angle per frame (see the module docstring).

    Args:
        command: The command line (no placeholders).
        name: Report name (default: the program's file name).
        version: Its version.
        timeout: Seconds per frame.
        image_format: ``png`` or ``raw``.
        steering_range: (low, high) of a valid answer (default ±π/2).
        cwd: Working directory.
        memory_limit, cpu_limit, max_answer_bytes: The program's limits, as for a detection
            worker (:class:`~lidarfuzz.suts.external.WorkerSut`).
    """

    def __init__(self, command: str, *, name: str | None = None, version: str = "0", timeout: float = 60.0,
                 image_format: ImageFormat = "png", steering_range: Sequence[float] | None = None,
                 cwd: str | None = None, memory_limit: int | str | None = MEMORY_LIMIT, cpu_limit: float | None = None,
                 max_answer_bytes: int | str = MAX_ANSWER_BYTES) -> None:
        if image_format not in ("png", "raw"):
            raise ValueError(f"image_format must be 'png' or 'raw', got {image_format!r}")
        self.worker = WorkerSut(command, name=name, version=version, timeout=timeout, cwd=cwd,
                                memory_limit=memory_limit, cpu_limit=cpu_limit, max_answer_bytes=max_answer_bytes)
        self.name = self.worker.name  # type: ignore[misc]
        self.version = version  # type: ignore[misc]
        self.image_format = image_format
        self.steering_range = checked_range(steering_range)  # type: ignore[misc]
        self._tmp: tempfile.TemporaryDirectory[str] | None = None

    def config(self) -> dict[str, Any]:
        return {"command": self.worker.command, "image_format": self.image_format,
                "steering_range": list(self.steering_range)}

    def code(self) -> dict[str, str]:
        """The adapter's Python code, the program's executable and every file its arguments name."""
        return {**super().code(), **program_code(self.worker.argv, self.worker.cwd)}

    @property
    def timeout(self) -> float:
        """Seconds the program may take per frame."""
        return self.worker.timeout

    @property
    def restarts(self) -> int:
        """How often the program was killed or found dead (and restarted on the next frame)."""
        return self.worker.restarts

    def load(self) -> None:
        self.worker.load()
        if self._tmp is None:
            self._tmp = tempfile.TemporaryDirectory(prefix="lidarfuzz-steering-")

    def close(self) -> None:
        self.worker.close()
        if self._tmp is not None:
            self._tmp.cleanup()
            self._tmp = None

    def frame_request(self, sample: ImageSample) -> dict[str, Any]:
        """Write the frame's image and return the request line's JSON for it."""
        self.load()
        assert self._tmp is not None
        stem = "".join(c if c.isalnum() or c in "-_." else "_" for c in sample.frame_id) or "frame"
        path = Path(self._tmp.name) / f"{stem}.{self.image_format}"
        if self.image_format == "png":
            if not cv2.imwrite(str(path), cv2.cvtColor(sample.image, cv2.COLOR_RGB2BGR)):
                raise SutError(FailureKind.CRASH, f"could not write {path} for the worker")
        else:
            path.write_bytes(sample.image.tobytes())
        height, width = sample.shape
        return {"frame_id": sample.frame_id, "image": str(path), "format": self.image_format,
                "height": height, "width": width, "channels": "rgb"}

    def detect(self, sample: ImageSample) -> Steering:
        answer = self.worker.exchange(self.frame_request(sample))
        return Steering.from_dict(answer, f"{self.name} answer")
