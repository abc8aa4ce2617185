"""What can go wrong with the store, by type: callers (the web app's HTTP answers, the CLI) act on
the class of an error, never on the words of its message.

* :class:`StoreError`: the store cannot be opened or migrated, or a request does not fit its state.
* :class:`NotFoundError`: no such task, finding, data set or model (HTTP 404).
* :class:`ConflictError`: the request contradicts what is stored — a name taken, a task still
  running, a data set registered with other options (HTTP 409).
"""

from __future__ import annotations

from lidarfuzz.errors import LidarfuzzError


class StoreError(LidarfuzzError):
    """The store cannot be opened or is not at a schema this version understands (and the base
    of the store's other errors)."""


class NotFoundError(StoreError):
    """A row the request names does not exist (its message says how to list what does)."""


class ConflictError(StoreError):
    """The request contradicts what is stored (its message says what to do instead)."""


__all__ = ["ConflictError", "NotFoundError", "StoreError"]
