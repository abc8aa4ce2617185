"""DeepTest's Table 7 in a task's summary and report, from hand-made subtask figures.

MSE_orig = 0.05 m², the relation's λ = 5 and ε = 0.03; Table 7's grid (λ = 1 … 10; ε = 0.01, 0.02,
0.03, 0.04, 0.05, 0.1, 0.2, 0.5, 1, 2):

    op_a@1: MSE_t 0.065 (|Δ| = 0.015: kept from ε = 0.02), erroneous per λ 5 4 3 2 1 0 0 0 0 0
    op_b@2: MSE_t 0.3   (|Δ| = 0.25:  kept from ε = 0.5),  erroneous per λ 9 8 7 6 5 4 3 2 1 0
    op_c@1: judged against each frame's own error: left out, with a note

    λ = 1:  0 5 5 5 5 5 5 14 14 14   (no filter 14)
    λ = 5:  0 1 1 1 1 1 1  6  6  6   (no filter 6)
    λ = 10: all 0
"""

from __future__ import annotations

from lidarfuzz.campaign.results import deeptest_table
from lidarfuzz.report.deeptest import deeptest_lines, deeptest_view
from lidarfuzz.report.html import _environment
from lidarfuzz.store.contracts import DeepTestErrors, SubtaskResults, SubtaskSummary, TaskSummary

LAMBDAS = [float(k) for k in range(1, 11)]


def subtask(index: int, operator: str, severity: int, mse: float, erroneous: list[int], origin: str = "data set",
            mse_orig: float = 0.05) -> SubtaskSummary:
    errors = DeepTestErrors(mse_orig=mse_orig, mse_orig_from=origin, mse=mse, objects=20, mutants=10,
                            violated=erroneous[4], lambdas=LAMBDAS, erroneous=erroneous, configured_lambda=5.0,
                            configured_epsilon=0.03)
    return SubtaskSummary(id=index, label=f"{operator}@{severity}", operator=operator, severity=severity,
                          status="done", deeptest=errors)


SUBTASKS = [
    subtask(2, "op_a", 1, 0.065, [5, 4, 3, 2, 1, 0, 0, 0, 0, 0]),
    subtask(3, "op_b", 2, 0.3, [9, 8, 7, 6, 5, 4, 3, 2, 1, 0]),
    subtask(4, "op_c", 1, 0.2, [3, 3, 3, 3, 3, 3, 3, 3, 3, 3], origin="frame", mse_orig=0.01),
]


def test_table_7_over_hand_made_subtasks() -> None:
    table = deeptest_table(SUBTASKS)
    assert table is not None
    assert table.mse_orig == 0.05 and table.configured_lambda == 5.0 and table.configured_epsilon == 0.03
    assert table.epsilons == [0.01, 0.02, 0.03, 0.04, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0]
    assert table.counts[0] == [0, 5, 5, 5, 5, 5, 5, 14, 14, 14] and table.unfiltered[0] == 14
    assert table.counts[4] == [0, 1, 1, 1, 1, 1, 1, 6, 6, 6] and table.unfiltered[4] == 6
    assert table.counts[9] == [0] * 10 and table.unfiltered[9] == 0
    kept = {t.label: t.kept for t in table.transformations}
    assert kept == {"op_a@1": True, "op_b@2": False, "op_c@1": False}
    assert any("each frame's own error" in note for note in table.notes)
    assert deeptest_table([SubtaskSummary(id=1, label="x@1", operator="x")]) is None
    # a search judges each test by its seed's own error: no table, only the note saying why
    alone = deeptest_table(SUBTASKS[2:])
    assert alone is not None and alone.counts == [] and alone.unfiltered == [] and alone.notes
    assert deeptest_view(alone)["rows"] == []  # type: ignore[index]


def test_the_report_shows_mse_orig_and_the_table() -> None:
    table = deeptest_table(SUBTASKS)
    lines = deeptest_lines(table)
    assert "MSE_orig = 0.05 m²" in lines[0] and "λ = 5, ε = 0.03" in lines[0]
    row5 = next(line.split() for line in lines if line.split()[:1] == ["5"])
    assert row5 == ["5", "0", "1", "1", "1", "1", "1", "1", "6", "6", "6", "6"]
    assert any(line.strip().startswith("op_b@2") and "dropped by ε = 0.03" in line for line in lines)
    view = deeptest_view(table)
    assert view is not None and view["configured_column"] == 2
    html = _environment().get_template("deeptest.html.j2").render(deeptest=view)
    assert "MSE_orig = 0.05 m²" in html and 'class="l2">1</td>' in html  # the relation's own cell, marked
    assert deeptest_lines(None) == [] and deeptest_view(None) is None


def test_summaries_stored_before_the_table_still_read() -> None:
    old = {"task": {"id": 1, "status": "done", "dataset": {"name": "d", "path": "p", "format": "kitti"},
                    "model": {"name": "m", "spec": "classic", "fingerprint": "f"}},
           "classes": ["Car"], "subtasks": [{"id": 1, "label": "original", "operator": "original"}]}
    summary = TaskSummary.model_validate(old)
    assert summary.deeptest is None and summary.subtasks[0].deeptest is None
    assert SubtaskResults.model_validate({"frames": 3}).deeptest is None
