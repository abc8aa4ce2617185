"""A structural task's report: report.json carries every number, the HTML shows the tables and views.

The task is the six-frame one of :mod:`tests.campaign.test_structural` (numbers worked out there):
Gate.step's all-nodes 75 % on the FT log and its base, 100 % aggregated with HGT, 75 % with AVG.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from lidarfuzz.report import write_report
from lidarfuzz.store.store import Store
from tests.campaign.test_structural import TARGET, campaign, run, write_log


def test_the_report_of_a_structural_task(tmp_path: Path) -> None:
    store = Store(tmp_path / "ws")
    task_id, _ = run(store, campaign(write_log(tmp_path / "drive")))
    files = write_report(store, task_id, tmp_path / "report", images=0)
    data = json.loads(Path(files.json).read_text(encoding="utf-8"))
    figures = data["kind_summary"]
    nodes = next(t for t in figures["tables"] if t["function"] == TARGET and t["criterion"] == "node")
    assert nodes["rows"][0]["values"] == [0.75, 0.75, 1.0, 0.75]
    assert figures["relations"]["safety"] == {"checked": 11, "violated": 3}
    page = Path(files.html).read_text(encoding="utf-8")
    assert 'id="structural"' in page and "all-nodes of tests.campaign.structural_system:Gate.step" in page
    # the FT log's row: 75 % (FT), 75 % (base), 100 % (agg HGT), 75 % (agg AVG)
    assert "<td>75.0 %</td><td>75.0 %</td><td>100.0 %</td><td>75.0 %</td>" in page
    assert 'class="lf-cov-source"' in page and "lf-cov-compare" in page
    if shutil.which("dot"):
        assert "<svg" in page
    assert page.count("speed ") >= 3  # the three safety findings' messages


@pytest.mark.skipif(shutil.which("dot") is None, reason="Graphviz's dot is not installed")
def test_every_log_together_reaches_the_if_branch_in_the_graph(tmp_path: Path) -> None:
    from lidarfuzz.campaign.results import summarise
    from lidarfuzz.report.structural import structural_view

    store = Store(tmp_path / "ws")
    task_id, _ = run(store, campaign(write_log(tmp_path / "drive")))
    view = structural_view(summarise(store, task_id))
    assert view is not None and view["views"] is not None
    [function] = view["views"]["functions"]
    # with the HGT log every block ran: no missed line in the source, no dashed edge in the graph
    assert 'class="missed"' not in function["source"] and "dashed" not in function["cfg"]
