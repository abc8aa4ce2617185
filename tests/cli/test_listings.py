"""Listings a user pipes or reads in a narrow terminal keep every name whole; ``--json`` and
``--plain`` give scripts the same rows; the CLI's help texts agree with the library; the ``web``
and ``postgres`` extras are named when they are missing."""

from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

from lidarfuzz.cli.app import app
from lidarfuzz.operators import available as operators
from lidarfuzz.oracles.relations import available as relations
from lidarfuzz.suts.registry import available as suts

runner = CliRunner()
NARROW = {"COLUMNS": "40"}


def invoke(*args: str, env: dict[str, str] | None = None) -> Any:
    result = runner.invoke(app, list(args), env=env or NARROW)
    assert result.exit_code == 0, result.output
    return result


@pytest.mark.parametrize(("command", "names"), [
    (["operators"], lambda: operators()),
    (["relations"], lambda: relations()),
    (["suts"], lambda: suts()),
])
def test_a_narrow_listing_keeps_every_name_whole(command: list[str], names: Any) -> None:
    output = invoke(*command).output
    expected = sorted(names())
    assert "random_region_noise_addition" in expected or command != ["operators"]
    cut = [name for name in expected if name not in output]
    assert not cut, f"names cut in a 40-column listing: {cut}"
    assert "…" not in "".join(line.split("│")[1] for line in output.splitlines() if line.count("│") > 2)


@pytest.mark.parametrize("command", [["operators"], ["relations"], ["suts"]])
def test_plain_and_json_list_the_same_rows(command: list[str]) -> None:
    plain = invoke(*command, "--plain").output.splitlines()
    records = json.loads(invoke(*command, "--json").output)
    assert len(plain) == len(records) > 0
    key = "spec" if command == ["suts"] else "name"
    assert [line.split("\t")[0] for line in plain] == [r[key] for r in records]
    assert all("\t" in line and "│" not in line for line in plain)
    assert runner.invoke(app, [*command, "--json", "--plain"]).exit_code == 2


def test_operators_json_holds_structured_fields() -> None:
    records = {r["name"]: r for r in json.loads(invoke("operators", "--json").output)}
    assert set(records) == set(operators())
    fog = records["fog"]
    assert fog["family"] and fog["relation"] == "degrading" and isinstance(fog["targets"], list)
    assert fog["modality"] == "lidar" and records["image_fog"]["modality"] == "camera"
    camera = {r["name"] for r in json.loads(invoke("operators", "--modality", "camera", "--json").output)}
    assert camera == {name for name, cls in operators().items() if cls.modality == "camera"} and "fog" not in camera
    assert set(fog["severities"]) >= {"1", "5"}
    one = json.loads(invoke("operators", "RAR", "--json").output)
    assert one["name"] == "rotate_z" and "RAR" in one["aliases"] and one["doc"]
    assert any(p["name"] == "angle_range" for p in one["parameters"])
    relation = json.loads(invoke("relations", "preservation", "--json").output)
    assert relation["name"] == "preservation" and relation["parameters"]


def test_store_listings_in_a_narrow_terminal_and_as_json(tmp_path: Path, kitti_log: Path) -> None:
    ws = ["--workspace", str(tmp_path / "ws")]
    name = "a_data_set_with_a_rather_long_name_for_a_narrow_terminal"
    assert runner.invoke(app, ["datasets", "add", name, str(kitti_log), *ws]).exit_code == 0
    assert runner.invoke(app, ["models", "add", "classic_pipeline_with_a_long_name", "classic", *ws]).exit_code == 0
    assert name in invoke("datasets", "list", *ws).output
    assert "classic_pipeline_with_a_long_name" in invoke("models", "list", *ws).output
    datasets = json.loads(invoke("datasets", "list", "--json", *ws).output)
    assert datasets[0]["name"] == name and datasets[0]["frames"] == 3 and datasets[0]["path"] == str(kitti_log)
    models = json.loads(invoke("models", "list", "--json", *ws).output)
    assert [(m["name"], m["spec"]) for m in models] == [("classic_pipeline_with_a_long_name", "classic")]
    plain = invoke("models", "list", "--plain", *ws).output.splitlines()
    assert plain[0].split("\t")[:2] == ["classic_pipeline_with_a_long_name", "classic"]
    assert json.loads(invoke("list", "--json", *ws).output) == []


