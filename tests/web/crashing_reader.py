"""Stand-ins for a native reader gone wrong, run by the upload inspector's worker process in
``tests/web/test_attacks.py`` (module-level, so a spawned worker can import them): one aborts the
process as the LAZ library's SIGABRT did, one hangs."""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Any


def abort(root: Path, base: Path, options: Any = None) -> tuple[list[dict[str, Any]], Any]:
    """What ``laszip`` did on a corrupt chunk table: abort the whole process (SIGABRT)."""
    os.abort()


def hang(root: Path, base: Path, options: Any = None) -> tuple[list[dict[str, Any]], Any]:
    """A reader looping forever on a header that claims ~2³² records."""
    while True:
        time.sleep(1)
