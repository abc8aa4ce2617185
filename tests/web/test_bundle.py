"""The committed front-end bundle (``src/lidarfuzz/web/static``) is built from the committed sources
(``web/frontend``): ``static/build.json`` records a sha256 of the sources, which this test recomputes
exactly as ``web/frontend/build.mjs`` does, and a sha256 of every built file (no Node needed); and,
with Node and the front end's packages (marker ``node``), that a fresh build writes the committed
files byte for byte."""

from __future__ import annotations

import hashlib
import json
import shutil
import subprocess
from pathlib import Path

import pytest

from tests.requirements import missing

ROOT = Path(__file__).resolve().parents[2]
FRONTEND = ROOT / "web" / "frontend"
STATIC = ROOT / "src" / "lidarfuzz" / "web" / "static"
REBUILD = "cd web/frontend && npm ci && npm run build"


def source_files() -> list[str]:
    """src/**, build.mjs, package.json and package-lock.json, relative to web/frontend, sorted by UTF-8 bytes."""
    files = [p.relative_to(FRONTEND).as_posix() for p in (FRONTEND / "src").rglob("*") if p.is_file()]
    files += ["build.mjs", "package.json", "package-lock.json"]
    return sorted(files, key=lambda path: path.encode())


def source_hash() -> str:
    """For each file: its path, NUL, its byte length in decimal, NUL, its bytes."""
    digest = hashlib.sha256()
    for path in source_files():
        data = (FRONTEND / path).read_bytes()
        digest.update(path.encode())
        digest.update(b"\0")
        digest.update(str(len(data)).encode())
        digest.update(b"\0")
        digest.update(data)
    return digest.hexdigest()


@pytest.fixture(scope="module")
def build() -> dict:
    path = STATIC / "build.json"
    assert path.is_file(), f"{path} is missing: build the front end ({REBUILD})"
    return json.loads(path.read_text())


def test_bundle_is_built_from_the_committed_sources(build: dict) -> None:
    assert build["sources"] == source_files(), f"the front end's files changed: rebuild ({REBUILD})"
    assert build["source_sha256"] == source_hash(), f"static/ is older than web/frontend: rebuild ({REBUILD})"


def test_built_files_are_the_ones_recorded(build: dict) -> None:
    files = [p for p in STATIC.rglob("*") if p.is_file() and p.name != "build.json"]
    on_disk = sorted(p.relative_to(STATIC).as_posix() for p in files)
    assert on_disk == sorted(build["files"]), "static/ holds files the build did not write, or lacks some: rebuild"
    for path, sha in build["files"].items():
        assert hashlib.sha256((STATIC / path).read_bytes()).hexdigest() == sha, f"static/{path} was edited by hand"


def test_bundle_is_complete_and_offline(build: dict) -> None:
    index = (STATIC / "index.html").read_text()
    assert '<script type="module" src="/static/app.js">' in index
    assert '<link rel="stylesheet" href="/static/app.css"' in index
    for path in ("app.js", "app.css", "vendor/swagger-ui/swagger-ui-bundle.js", "vendor/swagger-ui/swagger-ui.css"):
        assert (STATIC / path).is_file(), path
    viewer = [p for p in build["files"] if p.startswith("chunks/viewer-") and p.endswith(".js")]
    assert len(viewer) == 1, "the viewer (three.js) is its own lazily loaded chunk"
    # nothing fetched from elsewhere at run time: no CDN, no web fonts
    for path in build["files"]:
        if path.endswith((".html", ".css")) or (path.endswith(".js") and "vendor/" not in path):
            text = (STATIC / path).read_text(errors="replace")
            for needle in ("cdn.jsdelivr", "unpkg.com", "cdnjs", "fonts.googleapis", "@import url(http"):
                assert needle not in text, f"static/{path} refers to {needle}"
    assert build["versions"]["three"] and build["versions"]["swagger-ui-dist"]


def test_bundle_is_lean(build: dict) -> None:
    own = sum((STATIC / p).stat().st_size for p in build["files"] if not p.startswith("vendor/"))
    assert own < 900_000, f"the app and viewer weigh {own} bytes: is three.js tree-shaken and minified?"


@pytest.mark.node
def test_the_bundle_rebuilds_byte_for_byte(tmp_path: Path) -> None:
    """`npm run build` on the committed sources writes exactly the committed static/ (no network:
    the packages come from web/frontend/node_modules, which `npm ci` installs; .ci/run does)."""
    if shutil.which("node") is None:
        missing("node is not on PATH", "the Debian package nodejs")
    modules = FRONTEND / "node_modules"
    if not all((modules / name / "package.json").is_file() for name in ("esbuild", "three", "swagger-ui-dist")):
        missing(f"{modules} lacks esbuild, three or swagger-ui-dist", "the front end's packages (cd web/frontend "
                                                                      "&& npm ci)")
    lock = json.loads((FRONTEND / "package-lock.json").read_text())
    for name in ("esbuild", "three", "swagger-ui-dist"):
        installed = json.loads((modules / name / "package.json").read_text())["version"]
        assert installed == lock["packages"][f"node_modules/{name}"]["version"], \
            f"node_modules/{name} is {installed}, not the locked version: cd web/frontend && npm ci"
    # build.mjs writes to ../../src/lidarfuzz/web/static from where it lies: a copy of the sources
    # in the same layout under tmp_path leaves the committed bundle alone
    frontend = tmp_path / "web" / "frontend"
    frontend.mkdir(parents=True)
    shutil.copytree(FRONTEND / "src", frontend / "src")
    for name in ("build.mjs", "package.json", "package-lock.json"):
        shutil.copy2(FRONTEND / name, frontend / name)
    shutil.copytree(modules, frontend / "node_modules", symlinks=True)  # a link would change the chunk hashes
    result = subprocess.run(["node", "build.mjs"], cwd=frontend, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stdout + result.stderr
    built = tmp_path / "src" / "lidarfuzz" / "web" / "static"

    def tree(root: Path) -> dict[str, str]:
        return {p.relative_to(root).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
                for p in sorted(root.rglob("*")) if p.is_file()}

    rebuilt, committed = tree(built), tree(STATIC)
    assert sorted(rebuilt) == sorted(committed), "the build writes other files than static/ holds: rebuild"
    differ = [path for path in committed if rebuilt[path] != committed[path]]
    assert not differ, f"static/ differs from a fresh build in {differ}: rebuild ({REBUILD})"
