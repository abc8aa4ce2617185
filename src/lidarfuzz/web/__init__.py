"""The web application (``lidarfuzz serve``): the thesis's web system on the campaign engine.

:func:`create_app` builds the FastAPI app; nothing here re-implements the engine — tasks are
created by :func:`lidarfuzz.campaign.tasks.create_task`, run by
:func:`lidarfuzz.campaign.runner.run_task`, reported by :func:`lidarfuzz.report.write_report`.
The contract (layout, security rules, API, binary frames) is ``docs/web.md``.

``create_app`` and ``Limits`` are imported on first use, so that the upload inspector's worker
process (:mod:`lidarfuzz.web.inspection`) starts without loading FastAPI and every route.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from lidarfuzz.web.app import create_app
    from lidarfuzz.web.security import Limits


def __getattr__(name: str) -> Any:
    if name == "create_app":
        from lidarfuzz.web.app import create_app

        return create_app
    if name == "Limits":
        from lidarfuzz.web.security import Limits

        return Limits
    raise AttributeError(f"module 'lidarfuzz.web' has no attribute {name!r}")


__all__ = ["Limits", "create_app"]
