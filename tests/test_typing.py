"""The README's promise that the package type-checks: mypy over ``src/`` with the project's own
configuration (``[tool.mypy]`` in pyproject.toml) reports no error."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_mypy_clean() -> None:
    result = subprocess.run([sys.executable, "-m", "mypy", "--config-file", "pyproject.toml", "src"], cwd=ROOT,
                            capture_output=True, text=True, timeout=900)
    errors = [line for line in result.stdout.splitlines() if ": error:" in line]
    assert result.returncode == 0, "\n".join(errors) or result.stdout + result.stderr
