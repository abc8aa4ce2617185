"""``lidarfuzz serve``: the web application (tasks, data sets, models, reports, the 3D viewer)."""

from enum import StrEnum
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


def check_token(token: str) -> str:
    """A token a browser and ``curl`` can send in a header: printable ASCII without spaces, at least 8 characters."""
    if len(token) < 8 or not all(33 <= ord(c) <= 126 for c in token):
        raise LidarfuzzError("--token: use at least 8 printable ASCII characters without spaces (a header and "
                             "an address carry it); e.g. python -c 'import secrets; print(secrets.token_urlsafe())'")
    return token


def banner(host: str, port: int, workspace: str, token: str | None, print_token: bool) -> str:
    """The start-up line: the address, and with a token how to sign in (the token itself only with
    ``--print-token``: a terminal's scroll-back and a service's journal are logs too)."""
    shown = f"[{host}]" if ":" in host else host
    address = f"http://{shown}:{port}/"
    sign_in = ""
    if token and print_token:
        address += f"?token={token}"
    elif token:
        sign_in = (f"; a token is required: open {address}?token=TOKEN once with your token "
                   "(--print-token prints that address)")
    return f"lidarfuzz web app on [bold]{address}[/] (workspace {workspace}; API docs /docs{sign_in}); Ctrl-C stops it"


class ServedExecutor(StrEnum):
    """Where the server's tasks run (``--executor``)."""

    pool = "pool"
    ray = "ray"


def serve(
    host: Annotated[str, typer.Option(help="Address to bind; anything but localhost or a loopback address "
                                           "(127.0.0.0/8, ::1) needs --token.")] = "127.0.0.1",
    port: Annotated[int, typer.Option(min=0, max=65535, help="Port.")] = 8000,
    token: Annotated[str | None, typer.Option(help="Require this token on every API call "
                                                   "(Authorization: Bearer …); $LIDARFUZZ_TOKEN. Never "
                                                   "printed or logged.")] = None,
    print_token: Annotated[bool, typer.Option("--print-token", help="Print the address with the token at start "
                                                                    "(to open it in a browser).")] = False,
    workers: Annotated[int, typer.Option(min=0, help="Tasks run at once (0: queue only).")] = 1,
    processes: Annotated[int | None, typer.Option(min=1, help="Worker processes per running task "
                                                              "(default: the CPU count).")] = None,
    max_upload: Annotated[str, typer.Option(help="Largest upload, e.g. 2G or 500M.")] = "2G",
    executor: Annotated[ServedExecutor, typer.Option(
        help="Where tasks' units run: pool (local worker processes) or ray (a Ray cluster; the store must be "
             "PostgreSQL, --workspace postgresql+psycopg://...).")] = ServedExecutor.pool,
    address: Annotated[str | None, typer.Option(
        help="With --executor ray: the cluster, auto or ray://HOST:PORT (default: RAY_ADDRESS, else a local "
             "Ray).")] = None,
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
    if token:
        check_token(token)
    elif print_token:
        raise LidarfuzzError("--print-token: this server has no token to print (give --token T or $LIDARFUZZ_TOKEN)")
    limits = Limits(max_upload=parse_size(max_upload))
    check_store_driver(workspace)
    if address is not None and executor != ServedExecutor.ray:
        raise typer.BadParameter("the address of a Ray cluster goes with --executor ray", param_hint="'--address'")
    if executor == ServedExecutor.ray:  # refused before serving, not when the first task starts
        from lidarfuzz.campaign.cluster import import_ray, require_shared_store
        from lidarfuzz.store.store import store_url

        import_ray()
        require_shared_store(store_url(str(workspace)))

    import uvicorn

    from lidarfuzz.web import create_app

    web_app = create_app(workspace, token=token or None, workers=workers, processes=processes, limits=limits,
                         executor=executor.value, address=address)
    console.print(banner(host, port, str(workspace), token or None, print_token), soft_wrap=True)
    uvicorn.run(web_app, host=host, port=port, log_level=log_level)
