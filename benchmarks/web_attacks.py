"""The attacks of issue 23 against a real ``lidarfuzz serve``: what each variant got, and whether
anything in the workspace changed or the server went down.

Each server is a ``lidarfuzz serve`` subprocess on a fresh workspace (two simulated frames as data
set ``world``, the classic pipeline as model ``classic``, tasks queued and never run:
``--workers 0``), at log level ``info`` so that uvicorn writes its access log. The groups:

* cross-site writes (Origin ``null``, none, another site, another port, ``Sec-Fetch-Site``
  cross-site and same-site) × seven writes (upload, stop, resume, delete a task, notes, add and
  delete a model) on a tokenless server, and the same page's writes as the control;
* zip bombs of several ratios and shapes, and hostile members;
* the token in the banner and the logs (``?token=`` in several places and encodings);
* binding: a loopback address other than 127.0.0.1 without a token, and configurations that cannot work;
* ids at 2³¹ − 1 (in range: 404), 2³¹, 2⁶³, 10³⁰, −1 and 0 on every route with an id, and out-of-range queries;
* names and notes with each class of control character (C0, DEL, C1, bidirectional, zero-width,
  line separator) through the API and the store, and ``datasets list`` on names stored raw;
* corrupt ``.laz`` uploads (a valid LAZ truncated, its chunk table pointer and bytes mutated, seeded):
  the server must answer after each.

    python benchmarks/web_attacks.py              # print the table
    python benchmarks/web_attacks.py --write-doc  # and rewrite docs/reliability.md's `web` section
"""

from __future__ import annotations

import argparse
import io
import os
import random
import shutil
import socket
import struct
import subprocess
import sys
import tempfile
import time
import zipfile
from collections import Counter
from pathlib import Path
from typing import Any

import httpx

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
TOKEN = "bench-s3cret-token-4711"
CLI = "import sys; from lidarfuzz.cli.app import main; sys.argv = ['lidarfuzz', *sys.argv[1:]]; main()"
CONTROL = {"C0 ESC": "\x1b]0;pwned\x07", "C0 BEL": "\x07", "C0 CR": "\r", "DEL": "\x7f", "C1 NEL": "\x85",
           "C1 CSI": "\x9b2J", "bidi override": "\u202e", "zero-width space": "\u200b", "line separator": "\u2028"}


def raw_controls(text: str, layout: bool = False) -> int:
    """How many characters of ``text`` a terminal would act on: C0 (but a listing's own tabs and line
    breaks, with ``layout``), DEL, C1, and the bidirectional override, zero-width space and line
    separator of :data:`CONTROL`."""
    return sum(1 for c in text if (ord(c) < 32 and not (layout and c in "\t\n")) or 127 <= ord(c) < 160
               or c in "\u202e\u200b\u2028")


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


