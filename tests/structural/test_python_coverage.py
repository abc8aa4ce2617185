"""All-nodes and all-edges of Python code against graphs counted by hand (tests/structural/sample_code.py)."""

from __future__ import annotations

import multiprocessing
import pickle
import re
from concurrent.futures import ProcessPoolExecutor

import pytest

from lidarfuzz.errors import LidarfuzzError
from lidarfuzz.structural.python_coverage import CodeModel, RecorderConfig, requirements_of
from lidarfuzz.structural.requirements import Covered, Requirement, aggregated, coverage_ratio, union
from lidarfuzz.structural.targets import CodeTarget
from tests.structural import sample_code

M = "tests.structural.sample_code"


def node(function: str, line: int) -> Requirement:
    return Requirement(f"{M}:{function}", "node", line)


def edge(function: str, source: int, target: int) -> Requirement:
    return Requirement(f"{M}:{function}", "edge", source, target)


def nodes(function: str, *lines: int) -> set[Requirement]:
    return {node(function, line) for line in lines}


def edges(function: str, *pairs: tuple[int, int]) -> set[Requirement]:
    return {edge(function, a, b) for a, b in pairs}


# The graphs worked out by hand in sample_code.py's comments (entry and exit: minus the def line).
STRAIGHT = nodes("straight", 15) | edges("straight", (-14, 15), (15, -14))
SIGN = nodes("sign", 22, 23, 25, 26) | edges("sign", (-21, 22), (22, 23), (22, 25), (23, 26), (25, 26), (26, -21))
FIRST_NEGATIVE = nodes("first_negative", 34, 35, 36, 37, 39) | edges(
    "first_negative", (-33, 34), (34, 35), (35, 36), (35, 39), (36, 35), (36, 37), (37, 39), (39, -33))
PARSE = nodes("parse", 48, 50, 52) | edges("parse", (-47, 48), (48, 52), (48, 50), (50, 52), (52, -47))
AREA = nodes("Rectangle.area", 61, 62, 63) | edges(
    "Rectangle.area", (-60, 61), (61, 62), (61, 63), (62, -60), (63, -60))
IS_SQUARE = nodes("Rectangle.is_square", 67) | edges("Rectangle.is_square", (-66, 67), (67, -66))
COUNTDOWN = nodes("countdown", 119, 122, 123, 125) | edges(
    "countdown", (-117, 119), (119, 122), (122, 123), (122, 125), (123, 122), (125, -117))
HALVE = nodes("countdown.halve", 120) | edges("countdown.halve", (-119, 120), (120, -119))


@pytest.mark.parametrize("function, expected", [
    ("straight", STRAIGHT), ("sign", SIGN), ("first_negative", FIRST_NEGATIVE), ("parse", PARSE),
    ("Rectangle.area", AREA), ("Rectangle.is_square", IS_SQUARE), ("countdown.halve", HALVE),
])
def test_static_requirements_are_the_hand_counted_graphs(function, expected):
    assert requirements_of([f"{M}:{function}"]) == expected


def test_a_decorated_function_with_a_nested_one():
    # the function target includes the nested function; each has its own graph
    assert requirements_of([f"{M}:countdown"]) == COUNTDOWN | HALVE
    recorder = RecorderConfig((f"{M}:countdown",)).build()
    # n = 1: one pass through the loop (halve called once), then 122 -> 125
    assert recorder.record(sample_code.countdown, 1) == ([0], COUNTDOWN | HALVE)
    # n = 0: the loop body never runs, nor halve
    assert recorder.record(sample_code.countdown, 0)[1] == nodes("countdown", 119, 122, 125) | edges(
        "countdown", (-117, 119), (119, 122), (122, 125), (125, -117))


def test_blocks_group_straight_lines():
    graph = CodeModel.of([f"{M}:parse"]).graph(f"{M}:parse")
    assert [block.lines for block in graph.blocks] == [(48, 49), (50, 51), (52,)]
    assert graph.handlers == {50: 48}


def test_a_class_target_is_its_methods():
    assert requirements_of([f"{M}:Rectangle"]) == AREA | IS_SQUARE


def test_sign_taken_once_each_way():
    recorder = RecorderConfig((f"{M}:sign",)).build()
    result, positive = recorder.record(sample_code.sign, 3)
    assert result == "positive"
    # the then-branch: 22 -> 23 -> 26
    assert positive == nodes("sign", 22, 23, 26) | edges("sign", (-21, 22), (22, 23), (23, 26), (26, -21))
    _, negative = recorder.record(sample_code.sign, -3)
    assert negative == nodes("sign", 22, 25, 26) | edges("sign", (-21, 22), (22, 25), (25, 26), (26, -21))
    both = union(positive, negative)
    assert both == SIGN
    total = recorder.requirements()
    # 3 of 4 nodes and 4 of 6 edges for one run; the other run adds node 25 (1/4) and 2 edges (2/6)
    assert coverage_ratio(positive, total, "node") == 3 / 4 and coverage_ratio(positive, total, "edge") == 4 / 6
    assert aggregated(positive, negative, total, "node") == 1 / 4
    assert aggregated(positive, negative, total, "edge") == 2 / 6


