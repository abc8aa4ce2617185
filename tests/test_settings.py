"""The settings object: every LIDARFUZZ_* variable, its default, and one-line errors naming a bad one."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

import lidarfuzz.settings
from lidarfuzz.settings import LOG_LEVELS, VARIABLES, Settings, SettingsError, settings

SRC = Path(__file__).resolve().parents[1] / "src" / "lidarfuzz"


def test_defaults_when_nothing_is_set() -> None:
    env = Settings({})
    assert env.workspace == "lidarfuzz-workspace"
    assert env.cache == Path.home() / ".cache" / "lidarfuzz"
    assert env.token is None
    assert env.log_level == "warning"


def test_values_are_read_and_empty_ones_count_as_unset(tmp_path: Path) -> None:
    env = Settings({"LIDARFUZZ_WORKSPACE": "postgresql+psycopg://db//x", "LIDARFUZZ_CACHE": str(tmp_path),
                    "LIDARFUZZ_TOKEN": "s3cret", "LIDARFUZZ_LOG_LEVEL": "DEBUG", "HOME": "/elsewhere"})
    assert env.workspace == "postgresql+psycopg://db//x"  # text: a Path would fold the URL's "//"
    assert env.cache == tmp_path
    assert env.token == "s3cret"
    assert env.log_level == "debug"
    assert "HOME" not in env.environ  # only lidarfuzz's own variables are kept
    empty = Settings({"LIDARFUZZ_WORKSPACE": "", "LIDARFUZZ_CACHE": " ", "LIDARFUZZ_TOKEN": ""})
    assert (empty.workspace, empty.cache, empty.token) == (Settings({}).workspace, Settings({}).cache, None)


def test_settings_reads_the_environment_when_called(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setenv("LIDARFUZZ_CACHE", str(tmp_path / "a"))
    first = settings()
    monkeypatch.setenv("LIDARFUZZ_CACHE", str(tmp_path / "b"))
    assert first.cache == tmp_path / "a"  # a snapshot
    assert settings().cache == tmp_path / "b"


def test_the_cache_users_follow_the_variable(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    from lidarfuzz.coverage.profile import cache_dir
    from lidarfuzz.operators.lidar.objects.insertion import _cache_dir

    monkeypatch.setenv("LIDARFUZZ_CACHE", str(tmp_path))
    assert cache_dir() == tmp_path / "profiles"
    assert _cache_dir() == tmp_path


@pytest.mark.parametrize("value", ["loud", "3", "warn ing"])
def test_a_bad_log_level_is_one_line_naming_the_variable(value: str) -> None:
    env = Settings({"LIDARFUZZ_LOG_LEVEL": value})
    with pytest.raises(SettingsError) as caught:
        _ = env.log_level
    message = str(caught.value)
    assert "\n" not in message
    assert message.startswith(f"LIDARFUZZ_LOG_LEVEL={value!r} is not a log level")
    assert all(level in message for level in LOG_LEVELS)
    assert env.workspace == "lidarfuzz-workspace"  # a bad value fails only what reads it


def test_serve_refuses_a_bad_log_level_in_one_line(tmp_path: Path) -> None:
    code = "import sys; from lidarfuzz.cli.app import main; sys.argv = ['lidarfuzz', *sys.argv[1:]]; main()"
    env = {"PATH": "/usr/bin:/bin", "HOME": str(tmp_path), "LIDARFUZZ_LOG_LEVEL": "loud"}
    result = subprocess.run([sys.executable, "-c", code, "serve", "--workspace", str(tmp_path / "ws")],
                            capture_output=True, text=True, timeout=120, env=env)
    assert result.returncode == 2, result.stdout + result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "LIDARFUZZ_LOG_LEVEL='loud'" in lines[0]
    assert not (tmp_path / "ws").exists()  # refused before anything was opened


def test_every_variable_the_code_names_is_documented_and_read_through_settings() -> None:
    named: set[str] = set()
    direct: list[str] = []
    for path in sorted(SRC.rglob("*.py")):
        text = path.read_text(encoding="utf-8")
        named |= set(re.findall(r"\bLIDARFUZZ_[A-Z0-9_]+\b", text))
        if path.name != "settings.py" and re.search(r"(environ\b[^\n]*|getenv\(|envvar=)[\"']LIDARFUZZ_", text):
            direct.append(str(path.relative_to(SRC)))
    assert named <= set(VARIABLES), f"undocumented: {sorted(named - set(VARIABLES))}"
    assert direct == [], "read LIDARFUZZ_* through lidarfuzz.settings"
    table = lidarfuzz.settings.__doc__ or ""
    for variable in VARIABLES.values():
        assert variable.meaning and f"``{variable.name}``" in table