class Served:
    """``lidarfuzz serve`` in a subprocess; its output kept in a file."""

    def __init__(self, workspace: Path, host: str = "127.0.0.1", token: str | None = None) -> None:
        self.port, self.host, self.token = free_port(), host, token
        self.base = f"http://{host}:{self.port}"
        self.log = workspace.parent / f"serve-{host}-{self.port}.log"
        env = {**os.environ, "LIDARFUZZ_LOG_LEVEL": "info"}
        env.pop("LIDARFUZZ_TOKEN", None)
        if token:
            env["LIDARFUZZ_TOKEN"] = token
        self.handle = self.log.open("w")
        self.process = subprocess.Popen([sys.executable, "-c", CLI, "serve", "--host", host, "--port", str(self.port),
                                         "--workers", "0", "--workspace", str(workspace)],
                                        stdout=self.handle, stderr=subprocess.STDOUT, env=env)
        deadline = time.monotonic() + 60
        while True:
            try:
                if httpx.get(self.base + "/api/health", headers=self.auth(), timeout=2).status_code == 200:
                    break
            except httpx.HTTPError:
                pass
            if self.process.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError(f"the server did not start: {self.log.read_text()}")
            time.sleep(0.2)

    def auth(self) -> dict[str, str]:
        return {"Authorization": f"Bearer {self.token}"} if self.token else {}

    def own(self) -> dict[str, str]:
        """What the app's own page sends with a write (Chromium)."""
        return {"Origin": self.base, "Sec-Fetch-Site": "same-origin", **self.auth()}

    def request(self, method: str, path: str, **kwargs: Any) -> httpx.Response:
        headers = kwargs.pop("headers", None)
        return httpx.request(method, self.base + path, headers=headers if headers is not None else self.auth(),
                             timeout=300, **kwargs)

    def alive(self) -> bool:
        try:
            return self.process.poll() is None and self.request("GET", "/api/health").status_code == 200
        except httpx.HTTPError:
            return False

    def peak_rss(self) -> int:
        """The server process's peak resident memory (bytes)."""
        for line in Path(f"/proc/{self.process.pid}/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) * 1024
        return 0

    def stop(self) -> str:
        self.process.terminate()
        try:
            self.process.wait(30)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()
        self.handle.close()
        return self.log.read_text(errors="replace")


def state(server: Served, workspace: Path) -> Any:
    """What an attack could change: data sets with notes, models, tasks with status, files under uploads/."""
    get = lambda path: server.request("GET", path).json()["items"]  # noqa: E731
    uploads = workspace / "uploads"
    return ({d["name"]: d["notes"] for d in get("/api/datasets")}, sorted(m["name"] for m in get("/api/models")),
            {t["id"]: t["status"] for t in get("/api/tasks")},
            sorted(str(p) for p in uploads.rglob("*")) if uploads.exists() else [])


def workspace_with_world(folder: Path) -> Path:
    from lidarfuzz.sim.dataset import GenerationConfig, generate_dataset
    from lidarfuzz.store import Store
    from lidarfuzz.store.inventory import add_dataset, add_model

    world = folder / "world"
    if not world.exists():
        generate_dataset(world, GenerationConfig(frames=2, seed=0), workers=1, overwrite=True)
    workspace = folder / f"ws-{len(list(folder.glob('ws-*')))}"
    store = Store(workspace)
    add_dataset(store, "world", world)
    add_model(store, "classic", "classic")
    store.close()
    return workspace


def files_of(world: Path) -> list[tuple[str, tuple[str, bytes]]]:
    return [("files", (p.name, p.read_bytes())) for p in sorted((world / "velodyne").iterdir())]


# -- attacks ------------------------------------------------------------------------------------
def cross_site(folder: Path) -> dict[str, Any]:
    workspace = workspace_with_world(folder)
    server = Served(workspace)
    world = folder / "world"
    try:
        task = server.request("POST", "/api/tasks", headers=server.own(),
                              json={"dataset": "world", "sut": "classic", "operators": [{"name": "rotate_z"}]})
        task_id = task.json()["id"]
        origins = {"Origin null": {"Origin": "null"}, "no Origin": {}, "another site": {"Origin": "http://evil.example"},
                   "another port": {"Origin": "http://127.0.0.1:1"},
                   "localhost (other name)": {"Origin": f"http://localhost:{server.port}"},
                   "Sec-Fetch-Site cross-site": {"Origin": server.base, "Sec-Fetch-Site": "cross-site"},
                   "Sec-Fetch-Site same-site": {"Origin": server.base, "Sec-Fetch-Site": "same-site"}}
        writes = [("POST", "/api/datasets/upload", {"data": {"name": "pwned"}, "files": files_of(world)}),
                  ("POST", f"/api/tasks/{task_id}/stop", {}), ("POST", f"/api/tasks/{task_id}/resume", {}),
                  ("DELETE", f"/api/tasks/{task_id}", {}), ("PATCH", "/api/datasets/world", {"json": {"notes": "x"}}),
                  ("POST", "/api/models", {"json": {"name": "pwned", "spec": "classic"}}),
                  ("DELETE", "/api/models/classic", {})]
        before = state(server, workspace)
        codes: Counter[int] = Counter()
        for headers in origins.values():
            for method, path, kwargs in writes:
                codes[server.request(method, path, headers=headers, **kwargs).status_code] += 1
        unchanged = state(server, workspace) == before
        control = server.request("PATCH", "/api/datasets/world", headers=server.own(), json={"notes": "mine"})
        return {"attack": "cross-site writes (no token)",
                "variants": f"{len(origins)} origins ({', '.join(origins)}) × {len(writes)} writes",
                "tried": sum(codes.values()), "outcome": f"{codes[403]} refused (403), "
                f"{sum(codes.values()) - codes[403]} other; workspace {'unchanged' if unchanged else 'CHANGED'}; "
                f"the page's own write (Origin + Sec-Fetch-Site same-origin): {control.status_code}",
                "held": codes[403] == sum(codes.values()) and unchanged and control.status_code == 200}
    finally:
        server.stop()


def _zip(members: dict[str, bytes], method: int = zipfile.ZIP_DEFLATED) -> bytes:
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", method, allowZip64=True) as archive:
        for name, data in members.items():
            archive.writestr(name, data)
    return buffer.getvalue()


def _zeros_zip(name: str, size: int) -> bytes:
    """One member of ``size`` zeros, deflated in 1 MiB pieces (no ``size`` bytes in memory)."""
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED, allowZip64=True) as archive, \
            archive.open(name, "w", force_zip64=True) as member:
        block = b"\0" * (1 << 20)
        for _ in range(size >> 20):
            member.write(block)
    return buffer.getvalue()


