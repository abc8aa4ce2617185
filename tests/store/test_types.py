"""json_safe: what JSON has no word for becomes null or a plain Python value, whatever the nesting."""

from __future__ import annotations

import enum
import math

import numpy as np

from lidarfuzz.store.contracts import ViolationRecord
from lidarfuzz.store.types import json_safe


class Colour(enum.StrEnum):
    RED = "red"


class Ratio(float):
    pass


def test_non_finite_numbers_become_null_at_any_depth() -> None:
    value = {"a": math.nan, "b": [math.inf, -math.inf, 1.5, (2.0, math.nan)], "c": {"d": {"e": math.nan}}}
    assert json_safe(value) == {"a": None, "b": [None, None, 1.5, [2.0, None]], "c": {"d": {"e": None}}}


def test_numpy_scalars_become_python_numbers_and_tuples_lists() -> None:
    safe = json_safe({"n": np.int64(3), "x": np.float32(0.5), "bad": np.float64(np.nan), "t": (1, "a", True, None)})
    assert safe == {"n": 3, "x": 0.5, "bad": None, "t": [1, "a", True, None]}
    assert type(safe["n"]) is int and type(safe["x"]) is float


def test_subclasses_and_models_go_the_slow_way_with_the_same_rules() -> None:
    assert json_safe([Ratio(math.nan), Ratio(2.0), Colour.RED]) == [None, 2.0, "red"]
    safe = json_safe(ViolationRecord(relation="preservation", kind="missing", cls="Car", magnitude=2.5))
    assert safe["cls"] == "Car" and safe["magnitude"] == 2.5 and safe["range_m"] is None  # NaN by default
