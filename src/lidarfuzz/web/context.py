"""What every route needs, one per app: :class:`WebContext` (the store, the file folders, the
limits, the task workers, a cache of opened data sets) and :func:`web`, the FastAPI dependency
that hands it to a route. The routes import this module, never :mod:`lidarfuzz.web.app`, which
assembles them.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from fastapi import Request

from lidarfuzz.store.store import Store
from lidarfuzz.web.security import Limits
from lidarfuzz.web.workers import TaskWorkers


def files_root(workspace: str) -> Path:
    """Where the app keeps uploads, reports and caches: the workspace folder, or
    ``./lidarfuzz-web`` next to a database URL."""
    return Path("lidarfuzz-web") if "://" in workspace else Path(workspace)


@dataclass
class WebContext:
    """What every route needs, one per app (``request.app.state.web``)."""

    workspace: str
    store: Store
    files: Path
    limits: Limits
    token: str | None
    workers: TaskWorkers
    processes: int | None
    _datasets: OrderedDict[str, Any] = field(default_factory=OrderedDict)
    _lock: threading.Lock = field(default_factory=threading.Lock)
    _locks: dict[str, threading.Lock] = field(default_factory=dict)
    extras: dict[str, Any] = field(default_factory=dict)

    @property
    def uploads(self) -> Path:
        return self.files / "uploads"

    @property
    def reports(self) -> Path:
        return self.files / "reports"

    @property
    def cache(self) -> Path:
        return self.files / "cache" / "web"

    def lock(self, key: str) -> threading.Lock:
        """A lock per key (one report written at a time per task, one preview per operator...)."""
        with self._lock:
            return self._locks.setdefault(key, threading.Lock())

    def dataset(self, path: str) -> Any:
        """The data set at ``path``, opened once and kept (the 8 most recent)."""
        from lidarfuzz.io.open import open_dataset
        from lidarfuzz.store.inventory import options_at

        with self._lock:
            if path in self._datasets:
                self._datasets.move_to_end(path)
                return self._datasets[path]
        opened = open_dataset(path, options=options_at(self.store, path))
        with self._lock:
            self._datasets[path] = opened
            while len(self._datasets) > 8:
                self._datasets.popitem(last=False)
        return opened

    def forget_dataset(self, path: str) -> None:
        with self._lock:
            self._datasets.pop(path, None)


def web(request: Request) -> WebContext:
    """The app's :class:`WebContext` (a FastAPI dependency)."""
    return request.app.state.web  # type: ignore[no-any-return]


__all__ = ["WebContext", "files_root", "web"]
