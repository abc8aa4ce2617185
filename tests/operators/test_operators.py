"""Behaviour of individual operators, composition, the registry, and the field's known defects."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

import lidarfuzz.operators.registry as registry
import lidarfuzz.plugins as plugins
from lidarfuzz.operators import Compose, Maybe, OneOf, from_spec, generator, get
from lidarfuzz.operators.lidar.points import OutsideRoiScatter, UniformPointDeletion


@pytest.fixture(scope="module")
def scene(sample_scenes):
    return sample_scenes[0]


def rng(trial: int = 0) -> np.random.Generator:
    return generator(0, "000000", 0, trial)


def test_thesis_names_are_aliases():
    for alias, name in [("UNA", "uniform_noise_addition"), ("upd", "uniform_point_deletion"),
                        ("NNA", "gaussian_noise_addition"), ("RRNA", "random_region_noise_addition"),
                        ("RRPD", "random_region_point_deletion"), ("RAR", "rotate_z"), ("UIM", "intensity_scaling"),
                        ("RIM", "region_intensity_scaling"), ("HGT", "height_shift"), ("outside-roi-scatter",
                                                                                         "outside_roi_scatter")]:
        assert get(alias).name == name
    with pytest.raises(registry.UnknownOperatorError, match=r"known: .*rotate_z"):
        get("teleport")


@pytest.mark.parametrize("count", [10, 100, 1000])
def test_outside_roi_scatter_never_lands_in_the_roi(scene, count):
    op = OutsideRoiScatter(count_range=(count, count))
    mutant, params = op(scene, rng())
    added = mutant.points.data[len(scene.points):]
    assert len(added) == count and params.region == "frame_map"  # the simulator's own map
    assert not scene.roi.contains_xy(added[:, :2]).any()
    xyz = scene.points.xyz
    assert xyz[:, 2].min() <= added[:, 2].min() and added[:, 2].max() <= xyz[:, 2].max()
    assert scene.points.intensity.min() <= added[:, 3].min() and added[:, 3].max() <= scene.points.intensity.max()
    assert np.hypot(added[:, 0], added[:, 1]).max() <= np.hypot(xyz[:, 0], xyz[:, 1]).max()
    assert np.all(mutant.points.channel("instance")[len(scene.points):] == -1)  # no object's points


def test_outside_roi_scatter_boxes_region_avoids_the_objects(scene):
    # the fallback before the estimated region, kept as region "boxes" (tests/operators/test_roi_estimate.py
    # covers the estimate)
    no_map = scene.replace(roi=None)
    mutant, scatter = OutsideRoiScatter(count_range=(2000, 2000), region="boxes")(no_map, rng())
    assert scatter.region == "boxes"
    from lidarfuzz.scene.geometry import points_in_boxes

    boxes = scene.boxes.select(scene.boxes.has_geometry).as_array()
    added = mutant.points.xyz[len(scene.points):]
    assert not points_in_boxes(added, boxes, margin=0.9).any()
    with pytest.raises(ValueError, match="ROI"):
        OutsideRoiScatter().apply(no_map, OutsideRoiScatter()(scene, rng())[1])


def test_point_deletion_draws_without_replacement(scene):
    mutant, _ = UniformPointDeletion(ratio_range=(0.5, 0.5))(scene, rng())
    assert len(mutant.points) == len(scene.points) - round(0.5 * len(scene.points))
    # Every surviving point is a distinct original point, in the original order.
    original = {tuple(row) for row in scene.points.data.tolist()}
    kept = [tuple(row) for row in mutant.points.data.tolist()]
    assert len(set(kept)) == len(kept) and set(kept) <= original


def test_region_operators_draw_their_region_where_the_points_are():
    # A scan's points crowd near the sensor: here 100 points on a 0.9 m grid at the origin (z 0) and
    # two far returns at (70, 70, 5) and (-70, -70, -2), so the bounding box is 140 m × 140 m. A 2 m
    # column drawn uniformly in that box would touch a point in about (2.9 / 140)² + 2 · (2 / 140)²
    # ≈ 0.08 % of draws; centred on a drawn point it always does. By hand: a column of edge 2 m (RRPD,
    # severity 1's region, deleting all of it: share 1) centred on a grid point reaches ±1 m, which
    # covers the whole 0.9 m grid (100 deleted); centred on a far point it holds that point alone (1
    # deleted). The column spans the cloud's height (-2 … 5, plus 0.5 m each side), so the z of a point never keeps it.
    from lidarfuzz.scene.points import PointCloud
    from lidarfuzz.scene.scene import Scene

    grid = np.arange(10) * 0.1
    x, y = (a.ravel() for a in np.meshgrid(grid, grid))
    cloud = PointCloud.from_channels({"x": np.r_[x, 70, -70], "y": np.r_[y, 70, -70], "z": np.r_[np.zeros(100), 5, -2],
                                      "intensity": np.full(102, 0.5)})
    scene = Scene(points=cloud)
    rrpd = get("RRPD")(size_range=(2.0, 2.0), share_range=(1.0, 1.0))
    deleted = {len(scene.points) - len(rrpd(scene, rng(t))[0].points) for t in range(30)}
    assert deleted <= {1, 100} and 100 in deleted
    # RIM at severity 1's factor 0.8 and edge 4 m, lowering: the same region, every intensity in it 0.5 → 0.4.
    rim = get("RIM")(factor_range=(0.8, 0.8), size_range=(4.0, 4.0), direction="lower")
    for t in range(10):
        intensity = rim(scene, rng(t))[0].points.intensity
        assert np.count_nonzero(np.isclose(intensity, 0.4)) in (1, 100)


def test_intensity_operators_keep_positions_and_the_data_scale(scene):
    for name in ("UIM", "RIM"):
        mutant, _ = get(name).at_severity(5)(scene, rng())
        assert np.array_equal(mutant.points.xyz, scene.points.xyz)
        assert mutant.points.intensity.min() >= 0.0 and mutant.points.intensity.max() <= 1.0
    scaled = scene.with_points(scene.points.with_channel("intensity", scene.points.intensity * 255))
    mutant, _ = get("UIM").at_severity(5)(scaled, rng())
    assert mutant.points.intensity.max() > 1.0  # a 0–255 cloud stays in 0–255, it is not clipped to [0, 1]


def test_noise_addition_leaves_existing_points_and_labels(scene):
    for name in ("UNA", "NNA", "RRNA"):
        mutant, _ = get(name).at_severity(3)(scene, rng())
        assert np.array_equal(mutant.points.data[: len(scene.points)], scene.points.data)
        assert mutant.boxes == scene.boxes and len(mutant.points) > len(scene.points)


def test_rotation_moves_boxes_headings_and_map_with_the_points(scene):
    op = get("RAR")(angle_range=(90.0, 90.0), both_directions=False)
    mutant, params = op(scene, rng())
    assert params.angle == 90.0
    labelled = scene.boxes.has_geometry
    np.testing.assert_allclose(mutant.boxes.centers[labelled][:, 0], -scene.boxes.centers[labelled][:, 1], atol=1e-9)
    yaw_change = np.angle(np.exp(1j * (mutant.boxes.yaw[labelled] - scene.boxes.yaw[labelled])))
    np.testing.assert_allclose(yaw_change, np.pi / 2, atol=1e-9)
    assert mutant.roi == scene.roi.transformed(op.transform(params))
    # Objects turned out of the camera's view lose their 2D box; the rest get a projected one.
    np.testing.assert_allclose(mutant.boxes.alpha[labelled], scene.calib.alpha(mutant.boxes.as_array()[labelled]))


def test_height_shift_moves_points_and_boxes_not_the_map(scene):
    mutant, _ = get("HGT")(offset_range=(0.25, 0.25))(scene, rng())
    np.testing.assert_allclose(mutant.points.xyz[:, 2], scene.points.xyz[:, 2] + 0.25, atol=1e-5)
    labelled = scene.boxes.has_geometry
    np.testing.assert_allclose(mutant.boxes.centers[labelled, 2], scene.boxes.centers[labelled, 2] + 0.25)
    assert mutant.roi == scene.roi


def test_composites_serialise_and_replay(scene):
    ops = [Compose([get("UPD").at_severity(2), get("RAR").at_severity(3)]),
           OneOf([get("UNA").at_severity(1), get("RIM").at_severity(2)], weights=[1, 3]),
           Maybe(get("HGT").at_severity(2), p=0.5)]
    for op in ops:
        mutant, params = op(scene, rng(5))
        rebuilt = from_spec(json.loads(json.dumps(op.spec())))
        replayed = rebuilt.apply(scene, rebuilt.parse_params(json.loads(params.model_dump_json())))
        assert replayed.points == mutant.points and replayed.boxes == mutant.boxes
    chosen = {tuple(s.params is not None for s in ops[1].sample(rng(t), scene).steps) for t in range(20)}
    assert chosen == {(True, False), (False, True)}
    ran = [ops[2].sample(rng(t), scene).steps[0].params is not None for t in range(40)]
    assert 5 < sum(ran) < 35


def test_seeds_are_the_same_in_another_process(scene):
    code = ("from lidarfuzz.operators import generator, get; import json;"
            "op = get('RRPD').at_severity(3); import numpy as np;"
            "from lidarfuzz.sim import GenerationConfig, render_frames;"
            "s = list(render_frames(GenerationConfig(frames=3, seed=7, sequence=True, sensor='VLP-16')))[0];"
            "print(op.sample(generator(0, '000000', 0, 0), s).model_dump_json())")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True).stdout
    here = get("RRPD").at_severity(3).sample(rng(), scene)
    assert json.loads(out) == json.loads(here.model_dump_json())


def test_plugins_register_through_entry_points(monkeypatch):
    from importlib.metadata import EntryPoint

    plugin = EntryPoint(name="upside_down", value="tests.operators.plugin:UpsideDown", group=registry.GROUP)
    real = plugins.entry_points

    def fake(group):
        return [*real(group=group), plugin] if group == registry.GROUP else real(group=group)

    monkeypatch.setattr(plugins, "entry_points", fake)
    plugins.load_group.cache_clear()
    try:
        assert get("upside-down").family == "geometric"
        assert "upside_down" in registry.available()
    finally:
        plugins.load_group.cache_clear()



def test_global_flip_mirrors_boxes_and_headings(scene):
    mutant, _ = get("global_flip").at_severity(1)(scene, rng())
    labelled = scene.boxes.has_geometry
    np.testing.assert_allclose(mutant.boxes.centers[labelled, 1], -scene.boxes.centers[labelled, 1])
    np.testing.assert_allclose(np.sin(mutant.boxes.yaw[labelled]), -np.sin(scene.boxes.yaw[labelled]), atol=1e-12)
    np.testing.assert_array_equal(mutant.points.xyz[:, 1], -scene.points.xyz[:, 1])
    np.testing.assert_array_equal(mutant.points.intensity, scene.points.intensity)


def test_global_scale_scales_box_sizes(scene):
    mutant, _ = get("global_scale")(factor_range=(1.2, 1.2))(scene, rng())
    labelled = scene.boxes.has_geometry
    np.testing.assert_allclose(mutant.boxes.sizes[labelled], scene.boxes.sizes[labelled] * 1.2)
    assert mutant.roi.area == pytest.approx(scene.roi.area * 1.44)
