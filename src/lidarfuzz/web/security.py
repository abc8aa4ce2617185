"""The web app's security rules, each in one place (and each with a test in ``tests/web``).

* Binding: 127.0.0.1 by default; any other host needs a token (:func:`is_loopback`).
* Token: with one, every ``/api`` call carries ``Authorization: Bearer T`` or ``?token=T``,
  compared in constant time (:func:`check_token`).
* Without a token the app answers only requests addressed to a loopback name (a web page
  cannot reach it through DNS rebinding), and state-changing calls from another origin are
  refused (a page cannot post a form to it): :class:`RequestGuard`. With a token neither is
  needed: no other site can add the ``Authorization`` header.
* Uploads: a size limit per request, checked on ``Content-Length`` and again while the body
  streams in (:class:`RequestGuard`); zip members checked before anything is extracted —
  absolute paths, ``..``, links, member count and total uncompressed size
  (:func:`extract_zip`); files stored under ``<workspace>/uploads/<generated id>/`` with
  sanitised names (:func:`safe_component`) and never executed.
* Names and frame ids in paths: plain names only (:func:`check_name`, :func:`check_frame_id`).
* Systems under test: ``subprocess:`` and ``worker:`` specs, and options that name code or
  files outside the uploads, are refused through the API (:func:`check_model_spec`).
"""

from __future__ import annotations

import ipaddress
import re
import secrets
import shutil
import stat
import zipfile
from collections.abc import Awaitable, Callable, Iterable, MutableMapping
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import Annotated, Any

from fastapi import Depends, HTTPException, Request, status
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from lidarfuzz.plugins import declared

GiB = 1 << 30
MiB = 1 << 20

LOOPBACK_NAMES = frozenset({"localhost", "127.0.0.1", "::1", "[::1]"})
NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,99}$")
FRAME_ID = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9._-]{0,199}$")
# parts of a zip that are not data: macOS resource forks and Finder files
IGNORED_MEMBERS = ("__MACOSX/",)

Scope = MutableMapping[str, Any]
Message = MutableMapping[str, Any]
Receive = Callable[[], Awaitable[Message]]
Send = Callable[[Message], Awaitable[None]]
ASGIApp = Callable[[Scope, Receive, Send], Awaitable[None]]


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


UPLOAD_PATHS = frozenset({"/api/datasets/upload", "/api/models/upload"})
# on every response: no content sniffing, and no Referer (a ?token= in the address never leaks)
SECURITY_HEADERS = ((b"x-content-type-options", b"nosniff"), (b"referrer-policy", b"no-referrer"))


class UploadTooLarge(HTTPException):
    """A request body over its limit (413)."""

    def __init__(self, limit: int) -> None:
        super().__init__(status.HTTP_413_CONTENT_TOO_LARGE,
                         f"request body: larger than the limit of {format_bytes(limit)} (--max-upload)")


def format_bytes(value: int) -> str:
    """``2147483648`` → ``2 GiB``; ``10000`` → ``10,000 bytes``."""
    for unit, size in (("GiB", GiB), ("MiB", MiB), ("KiB", 1024)):
        if value >= size and value % size == 0:
            return f"{value // size} {unit}"
    return f"{value:,} bytes"


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


# -- names -------------------------------------------------------------------------------
def check_name(value: str, field: str) -> str:
    """A name a user gives a data set or model: letters, digits, ``. _ -``; no path."""
    if not NAME.match(value or "") or ".." in value:
        raise HTTPException(status.HTTP_400_BAD_REQUEST,
                            f"{field}: {value!r} is not a plain name (letters, digits, '.', '_', '-'; "
                            f"at most 100; no '/' or '..')")
    return value


def check_frame_id(value: str) -> str:
    """A frame id from a URL: never a path (no separators, no ``..``)."""
    if not FRAME_ID.match(value or "") or ".." in value:
        raise HTTPException(status.HTTP_400_BAD_REQUEST, f"frame_id: {value!r} is not a frame id")
    return value


