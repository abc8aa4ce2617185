"""The FastAPI application: :func:`create_app` wires the store, the task workers, the security
rules, the API routes, the offline OpenAPI docs and the built front end together. What the
routes share (:class:`~lidarfuzz.web.context.WebContext`) is in :mod:`lidarfuzz.web.context`.

Example:
    >>> app = create_app("lidarfuzz-workspace", workers=1)  # doctest: +SKIP
    >>> import uvicorn; uvicorn.run(app, host="127.0.0.1", port=8000)  # doctest: +SKIP
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

from fastapi import Depends, FastAPI, Request
from fastapi.openapi.docs import get_swagger_ui_html
from fastapi.responses import FileResponse, HTMLResponse, JSONResponse, PlainTextResponse
from fastapi.staticfiles import StaticFiles
from starlette.middleware.gzip import GZipMiddleware

from lidarfuzz import __version__
from lidarfuzz.errors import DataFormatError, LidarfuzzError
from lidarfuzz.store.errors import NotFoundError
from lidarfuzz.store.store import Store, StoreError
from lidarfuzz.web.context import WebContext, files_root
from lidarfuzz.web.routes import catalogue, compare, datasets, findings, frames, models, ratings, reports, tasks
from lidarfuzz.web.security import Limits, RequestGuard, install_redaction, token_dependency
from lidarfuzz.web.workers import TaskWorkers

STATIC = Path(__file__).with_name("static")
SWAGGER = "/static/vendor/swagger-ui"
log = logging.getLogger("lidarfuzz.web")


def create_app(workspace: str | Path = "lidarfuzz-workspace", *, token: str | None = None, workers: int = 1,
               processes: int | None = None, inline: bool = False, limits: Limits | None = None,
               files: str | Path | None = None, loopback_only: bool | None = None, executor: str = "pool",
               address: str | None = None) -> FastAPI:
    """The lidarfuzz web application on the store of ``workspace``.

    Args:
        workspace: A workspace folder (its SQLite store) or a database URL.
        token: When set, every ``/api`` call must carry it (``Authorization: Bearer``, or
            ``?token=`` for server-sent events and binary downloads).
        workers: Tasks run at once by background threads (0: tasks are queued, never run).
        processes: Worker processes of each running task (None: the CPU count), as ``lidarfuzz
            run --workers``.
        inline: Run tasks' units in the worker thread instead of a process pool (tests).
        executor, address: Where tasks' units run, as ``lidarfuzz run --executor --address``: ``pool``
            (local processes) or ``ray`` (the Ray cluster at ``address``; the store must be
            PostgreSQL).
        limits: Upload and request size limits.
        files: Where uploads, reports and caches go (default: the workspace folder, or
            ``./lidarfuzz-web`` for a database URL).
        loopback_only: Answer only requests addressed to 127.0.0.1/localhost (default: when
            there is no token).
    """
    workspace = str(workspace)
    store = Store(workspace)
    root = Path(files) if files is not None else files_root(workspace)
    context = WebContext(workspace=workspace, store=store, files=root, limits=limits or Limits(), token=token,
                         workers=TaskWorkers(store, threads=workers, processes=processes,
                                             executor="inline" if inline else executor, address=address),
                         processes=processes)

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        install_redaction()  # after the server configured its logging: no token= in any log line
        context.workers.start()
        try:
            yield
        finally:
            context.workers.close()
            from lidarfuzz.web.jobs import jobs_of

            jobs_of(context).close()
            store.close()

    app = FastAPI(title="lidarfuzz", version=__version__, lifespan=lifespan, docs_url=None, redoc_url=None,
                  description="Mutation-based and metamorphic testing of LiDAR perception software: the web API. "
                              "Every call drives the same campaign engine as the lidarfuzz CLI.")
    app.state.web = context
    # compressed answers for clients that accept them (a remote user on a slow link): a finding's pair, 8.9 MB
    # of float32 LFZ1, goes as 3.6 MB; level 1 costs about 150 ms per pair where level 9 (Starlette's
    # default) costs 600 ms for 0.3 MB less (benchmarks/web.py); event streams are never compressed
    app.add_middleware(GZipMiddleware, minimum_size=1024, compresslevel=1)
    app.add_middleware(RequestGuard, limits=context.limits,  # type: ignore[arg-type]
                       loopback_only=token is None if loopback_only is None else loopback_only,
                       same_origin_writes=token is None)
    _errors(app)

    api = [Depends(token_dependency(token))]
    for module in (tasks, compare, reports, findings, frames, datasets, models, catalogue, ratings):
        app.include_router(module.router, prefix="/api", dependencies=api)

    @app.get("/api/health", tags=["health"], dependencies=api)
    def health() -> dict[str, Any]:
        """Version, workspace, whether a token is required, and the workers."""
        return {"version": __version__, "workspace": workspace, "token_required": token is not None,
                "workers": context.workers.threads, "processes": processes}

    @app.get("/docs", include_in_schema=False)
    def docs() -> HTMLResponse:
        return get_swagger_ui_html(openapi_url=app.openapi_url or "/openapi.json", title="lidarfuzz API",
                                   swagger_js_url=f"{SWAGGER}/swagger-ui-bundle.js",
                                   swagger_css_url=f"{SWAGGER}/swagger-ui.css", swagger_favicon_url="data:,")

    @app.get("/", include_in_schema=False, response_model=None)
    def index() -> FileResponse | PlainTextResponse:
        page = STATIC / "index.html"
        if not page.is_file():
            return PlainTextResponse("the lidarfuzz front end is not built: cd web/frontend && npm ci && npm run build "
                                     "(the API is up: /docs)", status_code=503)
        return FileResponse(page, headers={"Cache-Control": "no-cache"})

    app.mount("/static", StaticFiles(directory=STATIC, check_dir=False), name="static")
    return app


def _errors(app: FastAPI) -> None:
    """The engine's errors as HTTP answers, by type: bad data 422, no such row 404, a state
    conflict (any other store error) 409, the rest 422."""

    @app.exception_handler(DataFormatError)
    async def data_error(_request: Request, exc: DataFormatError) -> JSONResponse:
        return JSONResponse({"detail": str(exc)}, status_code=422)

    @app.exception_handler(StoreError)
    async def store_error(_request: Request, exc: StoreError) -> JSONResponse:
        code = 404 if isinstance(exc, NotFoundError) else 409
        return JSONResponse({"detail": exc.plain}, status_code=code)  # no command-line advice in a web page

    @app.exception_handler(LidarfuzzError)
    async def lidarfuzz_error(_request: Request, exc: LidarfuzzError) -> JSONResponse:
        return JSONResponse({"detail": exc.plain}, status_code=422)


__all__ = ["create_app"]
