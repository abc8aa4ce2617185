"""Data sets rendered by the simulator in the background ("generate from the simulator").

A job renders with :func:`lidarfuzz.sim.dataset.generate_dataset` — the code of ``lidarfuzz
gen`` — into ``<workspace>/uploads/<id>/`` and, when it is done, records the data set with
:func:`lidarfuzz.store.inventory.add_dataset`, as ``lidarfuzz datasets add`` does. Until then
the data sets list shows it as ``generating`` (with frames done / total), or ``failed`` with
the reason; jobs live in the server's memory (a failed one is dismissed by deleting it).
"""

from __future__ import annotations

import logging
import threading
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

log = logging.getLogger("lidarfuzz.web")


@dataclass
class GenerationJob:
    """One data set being rendered."""

    name: str
    frames: int
    seed: int
    kind: str | None
    sensor: str | None
    path: Path
    scenes: str = "independent"  # or "sequence" (one scene driven through: a log), "drive" (a stop and a turn)
    camera: tuple[int, int] | None = None  # (width, height): camera 2's images too, registered as a camera data set
    status: str = "generating"
    done: int = 0
    error: str = ""
    started: float = field(default_factory=time.time)

    def as_dict(self) -> dict[str, Any]:
        from datetime import UTC, datetime

        return {"name": self.name, "status": self.status, "frame_count": self.frames, "done": self.done,
                "total": self.frames, "format": "kitti", "path": str(self.path), "error": self.error,
                "notes": f"simulator: {self.frames} frame(s), seed {self.seed}, "
                         + (f"{self.kind or 'mixed'} scenes" if self.scenes == "independent" else
                            f"a {'drive log' if self.scenes == 'drive' else 'sequence'} ({self.kind or 'any'} "
                            "scene)")
                         + (f", camera images {self.camera[0]}x{self.camera[1]} with steering labels"
                            if self.camera else ""),
                "modality": "camera" if self.camera else "lidar",
                "added_at": datetime.fromtimestamp(self.started, UTC).isoformat(), "uploaded": True}


class GenerationJobs:
    """The generation jobs of one app."""

    def __init__(self, store: Any, uploads: Path, processes: int | None) -> None:
        self.store, self.uploads, self.processes = store, uploads, processes
        self._jobs: dict[str, GenerationJob] = {}
        self._threads: list[threading.Thread] = []
        self._lock = threading.Lock()

    def jobs(self) -> list[GenerationJob]:
        with self._lock:
            return list(self._jobs.values())

    def get(self, name: str) -> GenerationJob | None:
        with self._lock:
            return self._jobs.get(name)

    def start(self, name: str, frames: int, seed: int, kind: str | None, sensor: str | None = None,
              scenes: str = "independent", camera: tuple[int, int] | None = None) -> GenerationJob:
        """Start rendering; the caller has checked that ``name`` is free and the config valid.
        ``camera``: also render camera 2's images at (width, height) and record the data set as a
        camera one (its images and steering labels)."""
        path = self.uploads / uuid.uuid4().hex
        job = GenerationJob(name, frames, seed, kind, sensor, path, scenes, camera)
        with self._lock:
            self._jobs[name] = job
        thread = threading.Thread(target=self._run, args=(job,), name=f"lidarfuzz-gen-{name}", daemon=True)
        self._threads.append(thread)
        thread.start()
        return job

    def dismiss(self, name: str) -> GenerationJob | None:
        """Forget a finished (failed) job; a running one stays."""
        with self._lock:
            job = self._jobs.get(name)
            if job is not None and job.status != "generating":
                del self._jobs[name]
            return job

    def _run(self, job: GenerationJob) -> None:
        from lidarfuzz.io.options import DatasetOptions
        from lidarfuzz.sim.dataset import GenerationConfig, generate_dataset
        from lidarfuzz.store.inventory import add_dataset

        def advance(_result: Any) -> None:
            job.done += 1

        try:
            config = GenerationConfig(frames=job.frames, seed=job.seed, kind=job.kind, sensor=job.sensor,
                                      sequence=job.scenes != "independent", drive=job.scenes == "drive",
                                      camera=job.camera)
            generate_dataset(job.path, config, workers=self.processes, on_frame=advance)
            options = DatasetOptions(modality="camera") if job.camera else None
            add_dataset(self.store, job.name, job.path, notes=job.as_dict()["notes"], options=options)
        except Exception as exc:  # shown in the list: the user sees why
            log.exception("generating data set %s failed", job.name)
            job.status, job.error = "failed", f"{type(exc).__name__}: {exc}"
            return
        with self._lock:
            self._jobs.pop(job.name, None)

    def close(self, timeout: float = 5.0) -> None:
        for thread in self._threads:
            thread.join(timeout)


def jobs_of(context: Any) -> GenerationJobs:
    """The :class:`GenerationJobs` of an app's context (made on first use)."""
    jobs = context.extras.get("generation")
    if jobs is None:
        jobs = context.extras.setdefault("generation", GenerationJobs(context.store, context.uploads,
                                                                      context.processes))
    return jobs  # type: ignore[no-any-return]


__all__ = ["GenerationJob", "GenerationJobs", "jobs_of"]
