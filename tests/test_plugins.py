"""Entry points: a broken third-party plugin is left out with a warning naming it; the group still loads."""

from __future__ import annotations

import sys
import types
from collections.abc import Iterator
from importlib.metadata import EntryPoint

import pytest

import lidarfuzz.plugins as plugins
from lidarfuzz.errors import LidarfuzzError
from lidarfuzz.operators import registry as operators
from lidarfuzz.operators.base import Operator
from lidarfuzz.suts import registry as suts


@pytest.fixture
def extra_entry_points(monkeypatch: pytest.MonkeyPatch) -> Iterator[list[EntryPoint]]:
    """Entry points appended to the installed ones (any group named in their ``group``)."""
    added: list[EntryPoint] = []
    real = plugins.entry_points

    def fake(group: str) -> list[EntryPoint]:
        return [*real(group=group), *(e for e in added if e.group == group)]

    monkeypatch.setattr(plugins, "entry_points", fake)
    plugins.load_group.cache_clear()
    yield added
    plugins.load_group.cache_clear()


@pytest.fixture
def fake_module(monkeypatch: pytest.MonkeyPatch) -> types.ModuleType:
    module = types.ModuleType("lidarfuzz_test_plugin")
    module.not_a_class = 42  # type: ignore[attr-defined]
    module.NotAnOperator = type("NotAnOperator", (), {"name": "not_an_operator"})  # type: ignore[attr-defined]
    module.Nameless = type("Nameless", (Operator,), {})  # type: ignore[attr-defined]
    monkeypatch.setitem(sys.modules, module.__name__, module)
    return module


@pytest.mark.parametrize(("value", "error"), [
    ("lidarfuzz_no_such_package.module:Thing", "ModuleNotFoundError: No module named 'lidarfuzz_no_such_package'"),
    ("lidarfuzz_test_plugin:missing", "AttributeError"),
    ("lidarfuzz_test_plugin:not_a_class", "is not a Operator"),
    ("lidarfuzz_test_plugin:NotAnOperator", "is not a Operator"),
    ("lidarfuzz_test_plugin:Nameless", "Nameless has no name"),
])
def test_a_broken_plugin_is_left_out_with_a_warning_naming_it(extra_entry_points, fake_module, value, error):
    builtin = set(operators.available())
    plugins.load_group.cache_clear()
    extra_entry_points.append(EntryPoint(name="broken_op", value=value, group=operators.GROUP))
    with pytest.warns(plugins.PluginWarning) as caught:
        found = operators.available()
    assert set(found) == builtin  # the rest of the group is there
    assert len(caught) == 1
    message = str(caught[0].message)
    assert "\n" not in message
    assert message.startswith(f"plugin broken_op = {value} (group lidarfuzz.operators) left out: ")
    assert error in message


def test_a_working_plugin_beside_a_broken_one_still_loads(extra_entry_points, recwarn):
    extra_entry_points += [
        EntryPoint(name="broken", value="lidarfuzz_no_such_package:Thing", group=operators.GROUP),
        EntryPoint(name="upside_down", value="tests.operators.plugin:UpsideDown", group=operators.GROUP),
    ]
    assert operators.get("upside-down").family == "geometric"
    assert [w for w in recwarn if issubclass(w.category, plugins.PluginWarning)]
    # a SUT spec naming a built-in works while another group has a broken plugin
    assert suts.create("classic").name == "classic"


def test_the_warning_is_given_once_per_process(extra_entry_points, recwarn):
    extra_entry_points.append(EntryPoint(name="broken", value="lidarfuzz_no_such_package:T", group=operators.GROUP))
    operators.available()
    operators.available()
    assert len([w for w in recwarn if issubclass(w.category, plugins.PluginWarning)]) == 1


def test_a_broken_builtin_raises(extra_entry_points):
    extra_entry_points.append(EntryPoint(name="broken", value="lidarfuzz.no_such_module:Thing", group=operators.GROUP))
    with pytest.raises(ModuleNotFoundError):
        operators.available()


def test_a_wrong_builtin_type_raises(extra_entry_points):
    extra_entry_points.append(EntryPoint(name="wrong", value="lidarfuzz.errors:LidarfuzzError", group=operators.GROUP))
    with pytest.raises(LidarfuzzError, match="is not a Operator"):
        operators.available()


def test_declared_lists_without_loading(extra_entry_points):
    extra_entry_points.append(EntryPoint(name="broken", value="lidarfuzz_no_such_package:Thing", group=suts.GROUP))
    names = [e.name for e in plugins.declared(suts.GROUP)]
    assert names[-1] == "broken" and "classic" in names  # built-ins first, nothing imported


def test_the_web_allows_modules_of_declared_sut_plugins_even_unloaded(extra_entry_points):
    from lidarfuzz.web.security.specs import _entry_point_modules

    extra_entry_points.append(EntryPoint(name="mine", value="my_package.detector:Mine", group=suts.GROUP))
    assert "my_package.detector" in _entry_point_modules()
    assert "lidarfuzz.suts.classic" in _entry_point_modules()