def _patch(data: bytes, index: int, **fields: int) -> bytes:
    offsets = {"flags": (8, "<H"), "file_size": (24, "<I"), "header_offset": (42, "<I")}
    out, at = bytearray(data), -1
    for _ in range(index + 1):
        at = out.index(b"PK\x01\x02", at + 1)
    for name, value in fields.items():
        offset, fmt = offsets[name]
        struct.pack_into(fmt, out, at + offset, value)
    return bytes(out)


def _overlapping(copies: int) -> bytes:
    """``copies`` central-directory entries all pointing to one 1 MiB kernel (Fifield's trick, simplified)."""
    data = _zip({f"velodyne/{i:06d}.bin": b"\0" * (1 << 20) for i in range(copies)})
    for index in range(1, copies):
        data = _patch(data, index, header_offset=0)
    return data


def _link() -> bytes:
    import stat

    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as archive:
        info = zipfile.ZipInfo("velodyne/000000.bin")
        info.create_system, info.external_attr = 3, (stat.S_IFLNK | 0o777) << 16
        archive.writestr(info, "/etc/passwd")
    return buffer.getvalue()


def bombs() -> dict[str, bytes]:
    zeros = b"\0" * (1 << 20)
    return {
        "ratio ~1,000: 8 MiB of zeros": _zeros_zip("velodyne/000000.bin", 8 << 20),
        "ratio ~1,000: 256 MiB of zeros": _zeros_zip("velodyne/000000.bin", 256 << 20),
        "ratio ~1,000: 1 GiB of zeros": _zeros_zip("velodyne/000000.bin", 1 << 30),
        "ratio 200: random 1 KiB + zeros": _zip({"velodyne/000000.bin": random.Random(0).randbytes(2 << 10)
                                                  + b"\0" * (4 << 20)}),
        "300 members × 64 KiB zeros (each under the grace)": _zip({f"velodyne/{i:06d}.bin": zeros[:64 << 10]
                                                                   for i in range(300)}),
        "5,000 members × 64 KiB zeros": _zip({f"velodyne/{i:06d}.bin": zeros[:64 << 10] for i in range(5000)}),
        "10 entries on one kernel (overlap)": _overlapping(10),
        "lying header: declares 1,000 B, inflates to 1 MiB": _patch(_zip({"velodyne/000000.bin": zeros}), 0,
                                                                    file_size=1000),
        "declares 3 GiB stored in 1 KiB": _patch(_zip({"velodyne/000000.bin": zeros[:1024]}, zipfile.ZIP_STORED),
                                                 0, file_size=3 << 30),
        "zip-slip ../../evil": _zip({"../../evil.txt": b"pwned"}),
        "absolute /etc/cron.d/x": _zip({"/etc/cron.d/x": b"pwned"}),
        "40 folders deep": _zip({"/".join(["d"] * 40) + "/000000.bin": b"x"}),
        "a 300-character name": _zip({"velodyne/" + "a" * 300 + ".bin": b"x"}),
        "symbolic link": _link(),
        "encrypted member": _patch(_zip({"velodyne/000000.bin": b"x" * 100}), 0, flags=1),
        "zip inside a zip (not extracted)": _zip({"inner.zip": _zeros_zip("velodyne/000000.bin", 64 << 20)}),
    }


