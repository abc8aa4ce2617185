"""Assertions shared by the format tests."""

from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from lidarfuzz.errors import DataFormatError


def expect_read_error(read: Callable[[Path], Any], path: Path, pattern: str) -> DataFormatError:
    """``read(path)`` raises a DataFormatError that names the file and matches ``pattern``."""
    with pytest.raises(DataFormatError, match=pattern) as info:
        read(path)
    assert info.value.path == path
    assert str(info.value).startswith(str(path))
    return info.value
