"""Campaign files: what is accepted, and how a mistake is reported."""

from __future__ import annotations

from pathlib import Path

import pytest

from lidarfuzz.campaign.spec import CampaignSpec, load_campaign, parse_campaign
from lidarfuzz.errors import DataFormatError

GOOD = """\
name: fog-vs-classic
dataset: sim
sut: classic
operators:
  - name: fog
    severities: [5, 1, 3, 3]
  - name: RAR
    config: {angle_range: [10, 20]}
relations: [preservation, equivariance]
seed: 4
frames: 50
"""


def test_a_campaign_file_is_read_and_normalised(tmp_path: Path) -> None:
    path = tmp_path / "c.yaml"
    path.write_text(GOOD)
    spec = load_campaign(path)
    assert isinstance(spec, CampaignSpec) and spec.seed == 4 and spec.frames == 50
    assert spec.operators[0].severities == [1, 3, 5]
    assert spec.operators[1].name == "rotate_z" and spec.operators[1].config == {"angle_range": [10, 20]}
    assert spec.relations == ["preservation", "equivariance"]
    json_path = tmp_path / "c.json"
    json_path.write_text(spec.model_dump_json())
    assert load_campaign(json_path) == spec
    minimal = parse_campaign({"dataset": "d", "sut": "classic", "operators": [{"name": "snow"}]})
    assert minimal.relations == "auto" and minimal.operators[0].severities == [1, 3, 5] and minimal.trials == 1


@pytest.mark.parametrize(
    ("change", "field", "message"),
    [
        ({"operators": [{"name": "teleport"}]}, "operators.0.name", "unknown operator 'teleport'"),
        ({"operators": [{"name": "fog", "severities": [0, 9]}]}, "operators.0.severities", "1 to 5"),
        ({"operators": [{"name": "fog", "config": {"visibility": 3}}]}, "operators.0.config.visibility",
         "Extra inputs"),
        ({"operators": []}, "operators", "at least one operator"),
        ({"relations": ["nope"]}, "relations", "unknown relation 'nope'"),
        ({"seeds": 3}, "seeds", "Extra inputs"),
        ({"frames": 0}, "frames", "greater than or equal to 1"),
        ({"operators": [{"name": "fog"}, {"name": "brightness"}]}, "operators",
         "image_brightness is a camera operator; a mutation campaign runs on lidar data"),
        ({"kind": "guided", "operators": [], "search": {"operators": ["image_rain"]}}, "<root>",
         "search.operators: image_rain is a camera operator"),
    ],
)
def test_mistakes_name_the_key(change: dict, field: str, message: str) -> None:
    data = {"dataset": "d", "sut": "classic", "operators": [{"name": "fog"}], **change}
    with pytest.raises(DataFormatError) as info:
        parse_campaign(data, "campaign.yaml")
    assert info.value.field == field and message in str(info.value), str(info.value)
    assert str(info.value).startswith("campaign.yaml: field ")


def test_files_that_are_not_campaigns(tmp_path: Path) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text("dataset: [unclosed\n")
    with pytest.raises(DataFormatError, match=r"bad.yaml:\d+: not valid YAML"):
        load_campaign(bad)
    listing = tmp_path / "list.yaml"
    listing.write_text("- fog\n")
    with pytest.raises(DataFormatError, match="must be a mapping"):
        load_campaign(listing)
    with pytest.raises(DataFormatError, match=r"missing\.yaml: file not found"):
        load_campaign(tmp_path / "missing.yaml")