def safe_component(name: str) -> str:
    """One path component of an uploaded file, reduced to safe characters (never empty or dotted)."""
    cleaned = re.sub(r"[^A-Za-z0-9._-]", "_", name).lstrip(".")
    return cleaned[:150] or "file"


def within(path: Path, root: Path) -> bool:
    """Whether ``path`` (resolved) lies inside ``root`` (resolved)."""
    try:
        path.resolve().relative_to(root.resolve())
    except ValueError:
        return False
    return True


# -- zips --------------------------------------------------------------------------------
def _bad_member(name: str, why: str) -> HTTPException:
    return HTTPException(status.HTTP_400_BAD_REQUEST, f"{name}: {why}; nothing was extracted")


def check_zip(archive: zipfile.ZipFile, limits: Limits) -> list[tuple[zipfile.ZipInfo, PurePosixPath]]:
    """Every member that will be extracted, with its sanitised relative path; raises 400 naming
    the first member that is absolute, climbs out with ``..``, is a link or special file, or
    breaks the count / size limits. Nothing is written."""
    infos = archive.infolist()
    if len(infos) > limits.max_members:
        raise _bad_member(infos[limits.max_members].filename,
                          f"the zip has {len(infos)} members, more than the limit of {limits.max_members}")
    chosen: list[tuple[zipfile.ZipInfo, PurePosixPath]] = []
    total = 0
    for info in infos:
        name = info.filename
        if "\x00" in name:
            raise _bad_member(repr(name), "a member name with a NUL byte")
        posix = name.replace("\\", "/")
        if posix.startswith("/") or re.match(r"^[A-Za-z]:", posix):
            raise _bad_member(name, "an absolute path")
        parts = [p for p in posix.split("/") if p not in ("", ".")]
        if ".." in parts:
            raise _bad_member(name, "a path with '..' (zip-slip)")
        kind = stat.S_IFMT(info.external_attr >> 16) if info.create_system == 3 else 0  # Unix file type bits
        if kind and kind not in (stat.S_IFREG, stat.S_IFDIR):
            raise _bad_member(name, "a symbolic link" if kind == stat.S_IFLNK else "not a regular file")
        total += info.file_size
        if total > limits.max_unzipped:
            raise _bad_member(name, f"the zip unpacks to more than the limit of {format_bytes(limits.max_unzipped)}")
        if info.is_dir() or not parts or posix.startswith(IGNORED_MEMBERS) or parts[-1].startswith("."):
            continue
        chosen.append((info, PurePosixPath(*(safe_component(p) for p in parts))))
    seen: dict[PurePosixPath, str] = {}
    for info, rel in chosen:
        if rel in seen:
            raise _bad_member(info.filename, f"has the same sanitised name as {seen[rel]!r}")
        seen[rel] = info.filename
    return chosen


def extract_zip(path: Path, dest: Path, limits: Limits) -> list[Path]:
    """Extract a zip into ``dest`` after :func:`check_zip`; every write is counted against the
    limits again (a member may unpack to more than its header says)."""
    try:
        archive = zipfile.ZipFile(path)
    except zipfile.BadZipFile as exc:
        raise HTTPException(status.HTTP_400_BAD_REQUEST, f"{path.name}: not a zip file ({exc})") from None
    written: list[Path] = []
    with archive:
        members = check_zip(archive, limits)
        total = 0
        for info, rel in members:
            target = dest.joinpath(*rel.parts)
            if not within(target, dest):  # unreachable after check_zip; kept as the last line of defence
                raise _bad_member(info.filename, "outside the upload folder")
            target.parent.mkdir(parents=True, exist_ok=True)
            try:
                with archive.open(info) as source, target.open("xb") as out:
                    while chunk := source.read(MiB):
                        total += len(chunk)
                        if total > limits.max_unzipped:
                            raise _bad_member(info.filename, f"the zip unpacks to more than the limit of "
                                                             f"{format_bytes(limits.max_unzipped)}")
                        out.write(chunk)
            except (zipfile.BadZipFile, zipfile.LargeZipFile, OSError, EOFError) as exc:
                raise HTTPException(status.HTTP_400_BAD_REQUEST, f"{info.filename}: cannot extract ({exc})") from None
            written.append(target)
    return written