def zip_bombs(folder: Path) -> list[dict[str, Any]]:
    workspace = workspace_with_world(folder)
    server = Served(workspace)
    rows = []
    try:
        before = state(server, workspace)
        for index, (name, data) in enumerate(bombs().items()):
            started = time.perf_counter()
            reply = server.request("POST", "/api/datasets/upload", headers=server.own(),
                                   data={"name": f"bomb{index}"}, files=[("files", ("data.zip", data))])
            took = time.perf_counter() - started
            detail = str(reply.json().get("detail", "")).replace("|", "\\|").replace("\n", " ")
            detail = detail if len(detail) <= 110 else f"{detail[:30]}…{detail[-75:]}"  # the member, and why
            unchanged = state(server, workspace) == before
            rows.append({"attack": "zip: " + name, "variants": f"{len(data):,} B uploaded", "tried": 1,
                         "outcome": f"{reply.status_code} in {took:.2f} s: {detail}; workspace "
                                    f"{'unchanged' if unchanged else 'CHANGED'}",
                         "held": reply.status_code in (400, 422) and unchanged and server.alive()})
        rows.append({"attack": "zip: server memory", "variants": "peak RSS over all the bombs above", "tried": 0,
                     "outcome": f"{server.peak_rss() / (1 << 20):.0f} MiB", "held": server.peak_rss() < 1 << 30})
    finally:
        server.stop()
    return rows


def token_in_logs(folder: Path) -> dict[str, Any]:
    workspace = workspace_with_world(folder)
    server = Served(workspace, host="127.0.0.1", token=TOKEN)
    variants = [("GET", f"/?token={TOKEN}"), ("GET", f"/api/health?token={TOKEN}"),
                ("GET", f"/api/datasets?x=1&token={TOKEN}&y=2"), ("GET", f"/api/datasets?TOKEN={TOKEN}"),
                ("GET", f"/api/datasets?token%3D{TOKEN}"), ("GET", f"/api/datasets?token={TOKEN}&token={TOKEN}"),
                ("GET", f"/api/tasks/1/events?token={TOKEN}"), ("GET", "/api/datasets?token=wrong-token-value"),
                ("GET", f"/static/missing.js?token={TOKEN}")]
    try:
        codes = Counter(server.request(method, path, headers={}).status_code for method, path in variants)
    finally:
        output = server.stop()
    lines = output.splitlines()
    access = [line for line in lines if '"GET ' in line]
    leaked = [line for line in lines if TOKEN in line or "wrong-token-value" in line]
    banner = lines[0] if lines else ""
    return {"attack": "the token in the banner and the logs",
            "variants": f"{len(variants)} requests with ?token= (query start, middle, repeated, upper case, "
                        f"URL-encoded, event stream, a wrong token, a 404), uvicorn at log level info",
            "tried": len(variants),
            "outcome": f"{len(leaked)} of {len(lines)} output lines hold a token ({len(access)} access-log lines, "
                       f"each `token=[redacted]`); banner without it: {TOKEN not in banner}; "
                       f"answers {dict(sorted(codes.items()))}",
            "held": not leaked and TOKEN not in banner and len(access) >= len(variants) - 1}


