"""Faster operators compute what they computed before (issue 25): every LiDAR operator's output on
two simulator frames, at severities 1 and 5, against the digests recorded before the speed work
(``tests/operators/golden.py``).

Exact bytes where numpy dispatches on the same CPU features as the recording machine; elsewhere
(numpy's transcendental functions may then differ in the last bit) the same point count and
channel sums to 1e-9. An operator whose maths was replaced by an approximation is listed in
``APPROXIMATED`` with the test that bounds its error, and is not compared here.
"""

from __future__ import annotations

import json
import math

import pytest

from tests.operators.golden import GOLDEN, SEVERITIES, describe, frames, operators, simd_features

RECORDED = json.loads(GOLDEN.read_text())
#: operator -> the test bounding its approximation's error against the integral it replaced
APPROXIMATED: dict[str, str] = {
    # each beam's expected particle count read from a table instead of integrated (issue 25)
    "rain": "tests/operators/test_weather_fast.py",
    "snow": "tests/operators/test_weather_fast.py",
}
CASES = [(name, severity, frame) for name in operators() if name not in APPROXIMATED for severity in SEVERITIES
         for frame in ("vlp16", "hdl64")]


def test_every_lidar_operator_is_recorded() -> None:
    recorded = {key.split("@")[0] for key in RECORDED["cases"]}
    assert recorded == set(operators()), "record new operators: python -m tests.operators.golden --write"


def test_every_approximation_names_the_test_that_bounds_it() -> None:
    for name, test in APPROXIMATED.items():
        assert name in operators()
        assert (GOLDEN.parents[2] / test).is_file(), test


@pytest.mark.parametrize(("name", "severity", "frame"), CASES)
def test_same_output_as_before(name: str, severity: int, frame: str) -> None:
    frames()  # rendered once per session
    expected = RECORDED["cases"][f"{name}@{severity}/{frame}"]
    got = describe(name, severity, frame)
    if "error" in expected or "error" in got:
        assert got.get("error") == expected.get("error")
        return
    assert got["params"] == expected["params"]
    if simd_features() == RECORDED["simd"]:
        assert got["sha256"] == expected["sha256"]
        return
    assert (got["points"], got["boxes"]) == (expected["points"], expected["boxes"])
    for now, before in zip(got["channel_sums"] + [got["box_sum"]], expected["channel_sums"] + [expected["box_sum"]],
                           strict=True):
        assert math.isclose(now, before, rel_tol=1e-9, abs_tol=1e-6)
