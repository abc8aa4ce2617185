"""The token: with one, every ``/api`` call carries ``Authorization: Bearer T`` (or ``?token=T``
for server-sent events and binary downloads), compared in constant time."""

from __future__ import annotations

import secrets
from collections.abc import Awaitable, Callable
from typing import Annotated

from fastapi import Depends, HTTPException, Request, status
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

_bearer = HTTPBearer(auto_error=False, description="The server's token (lidarfuzz serve --token); "
                                                   "SSE and binary endpoints also take ?token=")


def token_dependency(token: str | None) -> Callable[..., Awaitable[None]]:
    """A FastAPI dependency that checks ``token`` (none: every call passes)."""

    async def check_token(request: Request,
                          credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)]) -> None:
        if token is None:
            return
        given = credentials.credentials if credentials is not None else request.query_params.get("token")
        if not given or not secrets.compare_digest(given.encode(), token.encode()):
            raise HTTPException(status.HTTP_401_UNAUTHORIZED, "missing or wrong token: send "
                                "'Authorization: Bearer TOKEN' (or ?token=TOKEN)",
                                headers={"WWW-Authenticate": "Bearer"})

    return check_token


__all__ = ["token_dependency"]