def binding(folder: Path) -> list[dict[str, Any]]:
    workspace = workspace_with_world(folder)
    rows = []
    server = Served(workspace, host="127.0.0.2")
    try:
        health = server.request("GET", "/api/health").status_code
        write = server.request("PATCH", "/api/datasets/world", headers=server.own(), json={"notes": "n"}).status_code
        rebound = server.request("GET", "/api/health", headers={"Host": f"rebound.example:{server.port}"}).status_code
    finally:
        server.stop()
    rows.append({"attack": "bind 127.0.0.2 without a token", "variants": "health, a write from its page, "
                 "a DNS-rebound Host", "tried": 3, "outcome": f"health {health}, write {write}, rebound Host {rebound}",
                 "held": (health, write, rebound) == (200, 200, 403)})
    env = {k: v for k, v in os.environ.items() if k != "LIDARFUZZ_TOKEN"}
    refused = 0
    configurations = [["--host", "0.0.0.0"], ["--host", "192.168.1.5"], ["--host", "::"], ["--print-token"],
                      ["--token", "short"], ["--token", "has spaces in it"], ["--token", "tökenwithumlaut"]]
    for arguments in configurations:
        result = subprocess.run([sys.executable, "-c", CLI, "serve", *arguments, "--workspace",
                                 str(folder / "never")], capture_output=True, text=True, timeout=120, env=env)
        refused += result.returncode == 2 and len(result.stderr.strip().splitlines()) == 1
    rows.append({"attack": "configurations that cannot work",
                 "variants": "; ".join(" ".join(a) for a in configurations),
                 "tried": len(configurations), "outcome": f"{refused} refused at start with one line (exit 2), "
                 f"workspace created: {(folder / 'never').exists()}",
                 "held": refused == len(configurations) and not (folder / "never").exists()})
    return rows


def ids(folder: Path) -> dict[str, Any]:
    workspace = workspace_with_world(folder)
    server = Served(workspace)
    values = [2**31 - 1, 2**31, 2**63, 10**30, -1, 0]
    codes: Counter[int] = Counter()
    try:
        before = state(server, workspace)
        paths = server.request("GET", "/openapi.json").json()["paths"]
        routes = 0
        for template, operations in paths.items():
            if not any(f"{{{p}}}" in template for p in ("task_id", "finding_id", "pair_id")):
                continue
            for method in operations:
                routes += 1
                for value in values:
                    path = template.replace("{name}", "world").replace("{frame_id}", "000000")
                    for parameter in ("task_id", "finding_id", "pair_id"):
                        path = path.replace(f"{{{parameter}}}", str(value))
                    body = {"json": {"rater": "a", "verdict": "same"}} if method in ("put", "patch") else {}
                    codes[server.request(method.upper(), path, headers=server.own(), **body).status_code] += 1
        queries = [("/api/tasks/1/findings", {"subtask": 10**30}), ("/api/tasks", {"offset": 2**63}),
                   ("/api/tasks/1/ratings/pairs", {"seed": -1}), ("/api/compare", {"tasks": f"1,{10**30}"}),
                   ("/api/datasets/world/frames", {"offset": 10**30}), ("/api/tasks", {"limit": 2**64}),
                   ("/api/compare", {"tasks": "1,\u00b2"}), ("/api/compare", {"tasks": "1," + "9" * 5000}),
                   ("/api/tasks/" + "9" * 5000, {})]
        for path, params in queries:
            codes[server.request("GET", path, params=params).status_code] += 1
        unchanged = state(server, workspace) == before
    finally:
        server.stop()
    return {"attack": "ids out of range", "variants": f"{routes} routes with an id × {len(values)} values "
            "(2³¹−1, 2³¹, 2⁶³, 10³⁰, −1, 0) + 9 queries (a 5,000-digit id, '²')", "tried": sum(codes.values()),
            "outcome": f"answers {dict(sorted(codes.items()))}; 500s: {codes[500]}; workspace "
                       f"{'unchanged' if unchanged else 'CHANGED'}",
            "held": codes[500] == 0 and unchanged}


