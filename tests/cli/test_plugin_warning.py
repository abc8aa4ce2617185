"""A broken third-party plugin, met by the command line: one line on stderr naming its entry point,
not Python's two-line warning (file:line: category: message, then the source line)."""

from __future__ import annotations

import subprocess
import sys

BROKEN = "lidarfuzz_no_such_package.module:Thing"

# The real entry point (as the ``lidarfuzz`` script runs it), with one broken entry point declared
# beside the installed operators, as a package installed with a bad ``pyproject.toml`` would be.
WITH_BROKEN_PLUGIN = f"""
from importlib.metadata import EntryPoint
import lidarfuzz.plugins as plugins
installed = plugins.entry_points
broken = EntryPoint(name="broken_op", value="{BROKEN}", group="lidarfuzz.operators")
plugins.entry_points = lambda group: [*installed(group=group), *([broken] if group == broken.group else [])]
from lidarfuzz.cli.app import main
main()
"""


def test_a_broken_plugin_is_one_warning_line_on_stderr():
    result = subprocess.run([sys.executable, "-c", WITH_BROKEN_PLUGIN, "operators"],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert result.stderr == (
        f"lidarfuzz: warning: plugin broken_op = {BROKEN} (group lidarfuzz.operators) left out: "
        "ModuleNotFoundError: No module named 'lidarfuzz_no_such_package'\n")
    assert "outside_roi_scatter" in result.stdout  # the installed operators are still listed
