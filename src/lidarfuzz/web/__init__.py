"""The web application (``lidarfuzz serve``): the thesis's web system on the campaign engine.

:func:`create_app` builds the FastAPI app; nothing here re-implements the engine — tasks are
created by :func:`lidarfuzz.campaign.tasks.create_task`, run by
:func:`lidarfuzz.campaign.runner.run_task`, reported by :func:`lidarfuzz.report.write_report`.
The contract (layout, security rules, API, binary frames) is ``docs/web.md``.
"""

from lidarfuzz.web.app import create_app
from lidarfuzz.web.security import Limits

__all__ = ["Limits", "create_app"]
