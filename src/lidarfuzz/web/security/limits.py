"""Size limits of what clients send, and how the messages show sizes. No FastAPI here:
``lidarfuzz serve`` reads them before the web app is built."""

from __future__ import annotations

from dataclasses import dataclass

GiB = 1 << 30
MiB = 1 << 20


@dataclass(frozen=True)
class Limits:
    """Size limits of what clients send.

    Attributes:
        max_upload: Bytes in one upload request (data sets, model files).
        max_request: Bytes in any other request (JSON bodies).
        max_members: Members of an uploaded zip.
        max_unzipped: Total uncompressed bytes of an uploaded zip.
    """

    max_upload: int = 2 * GiB
    max_request: int = 1 * MiB
    max_members: int = 100_000
    max_unzipped: int = 8 * GiB


def format_bytes(value: int) -> str:
    """``2147483648`` → ``2 GiB``; ``10000`` → ``10,000 bytes``."""
    for unit, size in (("GiB", GiB), ("MiB", MiB), ("KiB", 1024)):
        if value >= size and value % size == 0:
            return f"{value // size} {unit}"
    return f"{value:,} bytes"


__all__ = ["GiB", "Limits", "MiB", "format_bytes"]
