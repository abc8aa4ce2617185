"""Every HTTP request passes :class:`RequestGuard` first: the Host and Origin checks of a server
without a token, the size limits (on ``Content-Length`` and again while the body streams in), and
the security headers of every response. :func:`is_loopback` says whether a bind address keeps the
server on this machine (anything else needs a token); :func:`is_loopback_host` whether a request's
``Host`` names this machine (``localhost`` or a loopback address: 127.0.0.0/8, ``::1``), which a
DNS-rebinding page cannot send (its ``Host`` is its own domain name); :func:`cross_site_write` why
a state-changing request did not come from the server's own page."""

from __future__ import annotations

import ipaddress
from collections.abc import Awaitable, Callable, MutableMapping
from typing import Any

from fastapi import HTTPException, status

from lidarfuzz.web.security.limits import Limits, format_bytes

LOOPBACK_NAMES = frozenset({"localhost", "127.0.0.1", "::1", "[::1]"})
#: Methods that change nothing; every other method is a write (POST, PUT, PATCH, DELETE, ...)
SAFE_METHODS = frozenset({"GET", "HEAD", "OPTIONS"})

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


def _loopback_address(name: str) -> bool:
    try:
        return ipaddress.ip_address(name).is_loopback
    except ValueError:
        return False


def is_loopback(host: str) -> bool:
    """Whether binding to ``host`` keeps the server on this machine (``localhost``, 127.0.0.0/8, ``::1``)."""
    name = host.strip().strip("[]").lower()
    return name == "localhost" or _loopback_address(name)


def _host_name(header: str) -> str:
    """``127.0.0.1:8000`` → ``127.0.0.1``; ``[::1]:8000`` → ``::1``."""
    header = header.strip().lower()
    if header.startswith("["):
        return header[1:].partition("]")[0]
    return header.rpartition(":")[0] if header.count(":") == 1 else header


def is_loopback_host(header: str) -> bool:
    """Whether a request's ``Host`` header (``127.0.0.2:8000``, ``[::1]:8000``, ``localhost``) names
    this machine: ``localhost`` or a loopback address literal, never another name however it resolves."""
    name = _host_name(header)
    return name in LOOPBACK_NAMES or _loopback_address(name)


def cross_site_write(headers: dict[str, str]) -> str | None:
    """Why a write did not come from the server's own page, or None when it did.

    A browser marks every request it sends: ``Origin`` on each POST, PUT, PATCH and DELETE (the
    page's ``scheme://host:port``; ``null`` from a sandboxed frame, a ``data:`` page or a file)
    and, in current browsers, ``Sec-Fetch-Site``; a page cannot forge either. So a write counts as
    the server's own only with ``Origin`` naming the ``Host`` it was sent to and, where present,
    ``Sec-Fetch-Site: same-origin``; a missing ``Origin`` (an old browser, or a script that did not
    say) is cross-site too.
    """
    fetch_site = headers.get("sec-fetch-site")
    if fetch_site is not None and fetch_site.strip().lower() != "same-origin":
        return f"Sec-Fetch-Site {fetch_site!r}: a request from another site"
    origin = headers.get("origin")
    if origin is None:
        return "no Origin header"
    if origin.strip().lower() == "null":
        return "Origin 'null' (a sandboxed frame, a data: page or a local file)"
    scheme, sep, rest = origin.strip().lower().partition("://")
    if not sep or scheme not in ("http", "https") or rest.rstrip("/") != headers.get("host", "").strip().lower():
        return f"Origin {origin!r}: another site"
    return None


class RequestGuard:
    """ASGI middleware: host and origin checks, and request size limits.

    Args:
        app: The wrapped application.
        limits: Size limits (uploads to :data:`UPLOAD_PATHS`, others to ``max_request``).
        loopback_only: Answer only requests whose ``Host`` names this machine
            (:func:`is_loopback_host`; set when no token protects the server, against DNS rebinding).
        same_origin_writes: Refuse writes (POST, PUT, PATCH, DELETE) that do not come from the
            server's own page (:func:`cross_site_write`; set when no token protects the server. A
            token travels in a header no other site can add, so with one a reverse proxy that
            rewrites ``Host`` or ``Origin`` keeps working).
    """

    def __init__(self, app: ASGIApp, limits: Limits, loopback_only: bool, same_origin_writes: bool = True) -> None:
        self.app, self.limits, self.loopback_only = app, limits, loopback_only
        self.same_origin_writes = same_origin_writes

    async def _refuse(self, send: Send, code: int, detail: str) -> None:
        import json

        body = json.dumps({"detail": detail}).encode()
        await send({"type": "http.response.start", "status": code,
                    "headers": [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode()),
                                (b"connection", b"close"), *SECURITY_HEADERS]})
        await send({"type": "http.response.body", "body": body})

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        headers = {k.decode("latin-1").lower(): v.decode("latin-1") for k, v in scope.get("headers", [])}
        host = headers.get("host", "")
        if self.loopback_only and not is_loopback_host(host):
            await self._refuse(send, 403, f"Host {host!r}: this server answers only requests to localhost, "
                                          "127.0.0.1 or another loopback address (start it with --token to serve "
                                          "other names)")
            return
        method = scope.get("method", "GET")
        if self.same_origin_writes and method not in SAFE_METHODS:
            why = cross_site_write(headers)
            if why is not None:
                shown = host or "127.0.0.1:8000"
                await self._refuse(send, 403, f"{why}: cross-site requests are refused; a {method} must come from "
                                              f"this server's page (a script sends 'Origin: http://{shown}', or "
                                              "the server is started with --token and the script sends "
                                              "'Authorization: Bearer TOKEN')")
                return
        path = scope.get("path", "")
        limit = self.limits.max_upload if path in UPLOAD_PATHS else self.limits.max_request
        declared = headers.get("content-length")
        if declared is not None and declared.isascii() and declared.isdigit() and \
                (len(declared) > 20 or int(declared) > limit):  # not int() of '²' or 5,000 digits
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


__all__ = ["LOOPBACK_NAMES", "SAFE_METHODS", "SECURITY_HEADERS", "UPLOAD_PATHS", "RequestGuard", "UploadTooLarge",
           "cross_site_write", "is_loopback", "is_loopback_host"]
