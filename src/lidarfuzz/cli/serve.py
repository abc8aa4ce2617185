"""``lidarfuzz serve``: the web application (tasks, data sets, models, reports, the 3D viewer)."""

from importlib.util import find_spec
from typing import Annotated

import typer

from lidarfuzz.cli.common import WORKSPACE, WorkspaceOption, check_store_driver, console
from lidarfuzz.errors import LidarfuzzError
from lidarfuzz.settings import settings

#: What the web app imports, by the distribution that installs it: the ``web`` extra.
WEB_MODULES = {"fastapi": "fastapi", "uvicorn": "uvicorn", "python_multipart": "python-multipart"}


def require_web_extra() -> None:
    """Raise a one-line error naming the ``web`` extra when its packages are not installed."""
    missing = [name for module, name in WEB_MODULES.items() if find_spec(module) is None]
    if missing:
        raise LidarfuzzError(f"lidarfuzz serve needs the web extra ({', '.join(missing)} not installed): "
                             f"pip install 'lidarfuzz[web]'")


def parse_size(text: str) -> int:
    """``2G``, ``512M``, ``100k`` or a number of bytes → bytes."""
    value = text.strip().upper().removesuffix("B").removesuffix("I")
    scale = {"K": 1 << 10, "M": 1 << 20, "G": 1 << 30, "T": 1 << 40}.get(value[-1:], 1)
    number = value[:-1] if scale > 1 else value
    try:
        size = int(float(number) * scale)
    except ValueError:
        raise LidarfuzzError(f"--max-upload: {text!r} is not a size (e.g. 2G, 500M, 1048576)") from None
    if size <= 0:
        raise LidarfuzzError(f"--max-upload: {text!r} must be positive")
    return size


def serve(
    host: Annotated[str, typer.Option(help="Address to bind; anything but loopback needs --token.")] = "127.0.0.1",
    port: Annotated[int, typer.Option(min=0, max=65535, help="Port.")] = 8000,
    token: Annotated[str | None, typer.Option(help="Require this token on every API call "
                                                   "(Authorization: Bearer …); $LIDARFUZZ_TOKEN.")] = None,
    workers: Annotated[int, typer.Option(min=0, help="Tasks run at once (0: queue only).")] = 1,
    processes: Annotated[int | None, typer.Option(min=1, help="Worker processes per running task "
                                                              "(default: the CPU count).")] = None,
    max_upload: Annotated[str, typer.Option(help="Largest upload, e.g. 2G or 500M.")] = "2G",
    workspace: WorkspaceOption = WORKSPACE,
) -> None:
    """Serve the web application on the workspace's store: tasks with live progress, data sets,
    models, reports and the 3D viewer; the API's documentation is at /docs."""
    require_web_extra()
    from lidarfuzz.web.security import Limits, is_loopback

    environment = settings()
    token, log_level = token or environment.token, environment.log_level  # a bad level fails before serving
    if not is_loopback(host) and not token:
        raise LidarfuzzError(f"--host {host}: serving beyond this machine needs a token "
                             f"(--token T or $LIDARFUZZ_TOKEN); every API call must then carry it")
    limits = Limits(max_upload=parse_size(max_upload))
    check_store_driver(workspace)

    import uvicorn

    from lidarfuzz.web import create_app

    web_app = create_app(workspace, token=token or None, workers=workers, processes=processes, limits=limits)
    shown = f"[{host}]" if ":" in host else host
    suffix = f"/?token={token}" if token else "/"
    console.print(f"lidarfuzz web app on [bold]http://{shown}:{port}{suffix}[/] (workspace {workspace}; "
                  f"API docs /docs); Ctrl-C stops it")
    uvicorn.run(web_app, host=host, port=port, log_level=log_level)