def remove_tree(path: Path, root: Path) -> None:
    """Delete an upload folder — only ever one inside ``root``."""
    if within(path, root) and path.resolve() != root.resolve():
        shutil.rmtree(path, ignore_errors=True)


# -- systems under test --------------------------------------------------------------------
CLI_ONLY_SCHEMES = ("subprocess", "worker")
FILE_SCHEMES = ("onnx", "open3d")
IMPORT_SPEC = re.compile(r"^\s*[A-Za-z_][\w.]*\s*:\s*[A-Za-z_][\w.]*\s*$")


def _entry_point_modules() -> set[str]:
    return {entry.value.partition(":")[0].strip() for entry in declared("lidarfuzz.suts")}


def _forbidden(detail: str) -> HTTPException:
    return HTTPException(status.HTTP_403_FORBIDDEN, detail)


def check_options(options: dict[str, Any], uploads: Path, field: str = "options") -> None:
    """Options given through the API may not name code to import or files outside the uploads."""
    for key, value in options.items():
        for item in (value if isinstance(value, list | tuple) else [value]):
            if not isinstance(item, str):
                continue
            if IMPORT_SPEC.match(item) and not re.match(r"^[A-Za-z]:[\\/]", item):
                raise _forbidden(f"{field}.{key}: {item!r} names code to import; options like this can only be "
                                 "given from the CLI or a campaign file")
            if ("/" in item or "\\" in item) and not within(Path(item), uploads):
                raise _forbidden(f"{field}.{key}: {item!r} is a file outside the uploads; upload it first")


def check_model_spec(spec: str, uploads: Path, options: Iterable[tuple[str, Any]] = (), field: str = "spec") -> None:
    """Refuse (403) a SUT spec the API may not register.

    Allowed: built-in and plugin names (``classic``, ``pillars?threads=2``), ``module:callable``
    in a module that an installed ``lidarfuzz.suts`` entry point comes from, and ``onnx:`` /
    ``open3d:`` specs of uploaded files. Refused: ``subprocess:`` and ``worker:`` (they run a
    command line: CLI or campaign file only), any other import, files outside the uploads.
    """
    from lidarfuzz.suts.registry import split_spec

    text = spec.strip()
    scheme, sep, rest = text.partition(":")
    if sep and scheme in CLI_ONLY_SCHEMES:
        raise _forbidden(f"{field}: {scheme}: systems run a command line; they can only be registered from the CLI "
                         f"(lidarfuzz models add) or a campaign file, not through the web API")
    base, query = split_spec(rest if sep and scheme in FILE_SCHEMES else text)
    if sep and scheme in FILE_SCHEMES:
        if not within(Path(base), uploads):
            raise _forbidden(f"{field}: {base!r} is not an uploaded file; upload it with POST /api/models/upload")
        if scheme == "open3d":
            config = dict(query).get("config", dict(options).get("config", ""))
            if isinstance(config, str) and config.endswith((".yml", ".yaml")):
                raise _forbidden(f"{field}: an Open3D-ML configuration file can only be given from the CLI; "
                                 f"use a bundled name such as pointpillars_kitti")
    elif ":" in base:
        module = base.partition(":")[0].strip()
        if module not in _entry_point_modules():
            raise _forbidden(f"{field}: {base!r} imports code from {module!r}, which no installed lidarfuzz.suts "
                             f"plugin provides; register it from the CLI (lidarfuzz models add)")
    check_options({**query, **dict(options)}, uploads)


__all__ = ["Limits", "RequestGuard", "UploadTooLarge", "check_frame_id", "check_model_spec", "check_name",
           "check_options", "check_zip", "extract_zip", "format_bytes", "is_loopback", "remove_tree",
           "safe_component", "token_dependency", "within"]
