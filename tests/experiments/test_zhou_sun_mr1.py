"""experiments/zhou_sun_mr1.py: the experiment runs end to end on a few frames and its report has the
paper's structure; the correct classic pipeline shows no MR1 violation where that holds by construction.

Why zero by construction: the classic pipeline's first stage keeps only points within 3 m of the
map's drivable area (its ``roi_margin``), and ``outside_roi_scatter`` places its points outside the
drivable area grown by the same 3 m (its ``margin_m``). The filter reads a 0.25 m raster whose cells
are inside when their centre is, so a scattered point within half a cell's diagonal (0.18 m) of that
edge can slip through; when none does, the pipeline's input after the filter is the original's,
point for point, and the pipeline is deterministic, so its output is the original's and no form of
MR1 can be violated. The test checks that premise on its frames (every scattered point dropped),
then the conclusion (zero violations in every form and class).
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

import pytest
from sqlalchemy import select

ROOT = Path(__file__).resolve().parents[2]


def load_script() -> ModuleType:
    spec = importlib.util.spec_from_file_location("zhou_sun_mr1", ROOT / "experiments" / "zhou_sun_mr1.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules["zhou_sun_mr1"] = module  # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def test_options_are_checked() -> None:
    script = load_script()
    with pytest.raises(SystemExit):
        script.parse_args(["--frames", "10", "--world-frames", "5"])
    with pytest.raises(SystemExit):
        script.parse_args(["--n", "0"])
    args = script.parse_args(["--frames", "7", "--n", "100", "10", "100"])
    assert (args.world_frames, args.n) == (14, [10, 100])
    # the classic family reports unknown obstacles unless told otherwise; other systems get nothing added
    assert script.sut_options("classic-bug-intensity-norm", []) == {"report_unknown": True}
    assert script.sut_options("classic", ["report_unknown=false"]) == {"report_unknown": False}
    assert script.sut_options("pillars", []) == {}


@pytest.mark.slow
def test_classic_on_four_frames(tmp_path: Path) -> None:
    from lidarfuzz.io.open import open_dataset
    from lidarfuzz.operators.lidar.points import OutsideRoiScatter, OutsideRoiScatterParams
    from lidarfuzz.store import Store
    from lidarfuzz.store.models import FrameResult, Subtask
    from lidarfuzz.suts.classic.pipeline import ClassicPipeline

    script = load_script()
    out = tmp_path / "docs" / "mr1.md"
    results = script.main(["--frames", "4", "--world-frames", "6", "--n", "10", "--workers", "1", "--seed", "1",
                           "--out", str(out), "--workspace", str(tmp_path / "ws"), "--world-dir", str(tmp_path)])

    # the report: command, the overall table beside the paper's, one table per form with the four classes
    text = out.read_text()
    assert "Regenerate: `python experiments/zhou_sun_mr1.py --frames 4 --world-frames 6 --n 10" in text
    assert "| 10 | 4 | 0.0 % (0) | 0.0 % (0) | 0.0 % (0) | 2.7 % (27) |" in text
    assert text.count("| n | all | Car | Pedestrian | Cyclist | Unknown |") == 3
    chart = tmp_path / "docs" / "images" / "mr1.png"
    assert chart.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "(images/mr1.png)" in text
    assert len(results.frames) == 4 and list(results.tables) == [10]

    # the premise: every scattered point fell outside the pipeline's ROI filter
    world = open_dataset(tmp_path / "world-s1-n6")
    pipeline = ClassicPipeline(report_unknown=True)
    with Store(tmp_path / "ws").session() as s:
        rows = s.scalars(select(FrameResult).join(Subtask).where(Subtask.name == "outside_roi_scatter")).all()
        assert len(rows) == 4
        for row in rows:
            scene = world.load(row.frame_id)
            params = OutsideRoiScatterParams(**row.params)
            mutant = OutsideRoiScatter().apply(scene, params)
            assert len(mutant.points) == len(scene.points) + 10
            kept = pipeline.roi_filter(mutant, pipeline.points_xyzi(mutant))
            assert kept.sum() == pipeline.roi_filter(scene, pipeline.points_xyzi(scene)).sum()

    # so the conclusion: nothing violated, in any form or class
    table = results.tables[10]
    for cls in table.names():
        tally = table.get(cls)
        assert tally.pairs == 4
        assert (tally.count, tally.subset, tally.strict) == (0, 0, 0), cls
    assert results.preservation[10] == (0, 4)
    # the script's own count of leaked points agrees with the premise checked above
    assert results.leaks is not None
    assert (results.leaks[10].pairs, results.leaks[10].points, results.leaks[10].strict_without) == (0, 0, 0)
    assert "| 10 | 0 | 0 | 0 |" in text