def test_a_piped_table_is_as_wide_as_its_content() -> None:
    """What `lidarfuzz operators | grep …` sees: whole rows, each on one line, whatever COLUMNS says."""
    output = invoke("operators").output
    row = next(line for line in output.splitlines() if "random_region_noise_addition" in line)
    assert "RRNA" in row or "random_region_noise_addition" in row
    assert all(len(line) > 40 for line in output.splitlines() if line.startswith("│"))


def test_a_narrow_terminal_shows_every_name_whole(monkeypatch: pytest.MonkeyPatch) -> None:
    """In a 40-column terminal the name column keeps its width; the other columns give way."""
    import io

    from rich.console import Console

    import lidarfuzz.cli.common as common

    screen = io.StringIO()
    monkeypatch.setattr(common, "console", Console(file=screen, force_terminal=True, width=40, color_system=None))
    names = sorted(operators())
    common.print_listing([common.Column("name", name=True), common.Column("family"), common.Column("changes")],
                         [[name, "points", "points, boxes, calibration"] for name in names], [])
    lines = screen.getvalue().splitlines()
    assert max(len(line) for line in lines) <= 40
    assert all(any(name in line for line in lines) for name in names)


def test_help_texts_list_what_the_library_has() -> None:
    from lidarfuzz.cli.convert import TARGETS
    from lidarfuzz.cli.gen import SENSOR_PRESETS
    from lidarfuzz.io.convert import FOLDER_TARGETS, LOG_TARGETS
    from lidarfuzz.sim.sensor import preset_names

    assert (*FOLDER_TARGETS, *LOG_TARGETS) == TARGETS
    assert tuple(preset_names()) == SENSOR_PRESETS


def test_help_imports_no_heavy_library() -> None:
    """`lidarfuzz --help` loads Typer, Rich and the commands' signatures: no numpy, engine or web server
    (the table of task kinds, which ``run --kind`` lists, is the engine's one module meant to be read
    at start-up: it imports nothing)."""
    code = ("import sys; from lidarfuzz.cli.app import main; sys.argv = ['lidarfuzz', '--help']\n"
            "try:\n    main()\nexcept SystemExit:\n    pass\n"
            "heavy = ('numpy', 'scipy', 'torch', 'sqlalchemy', 'fastapi', 'pydantic', 'lidarfuzz.io', "
            "'lidarfuzz.campaign', 'lidarfuzz.store', 'importlib.metadata')\n"
            "table = ('lidarfuzz.campaign', 'lidarfuzz.campaign.kinds')\n"
            "print(sorted(m for m in sys.modules if m not in table and (m.split('.')[0] in heavy or m in heavy "
            "or any(m.startswith(h + '.') for h in heavy))))")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip().splitlines()[-1] == "[]"


# -- extras -------------------------------------------------------------------------------------
def _without(monkeypatch: pytest.MonkeyPatch, *modules: str) -> None:
    """Make ``modules`` look uninstalled to the extras checks (they ask find_spec)."""
    real = importlib.util.find_spec

    def find_spec(name: str, *args: Any, **kwargs: Any) -> Any:
        return None if name in modules else real(name, *args, **kwargs)

    import lidarfuzz.cli.common as common
    import lidarfuzz.cli.serve as serve

    monkeypatch.setattr(common, "find_spec", find_spec)
    monkeypatch.setattr(serve, "find_spec", find_spec)


