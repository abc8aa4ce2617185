"""experiments/neves_tables.py: the tables' percentages from hand-made coverage of a hand-counted
function, and the whole experiment on a short simulator log (12 VLP-16 frames, about 5 s)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

from lidarfuzz.structural.requirements import Requirement

ROOT = Path(__file__).resolve().parents[2]
SIGN = "tests.structural.sample_code:sign"


def load_script() -> ModuleType:
    spec = importlib.util.spec_from_file_location("neves_tables", ROOT / "experiments" / "neves_tables.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules["neves_tables"] = module  # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def test_the_tables_read_each_column_as_covered_over_the_functions_requirements() -> None:
    script = load_script()
    # sign() has 4 nodes (22, 23, 25, 26) and 6 edges (tests/structural/sample_code.py)
    node = [Requirement(SIGN, "node", n) for n in (22, 23, 25, 26)]
    edge = [Requirement(SIGN, "edge", a, b) for a, b in ((-21, 22), (22, 23), (22, 25), (23, 26), (25, 26), (26, -21))]
    positive = frozenset(node[:2] + node[3:] + [edge[0], edge[1], edge[3], edge[5]])  # x > 0: 3 nodes, 4 edges
    both = frozenset(node + edge)
    first = script.LogResult("a", 10, 2, {"FT": both, "h-Base": positive}, {"h": (1, 5)}, 0.0)
    second = script.LogResult("b", 10, 2, {"FT": positive, "h-Base": frozenset()}, {"h": (1, 5)}, 0.0)
    lines = script.tables([first, second], [SIGN], ["FT", "h-Base"])
    text = "\n".join(lines)
    # nodes: a 4/4 = 100 %, 3/4 = 75 %; b 75 %, 0 %; average 87.5 -> "88 %" and 37.5 -> "38 %"
    assert "| a | 100 % | 75 % |" in text and "| b | 75 % | 0 % |" in text
    assert "| **average** | **88 %** | **38 %** |" in text
    # edges: a 6/6, 4/6 = 67 %; b 67 %, 0 %; average 83 %, 33 %
    assert "| a | 100 % | 67 % |" in text and "| **average** | **83 %** | **33 %** |" in text
    assert "(4 requirements)" in text and "(6 requirements)" in text


def test_the_experiment_on_a_short_log(tmp_path: Path) -> None:
    from lidarfuzz.sim.dataset import GenerationConfig, generate_dataset

    script = load_script()
    log = tmp_path / "drive"
    generate_dataset(log, GenerationConfig(frames=12, seed=1, sequence=True, sensor="VLP-16"), workers=1)
    out = tmp_path / "page.md"
    script.main(["--log", str(log), "--size", "3", "--out", str(out)])
    text = out.read_text()
    assert text.count("**Table") == 4 and "greedy_edges-Agg-HGT" in text
    # aggregated columns are unions with the base: never below it (Table 1's one row)
    row = next(line for line in text.splitlines() if line.startswith("| drive |"))
    cells = [float(c.strip(" %*")) for c in row.split("|")[2:-1]]
    assert cells[2] >= cells[1] and cells[3] >= cells[1]
