"""Operator parameters are checked where a campaign is read: ranges from the params models (a share
of points above 1 refused at its field), duplicate configurations refused naming the operator, and
operators whose severities all set the same configuration run at one severity."""

from __future__ import annotations

from typing import Any

import pytest

from lidarfuzz.campaign.spec import parse_campaign
from lidarfuzz.errors import DataFormatError
from lidarfuzz.operators import available

BASE = {"dataset": "sim", "sut": "classic"}


def refusal(operators: list[dict[str, Any]]) -> DataFormatError:
    with pytest.raises(DataFormatError) as caught:
        parse_campaign({**BASE, "operators": operators}, "request body")
    return caught.value


def test_a_share_of_points_above_one_is_refused_at_its_field() -> None:
    # random_region_point_deletion deletes share_range of a region's points: 1.5 of them cannot go
    error = refusal([{"name": "random_region_point_deletion", "config": {"share_range": [0.3, 1.5]}}])
    assert error.field == "operators.0.config.share_range.1"
    assert "less than or equal to 1" in error.message
    assert str(error).startswith("request body: field 'operators.0.config.share_range.1': ")


@pytest.mark.parametrize(("operator", "field", "value", "index", "words"), [
    ("uniform_point_deletion", "ratio_range", [-0.1, 0.2], 0, "greater than or equal to 0"),  # a negative share
    ("gaussian_jitter", "sigma_range", [0.0, -0.5], 1, "greater than or equal to 0"),  # a negative std
    ("fog", "mor_range", [0.0, 50.0], 0, "greater than 0"),  # a visibility of 0 m: beta = 3.912 / 0
    ("global_scale", "factor_range", [0.0, 1.0], 0, "greater than 0"),  # a scale of 0 collapses the scene
    ("cross_sensor", "beam_factor_range", [0.5, 2.0], 0, "greater than or equal to 1"),  # finer than the data
    ("fov_loss", "width_range", [90.0, 400.0], 1, "less than or equal to 360"),  # more than a full turn
])
def test_bounds_hold_by_definition(operator: str, field: str, value: list[float], index: int, words: str) -> None:
    error = refusal([{"name": "fog", "severities": [1]}, {"name": operator, "config": {field: value}}])
    assert error.field == f"operators.1.config.{field}.{index}"
    assert words in error.message and operator in error.message


def test_values_inside_the_bounds_pass() -> None:
    spec = parse_campaign({**BASE, "operators": [
        {"name": "random_region_point_deletion", "config": {"share_range": [0.0, 1.0]}},  # both ends allowed
        {"name": "height_shift", "config": {"offset_range": [-2.0, -1.0]}}]})  # an offset may be negative
    assert [op.config for op in spec.operators] == [{"share_range": [0.0, 1.0]}, {"offset_range": [-2.0, -1.0]}]


def test_every_documented_severity_lies_inside_the_bounds() -> None:
    # the bounds are definitions, not tuning: the operators' own tables (and identities) must pass them
    for name, cls in available().items():
        for severity in (0, *cls.SEVERITIES):
            assert cls.at_severity(severity).config is not None, (name, severity)


def test_shares_carry_their_bounds_in_the_params_schema() -> None:
    # what GET /api/operators sends as params_schema: the form's inputs take min and max from it
    from lidarfuzz.operators import get

    schema = get("random_region_point_deletion").ConfigModel.model_json_schema()
    items = schema["properties"]["share_range"]["prefixItems"]
    assert [(item["minimum"], item["maximum"]) for item in items] == [(0, 1), (0, 1)]
    sigma = get("gaussian_jitter").ConfigModel.model_json_schema()["properties"]["sigma_range"]["prefixItems"]
    assert [item.get("minimum") for item in sigma] == [0, 0] and "maximum" not in sigma[0]


def test_every_share_field_is_bounded_to_zero_one() -> None:
    # a config field described as a share (of points, rings, returns, ...) has [0, 1] on both ends,
    # except where the share is of points *added* (more noise points than the cloud has is possible)
    added = {("uniform_noise_addition", "ratio_range"), ("gaussian_noise_addition", "ratio_range"),
             ("image_rain", "length_range")}  # a streak longer than the image is possible
    for name, cls in available().items():
        for field, prop in cls.ConfigModel.model_json_schema()["properties"].items():
            described = "share" in (prop.get("description") or "")
            items = prop.get("prefixItems") or next((o.get("prefixItems") for o in prop.get("anyOf", [])
                                                     if o.get("prefixItems")), None)
            if not described or items is None or (name, field) in added:
                continue
            assert [(i.get("minimum"), i.get("maximum")) for i in items] == [(0, 1), (0, 1)], (name, field)


def test_a_duplicate_severity_names_the_operator_and_both_entries() -> None:
    error = refusal([{"name": "fog", "severities": [1, 3]}, {"name": "fog", "severities": [3, 5]}])
    assert error.field == "operators.1"
    assert error.message.startswith("fog at severity 3 is in entry 0 already")


def test_a_duplicate_config_is_refused_even_written_differently() -> None:
    # 100 and 100.0 are the same visibility: the built configs compare equal
    error = refusal([{"name": "fog", "config": {"mor_range": [100, 100]}},
                     {"name": "fog", "config": {"mor_range": [100.0, 100.0]}}])
    assert error.field == "operators.1" and error.message.startswith("fog with this config is in entry 0")


def test_the_same_operator_with_different_configs_is_no_duplicate() -> None:
    spec = parse_campaign({**BASE, "operators": [{"name": "fog", "config": {"mor_range": [100, 100]}},
                                                 {"name": "fog", "config": {"mor_range": [50, 50]}},
                                                 {"name": "fog", "severities": [3]}]})
    assert len(spec.operators) == 3


def test_an_operator_with_one_setting_runs_at_one_severity() -> None:
    # global_flip mirrors with probability 1 at every severity: the default 1, 3, 5 become [1]
    spec = parse_campaign({**BASE, "operators": [{"name": "global_flip"}, {"name": "fog"}]})
    assert [(op.name, op.severities) for op in spec.operators] == [("global_flip", [1]), ("fog", [1, 3, 5])]
    error = refusal([{"name": "global_flip", "severities": [1, 3, 5]}])
    assert error.field == "operators.0.severities"
    assert error.message == "global_flip is configured the same way at severities 1, 3, 5: give one of them"
