"""Targets with known outcomes, for testing the harness itself (each read does one thing)."""

from __future__ import annotations

import os
import time
from pathlib import Path

from lidarfuzz.errors import DataFormatError
from lidarfuzz.io.formats.bin import frame_id_of
from tests.fuzz.harness import Target


def _seeds(_: Path) -> list[bytes]:
    return [b"seed one", b"seed two"]


def _ok(path: Path) -> object:
    return path.read_bytes()


def _refused(path: Path) -> object:
    raise DataFormatError(path, "refused on purpose")


def _foreign(path: Path) -> object:
    return frame_id_of(None)  # type: ignore[arg-type]  # a TypeError inside lidarfuzz/io/formats/bin.py


def _hang(path: Path) -> object:
    time.sleep(3600)
    return None


def _abort(path: Path) -> object:
    os.abort()


def _memory(path: Path) -> object:
    return bytearray(8 << 30)  # 8 GiB: over the child's 4 GiB address-space limit


TARGETS: list[Target] = [
    Target("selftest-ok", "case.bin", _seeds, _ok),
    Target("selftest-refused", "case.bin", _seeds, _refused),
    Target("selftest-foreign", "case.bin", _seeds, _foreign),
    Target("selftest-hang", "case.bin", _seeds, _hang),
    Target("selftest-abort", "case.bin", _seeds, _abort),
    Target("selftest-memory", "case.bin", _seeds, _memory),
]