def names(folder: Path) -> list[dict[str, Any]]:
    from lidarfuzz.errors import LidarfuzzError
    from lidarfuzz.store import Store
    from lidarfuzz.store.inventory import add_dataset

    workspace = workspace_with_world(folder)
    world = folder / "world"
    rows = []
    store = Store(workspace)
    refused = 0
    for text in CONTROL.values():
        try:
            add_dataset(store, f"evil{text}x", world)
        except LidarfuzzError as exc:
            refused += "\n" not in str(exc) and str(exc).startswith("name: ")
    store.close()
    rows.append({"attack": "names with control characters (store, as CLI and API add them)",
                 "variants": ", ".join(CONTROL), "tried": len(CONTROL),
                 "outcome": f"{refused} refused with one line naming `name`", "held": refused == len(CONTROL)})
    server = Served(workspace)
    notes_codes: dict[str, int] = {}
    upload_codes: Counter[int] = Counter()
    escaped = 0
    try:
        for name, text in CONTROL.items():
            notes_codes[name] = server.request("PATCH", "/api/datasets/world", headers=server.own(),
                                               json={"notes": f"n{text}"}).status_code
        for index, text in enumerate(CONTROL.values()):
            boundary = "attack"
            body = (f"--{boundary}\r\nContent-Disposition: form-data; name=\"name\"\r\n\r\nup{index}\r\n"
                    f"--{boundary}\r\nContent-Disposition: form-data; name=\"files\"; filename=\"x{text}.bin\"\r\n"
                    "Content-Type: application/octet-stream\r\n\r\n").encode() \
                + (world / "velodyne" / "000000.bin").read_bytes() + f"\r\n--{boundary}--\r\n".encode()
            form = {**server.own(), "Content-Type": f"multipart/form-data; boundary={boundary}"}
            reply = server.request("POST", "/api/datasets/upload", content=body, headers=form)
            upload_codes[reply.status_code] += 1
            escaped += reply.status_code == 201 and raw_controls(reply.json()["notes"]) == 0
    finally:
        server.stop()
    # notes keep format characters text needs (a zero-width space among them): escaped on output only
    expected = {name: 200 if name == "zero-width space" else 422 for name in CONTROL}
    refused = sum(1 for code in notes_codes.values() if code == 422)
    rows.append({"attack": "notes with control characters (PATCH)", "variants": ", ".join(CONTROL),
                 "tried": len(CONTROL), "outcome": f"{refused} refused (422 naming `notes`); kept: "
                 f"{', '.join(n for n, c in notes_codes.items() if c != 422) or 'none'}",
                 "held": notes_codes == expected})
    rows.append({"attack": "uploaded file names with control characters", "variants": ", ".join(CONTROL),
                 "tried": len(CONTROL), "outcome": f"answers {dict(sorted(upload_codes.items()))}; {escaped} "
                 "recorded with the name escaped in the notes, the others refused",
                 "held": escaped == upload_codes[201] and sum(upload_codes.values()) == len(CONTROL)
                 and upload_codes[500] == 0})
    # names an older version stored raw, printed by `datasets list`
    from sqlalchemy import update

    from lidarfuzz.store.models import Dataset

    store = Store(workspace)
    with store.session() as s:
        s.execute(update(Dataset).where(Dataset.name == "world")
                  .values(name="evil" + "".join(CONTROL.values()), notes="".join(CONTROL.values())))
    store.close()
    raw = 0
    for extra in ([], ["--plain"]):
        result = subprocess.run([sys.executable, "-c", CLI, "datasets", "list", "--workspace", str(workspace), *extra],
                                capture_output=True, text=True, timeout=120, env={**os.environ, "COLUMNS": "200"})
        raw += raw_controls(result.stdout, layout=True)
    rows.append({"attack": "`datasets list` on names and notes stored raw", "variants": "table and --plain, "
                 f"{len(CONTROL)} classes each in name and notes", "tried": 2,
                 "outcome": f"{raw} raw control characters printed", "held": raw == 0})
    return rows


