"""Small hand-written scenes for simulator tests."""

from __future__ import annotations

from typing import Any

from lidarfuzz.scene.scene import Scene
from lidarfuzz.sim import Renderer, compile_world, parse_scene


def render(scene: dict[str, Any], t_ref: float = 0.0, **kwargs: Any) -> Scene:
    return Renderer(compile_world(parse_scene(scene))).render(t_ref, **kwargs)


def street(**extra: Any) -> dict[str, Any]:
    """A straight two-lane road along x with sidewalks, the ego in the right lane; ``extra`` adds keys."""
    scene: dict[str, Any] = {
        "roads": [{"centerline": [[-150, 0], [150, 0]], "lanes": 2, "lane_width": 3.5}],
        "ego": {"position": [0, -1.75]},
    }
    scene.update(extra)
    return scene