def test_serve_without_the_web_extra_names_it(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    _without(monkeypatch, "fastapi", "uvicorn")
    result = runner.invoke(app, ["serve", "--workspace", str(tmp_path / "ws")])
    assert result.exit_code != 0
    message = str(result.exception)
    assert "pip install 'lidarfuzz[web]'" in message and "fastapi" in message and "\n" not in message
    assert not (tmp_path / "ws").exists()


def test_a_postgresql_store_without_the_driver_names_the_extra(monkeypatch: pytest.MonkeyPatch) -> None:
    _without(monkeypatch, "psycopg", "psycopg2")
    for url in ("postgresql+psycopg://u@localhost/db", "postgresql://u@localhost/db"):
        result = runner.invoke(app, ["list", "--workspace", url])
        assert result.exit_code != 0
        assert "pip install 'lidarfuzz[postgres]'" in str(result.exception), str(result.exception)


def test_the_extras_message_is_one_line_from_the_entry_point(tmp_path: Path) -> None:
    """The real entry point with fastapi made unimportable: exit 2, one line naming the extra."""
    code = ("import importlib.util, sys\n"
            "real = importlib.util.find_spec\n"
            "import lidarfuzz.cli.serve as serve\n"
            "serve.find_spec = lambda name, *a, **k: None if name == 'fastapi' else real(name, *a, **k)\n"
            "from lidarfuzz.cli.app import main\n"
            "sys.argv = ['lidarfuzz', 'serve', '--workspace', sys.argv[1]]\n"
            "main()\n")
    result = subprocess.run([sys.executable, "-c", code, str(tmp_path / "ws")], capture_output=True, text=True,
                            timeout=60)
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "pip install 'lidarfuzz[web]'" in lines[0]


BLOCK_EXTRAS = """
import importlib.abc, sys
BLOCKED = {"fastapi", "starlette", "uvicorn", "python_multipart", "multipart", "psycopg", "psycopg2", "httpx"}
class Uninstalled(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in BLOCKED:
            raise ModuleNotFoundError(f"No module named {name!r}", name=name)
        return None
sys.meta_path.insert(0, Uninstalled())
import importlib.util
real = importlib.util.find_spec
importlib.util.find_spec = lambda name, *a, **k: None if name.split(".")[0] in BLOCKED else real(name, *a, **k)
from lidarfuzz.cli.app import main
sys.argv = ["lidarfuzz", *sys.argv[1:]]
main()
"""


def test_the_core_runs_a_campaign_without_the_web_and_postgres_extras(kitti_log: Path, tmp_path: Path) -> None:
    """What `pip install lidarfuzz` (no extras) gives: a campaign and its report, with FastAPI,
    Uvicorn, python-multipart and psycopg unimportable; `serve` then names the web extra."""
    def cli(*args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run([sys.executable, "-c", BLOCK_EXTRAS, *args], capture_output=True, text=True,
                              timeout=300, env={**os.environ, "COLUMNS": "160"})

    ws = ["--workspace", str(tmp_path / "ws")]
    run = cli("run", "--dataset", str(kitti_log), "--sut", "classic", "--op", "fog@1", "--frames", "1",
              "--inline", *ws)
    assert run.returncode == 0, run.stdout + run.stderr
    assert (tmp_path / "ws" / "reports" / "task-1" / "report.html").is_file()
    serve = cli("serve", *ws)
    assert serve.returncode == 2 and serve.stderr.strip().count("\n") == 0
    assert "pip install 'lidarfuzz[web]'" in serve.stderr
    store = cli("list", "--workspace", "postgresql+psycopg://nobody@localhost/none")
    assert store.returncode == 2 and "pip install 'lidarfuzz[postgres]'" in store.stderr


@pytest.mark.parametrize("plain", [False, True])
def test_names_with_terminal_escapes_are_listed_escaped(plain: bool, capsys: pytest.CaptureFixture[str]) -> None:
    # a name stored before names were checked (or a task's name from a campaign file): ESC ] 0 ; … BEL
    # would retitle the user's terminal; the listing shows the characters as \x1b and \x07 instead
    from lidarfuzz.cli.common import Column, print_listing

    evil = "drive" + chr(27) + "]0;pwned" + chr(7)
    print_listing([Column("name", name=True)], [[evil]], [{"name": evil}], plain=plain)
    out = capsys.readouterr().out
    assert chr(27) not in out and chr(7) not in out
    assert "drive\\x1b]0;pwned\\x07" in out
