"""Row ids from clients, bounded before they reach the store: a path or query id is an integer
from 1 to :data:`MAX_ID` (PostgreSQL's ``INTEGER`` columns, which the store's ids are, stop at
2³¹ − 1; SQLite's at 2⁶³ − 1, and a larger number made its driver raise ``OverflowError``, a 500).
Out of range is a 422 naming the parameter, as FastAPI answers any other invalid parameter."""

from __future__ import annotations

from typing import Annotated

from fastapi import HTTPException, Path, Query, status

#: The largest row id: PostgreSQL's 32-bit ``INTEGER`` (the store's id columns)
MAX_ID = 2**31 - 1
#: The largest offset into a list, or count, a client may ask for
MAX_COUNT = 2**31 - 1
#: The largest seed a client may give (numpy takes any non-negative integer; this keeps it a 64-bit one)
MAX_SEED = 2**63 - 1

RowId = Annotated[int, Path(ge=1, le=MAX_ID, description=f"a row id, 1 to {MAX_ID}")]
QueryId = Annotated[int | None, Query(ge=1, le=MAX_ID, description=f"a row id, 1 to {MAX_ID}")]
Offset = Annotated[int, Query(ge=0, le=MAX_COUNT)]
Seed = Annotated[int | None, Query(ge=0, le=MAX_SEED)]


def check_id(value: int, field: str) -> int:
    """``value`` as a row id, or a 422 naming ``field``."""
    if not 1 <= value <= MAX_ID:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                            f"{field}: {value if value.bit_length() < 64 else 'a number'} is not a row id "
                            f"(1 to {MAX_ID})")
    return value


__all__ = ["MAX_COUNT", "MAX_ID", "MAX_SEED", "Offset", "QueryId", "RowId", "Seed", "check_id"]
