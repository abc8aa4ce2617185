"""The built-in world: a LiDAR simulator that produces labelled KITTI-format data.

Procedural (or hand-written) scenes are compiled into triangle meshes and ray-cast
with Embree by a spinning-LiDAR model; labels follow the KITTI object benchmark.

    scene description (spec) → world (meshes, trajectories) → renderer (rays, physics, labels) → Scene
                                                                     ↓
                                                   data set generator (KITTI layout, parallel)

Example:
    >>> from lidarfuzz.sim import GenerationConfig, render_frames
    >>> scene = next(render_frames(GenerationConfig(frames=1, seed=0, sensor="VLP-16")))
    >>> scene.points.channels[:4]
    ('x', 'y', 'z', 'intensity')
"""

from lidarfuzz.sim.dataset import GenerationConfig, generate_dataset, render_frames
from lidarfuzz.sim.generate import generate_scene
from lidarfuzz.sim.labels import LabelConfig
from lidarfuzz.sim.render import Renderer
from lidarfuzz.sim.sensor import SENSOR_PRESETS, LidarSensor, load_sensor
from lidarfuzz.sim.spec import SceneSpec, load_scene, parse_scene
from lidarfuzz.sim.world import compile_world

__all__ = [
    "SENSOR_PRESETS", "GenerationConfig", "LabelConfig", "LidarSensor", "Renderer", "SceneSpec", "compile_world",
    "generate_dataset", "generate_scene", "load_scene", "load_sensor", "parse_scene", "render_frames",
]
