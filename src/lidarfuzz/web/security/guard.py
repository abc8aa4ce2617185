"""Every HTTP request passes :class:`RequestGuard` first: the Host and Origin checks of a server
without a token, the size limits (on ``Content-Length`` and again while the body streams in), and
the security headers of every response. :func:`is_loopback` says whether a bind address keeps the
server on this machine (anything else needs a token)."""

from __future__ import annotations

import ipaddress
from collections.abc import Awaitable, Callable, MutableMapping
from typing import Any

from fastapi import HTTPException, status

from lidarfuzz.web.security.limits import Limits, format_bytes

LOOPBACK_NAMES = frozenset({"localhost", "127.0.0.1", "::1", "[::1]"})

Scope = MutableMapping[str, Any]
Message = MutableMapping[str, Any]
Receive = Callable[[], Awaitable[Message]]
Send = Callable[[Message], Awaitable[None]]
ASGIApp = Callable[[Scope, Receive, Send], Awaitable[None]]

UPLOAD_PATHS = frozenset({"/api/datasets/upload", "/api/models/upload"})
# on every response: no content sniffing, and no Referer (a ?token= in the address never leaks)
SECURITY_HEADERS = ((b"x-content-type-options", b"nosniff"), (b"referrer-policy", b"no-referrer"))


class UploadTooLarge(HTTPException):
    """A request body over its limit (413)."""

    def __init__(self, limit: int) -> None:
        super().__init__(status.HTTP_413_CONTENT_TOO_LARGE,
                         f"request body: larger than the limit of {format_bytes(limit)} (--max-upload)")


def is_loopback(host: str) -> bool:
    """Whether binding to ``host`` keeps the server on this machine."""
    name = host.strip().strip("[]").lower()
    if name == "localhost":
        return True
    try:
        return ipaddress.ip_address(name).is_loopback
    except ValueError:
        return False


def _host_name(header: str) -> str:
    """``127.0.0.1:8000`` → ``127.0.0.1``; ``[::1]:8000`` → ``::1``."""
    header = header.strip().lower()
    if header.startswith("["):
        return header[1:].partition("]")[0]
    return header.rpartition(":")[0] if header.count(":") == 1 else header


class RequestGuard:
    """ASGI middleware: host and origin checks, and request size limits.

    Args:
        app: The wrapped application.
        limits: Size limits (uploads to :data:`UPLOAD_PATHS`, others to ``max_request``).
        loopback_only: Answer only requests whose ``Host`` is a loopback name (set when no
            token protects the server, against DNS rebinding).
        same_origin_writes: Refuse POST/DELETE... from another site's page (set when no token
            protects the server; a token travels in a header no other site can add, so with one
            a reverse proxy that rewrites ``Host`` keeps working).
    """

    def __init__(self, app: ASGIApp, limits: Limits, loopback_only: bool, same_origin_writes: bool = True) -> None:
        self.app, self.limits, self.loopback_only = app, limits, loopback_only
        self.same_origin_writes = same_origin_writes

    async def _refuse(self, send: Send, code: int, detail: str) -> None:
        import json

        body = json.dumps({"detail": detail}).encode()
        await send({"type": "http.response.start", "status": code,
                    "headers": [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode()),
                                (b"connection", b"close")]})
        await send({"type": "http.response.body", "body": body})

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        headers = {k.decode("latin-1").lower(): v.decode("latin-1") for k, v in scope.get("headers", [])}
        if self.loopback_only and _host_name(headers.get("host", "")) not in LOOPBACK_NAMES:
            await self._refuse(send, 403, f"Host {headers.get('host', '')!r}: this server answers only requests to "
                                          "127.0.0.1/localhost (start it with --token to serve other names)")
            return
        method = scope.get("method", "GET")
        origin = headers.get("origin")
        if self.same_origin_writes and method not in ("GET", "HEAD", "OPTIONS") and origin and origin != "null":
            origin_host = origin.split("://", 1)[-1].rstrip("/").lower()
            if origin_host != headers.get("host", "").lower():
                await self._refuse(send, 403, f"Origin {origin!r}: cross-site requests are refused")
                return
        path = scope.get("path", "")
        limit = self.limits.max_upload if path in UPLOAD_PATHS else self.limits.max_request
        declared = headers.get("content-length")
        if declared is not None and declared.isdigit() and int(declared) > limit:
            await self._refuse(send, 413, UploadTooLarge(limit).detail)
            return
        received = 0

        async def counted() -> Message:
            nonlocal received
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > limit:  # a body longer than it said, or no Content-Length at all
                    raise UploadTooLarge(limit)
            return message

        async def with_headers(message: Message) -> None:
            if message["type"] == "http.response.start":
                message["headers"] = [*message.get("headers", []), *SECURITY_HEADERS]
            await send(message)

        await self.app(scope, counted, with_headers)


__all__ = ["LOOPBACK_NAMES", "SECURITY_HEADERS", "UPLOAD_PATHS", "RequestGuard", "UploadTooLarge", "is_loopback"]
