"""All-nodes and all-edges of a compiled program from gcov data: the C worker of examples/suts/c_worker.

Built with ``gcc --coverage -O0`` (one conditional jump per condition, so gcov's branch outcomes
can be counted by hand from the source) and run through the worker protocol by WorkerSut.
"""

from __future__ import annotations

import importlib.util
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from lidarfuzz.errors import LidarfuzzError
from lidarfuzz.scene.points import PointCloud
from lidarfuzz.scene.scene import Scene
from lidarfuzz.structural import gcov
from lidarfuzz.structural.requirements import Covered, Requirement, coverage_ratio
from lidarfuzz.suts.external import WorkerSut
from tests.requirements import missing

pytestmark = pytest.mark.gcov

SOURCE = Path(__file__).resolve().parents[2] / "examples" / "suts" / "c_worker"
MAIN = "detector.c:main"
STRING_FIELD = "detector.c:string_field"  # reads the request's "id" and "points"


@pytest.fixture(scope="module")
def built(tmp_path_factory: pytest.TempPathFactory) -> Path:
    compiler = shutil.which("gcc")
    if compiler is None or shutil.which("gcov") is None:
        missing("gcc or gcov not found", "the Debian package gcc")
    if importlib.util.find_spec("gcovr") is None:
        missing("gcovr not installed", "the gcov extra: pip install 'lidarfuzz[gcov]'")
    build = tmp_path_factory.mktemp("gcov")
    subprocess.run([compiler, "--coverage", "-O0", "-o", str(build / "detector"), str(SOURCE / "detector.c")],
                   check=True, cwd=build)
    return build


def scene(frame_id: str, xyz: list[tuple[float, float, float]]) -> Scene:
    points = np.array([(*p, 0.5) for p in xyz], np.float32).reshape(-1, 4)
    return Scene(points=PointCloud(points), frame_id=frame_id)


# Frame A: 30 points inside the 20 m x 8 m corridor: a detection, score 30/500 (n <= 500).
# Frame B: 3 points, each failing one test of line 52: x < 2, x > 22, y > 4; then n < 20: none.
FRAME_A = scene("a", [(5.0 + 0.1 * i, 0.0, 0.0) for i in range(30)])
FRAME_B = scene("b", [(1.0, 0.0, 0.0), (50.0, 0.0, 0.0), (5.0, 10.0, 0.0)])


def run(build: Path, *frames: Scene) -> tuple[Covered, Covered]:
    gcov.reset(build)
    with WorkerSut(str(build / "detector")) as worker:
        for frame in frames:
            worker.detect(frame)
    return gcov.collect(build, SOURCE)


def edges_on(requirements: Covered, function: str, line: int) -> int:
    return sum(1 for r in requirements if r.kind == "edge" and r.function == function and r.source == line)


def test_nodes_and_branch_outcomes_of_two_frames(built: Path):
    total, covered = run(built, FRAME_A, FRAME_B)
    assert {r.function for r in total} == {MAIN, STRING_FIELD}
    main_lines = {r.source for r in total if r.kind == "node" and r.function == MAIN}
    missed = main_lines - {r.source for r in covered if r.kind == "node" and r.function == MAIN}
    # by hand: every request names a readable points file, so only the two error paths never run
    assert missed == {38, 39, 40, 44, 45, 46}
    assert all(r in covered for r in total if r.kind == "node" and r.function == STRING_FIELD)
    # branch outcomes per line (covered, total), worked from the source at -O0:
    expected = {
        34: (1, 2),  # while (fgets(...)): the loop always ends at the empty line, never at end of input
        35: (3, 4),  # '\n' || '\0': the first test both ways, the second only false
        37: (1, 2),  # !string_field(... "points" ...): never (line 36, the id, has no branch)
        43: (1, 2),  # !f: never
        52: (8, 10),  # five tests: x < 2, x > 22, y > 4 each true once (frame B); y < -4, z < -1.3 never
        60: (2, 2),  # n < 20: false for A, true for B
    }
    for line, (n_covered, n_total) in expected.items():
        assert (edges_on(covered, MAIN, line), edges_on(total, MAIN, line)) == (n_covered, n_total), line
    assert Requirement(MAIN, "edge", 60, 1) in total
    assert 0 < coverage_ratio(covered, total, "edge") < coverage_ratio(covered, total, "node") < 1


def test_counts_start_from_zero_after_reset_and_runs_are_deterministic(built: Path):
    total_a, only_a = run(built, FRAME_A)
    total_b, only_b = run(built, FRAME_B)
    assert total_a == total_b == gcov.requirements(built, SOURCE)
    # A alone never takes n < 20 nor prints the empty answer (line 61); B never reaches the detection (63)
    assert Requirement(MAIN, "node", 61) in only_b - only_a
    assert Requirement(MAIN, "node", 63) in only_a - only_b
    assert run(built, FRAME_A) == (total_a, only_a)


def test_no_gcov_data_is_a_one_line_error(built: Path, tmp_path: Path):
    gcov.reset(built)
    with pytest.raises(LidarfuzzError, match=r"no gcov data \(\.gcda\)") as info:
        gcov.collect(built, SOURCE)
    assert str(built) in str(info.value) and "\n" not in str(info.value)
    with pytest.raises(LidarfuzzError, match=r"no gcov notes \(\.gcno\)"):
        gcov.requirements(tmp_path, SOURCE)
