"""Finding metamorphic relations by name: built-ins and plugins, through the ``lidarfuzz.relations`` entry points."""

from __future__ import annotations

from typing import Any

from lidarfuzz.errors import LidarfuzzError
from lidarfuzz.oracles.relations.base import MetamorphicRelation
from lidarfuzz.plugins import find, load_group

GROUP = "lidarfuzz.relations"


def available() -> dict[str, type[MetamorphicRelation[Any, Any, Any]]]:
    """Every registered relation class by its name, built-ins first."""
    return load_group(GROUP, MetamorphicRelation)


def get(name: str) -> type[MetamorphicRelation[Any, Any, Any]]:
    """The relation class called ``name``."""
    return find(GROUP, MetamorphicRelation, name, "relation", "see lidarfuzz relations")


def from_spec(spec: str | dict[str, Any]) -> MetamorphicRelation[Any, Any, Any]:
    """A relation from its name or from :meth:`MetamorphicRelation.spec` output."""
    if isinstance(spec, str):
        return get(spec)()
    name = spec.get("name")
    if not isinstance(name, str):
        raise LidarfuzzError(f"a relation spec needs a name, got {spec!r}")
    return get(name)(**spec.get("config", {}))


def for_operator(relation: Any, output: str = "detections") -> list[MetamorphicRelation[Any, Any, Any]]:
    """Default-configured built-in and plugin relations that apply to an operator's relation kind,
    among those reading ``output`` (``detections`` or ``decisions``)."""
    return [cls() for cls in available().values() if relation in cls.applies_to and cls.output == output]