def test_loop_with_break():
    recorder = RecorderConfig((f"{M}:first_negative",)).build()
    # [2, -1]: 34, 35 -> 36 (2 is not negative) -> 35 -> 36 -> 37 (break) -> 39
    _, found = recorder.record(sample_code.first_negative, [2.0, -1.0])
    assert found == nodes("first_negative", 34, 35, 36, 37, 39) | edges(
        "first_negative", (-33, 34), (34, 35), (35, 36), (36, 35), (36, 37), (37, 39), (39, -33))
    # []: the loop ends at once, 35 -> 39
    _, empty = recorder.record(sample_code.first_negative, [])
    assert empty == nodes("first_negative", 34, 35, 39) | edges(
        "first_negative", (-33, 34), (34, 35), (35, 39), (39, -33))
    assert union(found, empty) == FIRST_NEGATIVE


def test_try_except_exception_edge():
    recorder = RecorderConfig((f"{M}:parse",)).build()
    _, number = recorder.record(sample_code.parse, "7")
    assert number == nodes("parse", 48, 52) | edges("parse", (-47, 48), (48, 52), (52, -47))
    value, text = recorder.record(sample_code.parse, "seven")
    assert value == -1
    assert text == nodes("parse", 48, 50, 52) | edges("parse", (-47, 48), (48, 50), (50, 52), (52, -47))


def test_straight_line_and_out_of_target_code():
    recorder = RecorderConfig((f"{M}:straight",)).build()
    assert recorder.record(sample_code.straight, 1, 2) == (6, STRAIGHT)
    # sign is outside the target: nothing covered
    assert recorder.record(sample_code.sign, 1)[1] == frozenset()


def test_an_exception_propagates_and_its_coverage_is_kept():
    recorder = RecorderConfig((f"{M}:Rectangle",)).build()
    with pytest.raises(TypeError):
        recorder.record(sample_code.Rectangle().area, "a", 2)
    # 61 ran and raised comparing 'a' <= 0: the node and the entry edge, no other edge
    assert recorder.last == nodes("Rectangle.area", 61) | edges("Rectangle.area", (-60, 61))


def test_deterministic_and_per_call():
    recorder = RecorderConfig((M,), erase_every=3).build()
    calls = [(sample_code.sign, 1), (sample_code.parse, "x"), (sample_code.sign, -1), (sample_code.first_negative, [1])]
    first = [recorder.record(*call)[1] for call in calls * 2]
    again = RecorderConfig((M,)).build()
    second = [again.record(*call)[1] for call in calls * 2]
    assert first == second
    assert first[:4] == first[4:]  # the same call covers the same, across an erase of the data


def _in_worker(config: RecorderConfig, text: str) -> Covered:
    return config.build().record(sample_code.parse, text)[1]


def test_a_worker_process_builds_its_recorder_from_the_config():
    config = RecorderConfig((f"{M}:parse",))
    assert pickle.loads(pickle.dumps(config)) == config
    with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")) as pool:
        got = pool.submit(_in_worker, config, "seven").result(timeout=120)
    assert got == nodes("parse", 48, 50, 52) | edges("parse", (-47, 48), (48, 50), (50, 52), (52, -47))


@pytest.mark.parametrize("text, message", [
    ("no_such_module_xyz", "code target 'no_such_module_xyz': no module named 'no_such_module_xyz'"),
    ("tests.no_such_module", "code target 'tests.no_such_module': no module named 'tests.no_such_module'"),
    ("no_such_package.module", "no module named 'no_such_package.module'"),
    (f"{M}:nothing", f"code target '{M}:nothing': module '{M}' has no function or class 'nothing'"),
    (f"{M}:Rectangle.perimeter", "has no function or class 'Rectangle.perimeter'"),
    ("pkg mod", "code target 'pkg mod': expected 'pkg.module' or 'pkg.module:Name[.name]'"),
])
def test_targets_that_do_not_exist_are_one_line_errors(text, message):
    with pytest.raises(LidarfuzzError, match=re.escape(message)) as info:
        CodeTarget.parse(text).functions()
    assert "\n" not in str(info.value)


def test_targets_parse_and_resolve():
    assert str(CodeTarget.parse(f"{M}:Rectangle.area")) == f"{M}:Rectangle.area"
    names = [f.qualname for f in CodeTarget.parse(M).functions()]
    assert names == ["straight", "sign", "first_negative", "parse", "Rectangle.area", "Rectangle.is_square",
                     "ground_height", "steer", "tagged", "countdown", "countdown.halve"]
    # a package: every module in it
    package = {f.module for f in CodeTarget.parse("tests.structural").functions()}
    assert M in package