def corrupt_laz(folder: Path, count: int) -> dict[str, Any]:
    import laspy
    import numpy as np

    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales = np.array([0.01, 0.01, 0.01])
    las = laspy.LasData(header)
    rng = np.random.default_rng(0)
    n = 20_000
    las.x, las.y, las.z = rng.uniform(-50, 50, n), rng.uniform(-50, 50, n), rng.uniform(-2, 5, n)
    las.intensity = rng.integers(0, 255, n)
    valid = io.BytesIO()
    las.write(valid, do_compress=True)
    good = valid.getvalue()
    offset = int.from_bytes(good[96:100], "little")  # offset to point data: the chunk table pointer is there
    generator = random.Random(0)
    variants = [("truncated to 4 KiB", good[:4096]), ("truncated to half", good[: len(good) // 2]),
                ("chunk table pointer = 2^62", good[:offset] + struct.pack("<q", 1 << 62) + good[offset + 8:]),
                ("chunk table pointer = -1", good[:offset] + struct.pack("<q", -1) + good[offset + 8:]),
                ("chunk table pointer past the end", good[:offset] + struct.pack("<q", len(good) + 10)
                 + good[offset + 8:])]
    for index in range(count - len(variants)):
        data = bytearray(good)
        for _ in range(generator.randint(1, 16)):
            at = generator.randrange(offset, len(data))
            data[at] = generator.randrange(256)
        variants.append((f"seeded byte flips #{index}", bytes(data)))
    workspace = workspace_with_world(folder)
    server = Served(workspace)
    codes: Counter[int] = Counter()
    crashed = 0
    try:
        for index, (_, data) in enumerate(variants):
            reply = server.request("POST", "/api/datasets/upload", headers=server.own(), data={"name": f"laz{index}"},
                                   files=[("files", ("scan.laz", data))])
            codes[reply.status_code] += 1
            crashed += "reader crashed" in str(reply.json().get("detail", ""))
            if not server.alive():
                break
        alive = server.alive()
        rss = server.peak_rss()
    finally:
        server.stop()
    return {"attack": "corrupt .laz uploads", "variants": f"{len(variants)} (truncations, chunk table pointers, "
            "seeded byte flips of a valid 20,000-point LAZ)", "tried": sum(codes.values()),
            "outcome": f"answers {dict(sorted(codes.items()))}, {crashed} with the reader crashed in the inspecting "
                       f"process; server alive after all: {alive}; server peak RSS {rss / (1 << 20):.0f} MiB",
            "held": alive and sum(codes.values()) == len(variants)}


def table(rows: list[dict[str, Any]]) -> str:
    lines = ["| attack | variants tried | cases | outcome | held |", "|---|---|---|---|---|"]
    for row in rows:
        lines.append(f"| {row['attack']} | {row['variants']} | {row['tried']} | {row['outcome']} | "
                     f"{'yes' if row['held'] else '**no**'} |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--write-doc", action="store_true", help="rewrite the `web` section of docs/reliability.md")
    parser.add_argument("--laz", type=int, default=30, help="corrupt LAZ uploads (default 30)")
    args = parser.parse_args()
    folder = Path(tempfile.mkdtemp(prefix="web-attacks-"))
    started = time.perf_counter()
    try:
        rows: list[dict[str, Any]] = [cross_site(folder)]
        rows += zip_bombs(folder)
        rows.append(token_in_logs(folder))
        rows += binding(folder)
        rows.append(ids(folder))
        rows += names(folder)
        rows.append(corrupt_laz(folder, args.laz))
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    took = time.perf_counter() - started
    text = table(rows)
    print(text)
    held = sum(1 for row in rows if row["held"])
    print(f"\n{held} of {len(rows)} held, {sum(r['tried'] for r in rows)} requests or cases, {took:.0f} s")
    if args.write_doc:
        from benchmarks.reliability_doc import provenance, write_section

        command = "python benchmarks/web_attacks.py --write-doc" + (f" --laz {args.laz}" if args.laz != 30 else "")
        write_section("web", "\n".join([
            provenance(command), "",
            "Each attack of issue 23 against a real `lidarfuzz serve` subprocess (a fresh workspace with a data set, "
            "a model and a queued task; `--workers 0`; log level info). *Held*: every variant got the refusal or "
            "answer the rules in [web.md](web.md#security) give, nothing in the workspace changed, and the server "
            "kept answering.", "",
            text, "",
            f"{held} of {len(rows)} held; {sum(r['tried'] for r in rows)} requests or cases in {took:.0f} s. The same "
            "attacks, one test each, are `tests/web/test_attacks.py`."]))


if __name__ == "__main__":
    main()
