"""The operator catalogue in docs/operators.md is generated from the registry; it must not fall behind."""

from pathlib import Path

from lidarfuzz.operators import available

PAGE = Path(__file__).resolve().parents[2] / "docs" / "operators.md"


def test_every_registered_operator_is_documented_with_a_picture():
    text = PAGE.read_text(encoding="utf-8")
    for name in available():
        assert f"**`{name}`**" in text, f"{name} is missing: run docs/scripts/render_operators.py"
        assert (PAGE.parent / "images" / "operators" / f"{name}.png").is_file()
