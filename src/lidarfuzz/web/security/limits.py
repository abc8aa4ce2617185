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
        max_unzipped: Total uncompressed bytes of an uploaded zip (counted as written, never
            taken from its headers).
        max_ratio: How many times its compressed size a zip member, and the whole zip, may
            unpack to (deflate reaches about 1,000 on zeros; point clouds and labels 1-10).
        ratio_grace: Bytes a member, and the zip, may unpack to before ``max_ratio`` applies
            (a small file of zeros is no bomb).
        max_depth: Folders in a member's path.
        max_name: Characters in a member's path (each folder or file name: at most 255).
        inspect_memory: Address space of the process that inspects uploads (None: no limit).
        inspect_seconds: Time an upload's inspection may take (None: no limit).
    """

    max_upload: int = 2 * GiB
    max_request: int = 1 * MiB
    max_members: int = 100_000
    max_unzipped: int = 8 * GiB
    max_ratio: int = 100
    ratio_grace: int = 1 * MiB
    max_depth: int = 32
    max_name: int = 1024
    inspect_memory: int | None = 4 * GiB
    inspect_seconds: float | None = 3600.0


def format_bytes(value: int) -> str:
    """``2147483648`` → ``2 GiB``; ``10000`` → ``10,000 bytes``."""
    for unit, size in (("GiB", GiB), ("MiB", MiB), ("KiB", 1024)):
        if value >= size and value % size == 0:
            return f"{value // size} {unit}"
    return f"{value:,} bytes"


__all__ = ["GiB", "Limits", "MiB", "format_bytes"]
