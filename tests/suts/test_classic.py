"""The classic pipeline: each stage on hand-built inputs, the whole on simulator frames."""

from __future__ import annotations

import numpy as np
import pytest

from lidarfuzz.oracles.matching import match_boxes
from lidarfuzz.scene.boxes import Boxes3D
from lidarfuzz.scene.points import PointCloud
from lidarfuzz.scene.roi import RoiMap
from lidarfuzz.scene.scene import Scene
from lidarfuzz.sim.dataset import GenerationConfig, render_frames
from lidarfuzz.suts.base import validate_detections
from lidarfuzz.suts.classic import ClassicPipeline
from lidarfuzz.suts.classic.boxes import box_from_footprint, end_on, fit_footprint
from lidarfuzz.suts.classic.classify import Measurement, classify
from lidarfuzz.suts.classic.cluster import euclidean_clusters, grid_clusters, split_clusters
from lidarfuzz.suts.classic.ground import height_above_grid, height_above_plane, ransac_plane
from lidarfuzz.suts.classic.roi import rasterize, roi_mask
from lidarfuzz.suts.registry import create


@pytest.fixture(scope="module")
def hdl64_frames() -> list[Scene]:
    return list(render_frames(GenerationConfig(frames=4, seed=3)))


# -- stages ------------------------------------------------------------------------------------
def test_roi_raster_matches_the_polygon_and_keeps_holes() -> None:
    import shapely

    outer = [(0, -5), (30, -5), (30, 5), (0, 5)]
    hole = [(10, -1), (14, -1), (14, 1), (10, 1)]
    roi = RoiMap.from_polygons([outer], [[hole]])
    rng = np.random.default_rng(0)
    xy = rng.uniform([-5, -10], [35, 10], (5000, 2)).astype(np.float32)
    mask = roi_mask(xy, roi, margin=0.0, cell=0.05)
    exact = shapely.contains_xy(roi.geometry, xy[:, 0].astype(float), xy[:, 1].astype(float))
    assert np.mean(mask == exact) > 0.99
    assert not roi_mask(np.array([[12.0, 0.0]], np.float32), roi, 0.0, 0.05)[0]  # in the hole
    grown = roi_mask(np.array([[31.5, 0.0], [33.5, 0.0]], np.float32), roi, margin=2.0, cell=0.05)
    assert grown.tolist() == [True, False]
    assert rasterize(shapely.Polygon(outer), np.array([0.0, -5.0]), 1.0, (30, 10)).all()


def test_both_ground_models_remove_a_noisy_plane_and_keep_a_box_on_it() -> None:
    rng = np.random.default_rng(1)
    road = np.c_[rng.uniform(0, 40, 4000), rng.uniform(-10, 10, 4000), rng.normal(-1.7, 0.03, 4000)]
    road[:, 2] += 0.01 * road[:, 0]  # a gentle slope
    car = np.c_[rng.uniform(10, 14, 500), rng.uniform(-1, 1, 500), rng.uniform(-1.2, -0.2, 500)]
    xyz = np.r_[road, car].astype(np.float32)
    plane = ransac_plane(xyz, iterations=50, threshold=0.2, sample=3000, max_tilt_deg=10, seed=0)
    above = height_above_plane(xyz, plane)
    assert np.mean(np.abs(above[:4000]) < 0.15) > 0.97 and np.all(above[4000:] > 0.15)
    grid = height_above_grid(xyz, 2.0)
    assert np.mean(grid[:4000] < 0.2) > 0.95 and np.mean(grid[4000:] > 0.25) > 0.9
    again = ransac_plane(xyz, iterations=50, threshold=0.2, sample=3000, max_tilt_deg=10, seed=0)
    assert np.array_equal(plane, again)


def test_clustering_separates_blobs_and_joins_close_points() -> None:
    rng = np.random.default_rng(2)
    a = rng.normal([0, 0, 0], 0.1, (100, 3))
    b = rng.normal([2.0, 0, 0], 0.1, (100, 3))
    xyz = np.r_[a, b].astype(np.float32)
    for labels in (grid_clusters(xyz[:, :2], 0.3), euclidean_clusters(xyz, 0.45)):
        assert labels[:100].tolist() == [labels[0]] * 100 and labels[100:].tolist() == [labels[100]] * 100
        assert labels[0] != labels[100]
    parts = split_clusters(grid_clusters(xyz[:, :2], 0.3), 10, 1000)
    assert sorted(len(p) for p in parts) == [100, 100]
    assert split_clusters(grid_clusters(xyz[:, :2], 0.3), 150, 1000) == []


def test_a_car_the_grid_cut_in_two_is_joined() -> None:
    # a car 16-20 m ahead seen from behind: its bumper (a face 1.6 m wide, 0.3-0.85 m above the
    # road) and its roof (1.6 x 1.5 m at 1.2-1.45 m), with 0.9 m of glass returning nothing
    # between them: two 0.5 m-grid clusters, each a car on its own (the bumper by the low-car rule:
    # 1.6 m long, 0.85 m high), whose completed boxes overlap. Together: 2.6 x 1.6 m, 1.45 m high,
    # one car.
    rng = np.random.default_rng(3)
    road = np.c_[rng.uniform(0, 40, 6000), rng.uniform(-10, 10, 6000), np.full(6000, -1.7)]
    bumper = np.c_[rng.uniform(16.0, 16.1, 200), rng.uniform(-0.8, 0.8, 200), rng.uniform(-1.4, -0.85, 200)]
    roof = np.c_[rng.uniform(17.0, 18.6, 200), rng.uniform(-0.75, 0.75, 200), rng.uniform(-0.5, -0.25, 200)]
    xyz = np.r_[road, bumper, roof]
    scene = Scene(PointCloud(np.c_[xyz, np.full(len(xyz), 0.3)].astype(np.float32)))
    joined = ClassicPipeline().detect(scene)
    assert joined.labels.tolist() == ["Car"]
    assert joined.centers[0, 1] == pytest.approx(0.0, abs=0.1)
    assert 15.9 <= joined.centers[0, 0] - joined.as_array()[0, 3] / 2 <= 16.1  # starts at the bumper
    assert ClassicPipeline(merge_iou=0).detect(scene).labels.tolist() == ["Car", "Car"]


@pytest.mark.parametrize("yaw", [0.0, 0.4, 1.2, -0.7])
def test_lshape_recovers_the_heading_and_size_of_two_visible_sides(yaw: float) -> None:
    # the two sides of a 4 × 1.8 m car facing a sensor at the origin, car centred at (15, 6)
    t = np.linspace(-0.5, 0.5, 80)
    length_side = np.c_[t * 4.0, np.full_like(t, -0.9)]
    width_side = np.c_[np.full_like(t, -2.0), t * 1.8]
    local = np.r_[length_side, width_side]
    c, s = np.cos(yaw), np.sin(yaw)
    xy = local @ np.array([[c, s], [-s, c]]) + [15.0, 6.0]
    fp = fit_footprint(xy, "lshape", 1.0)
    box = box_from_footprint(fp, -1.7, -0.2, None)
    assert abs(np.sin(box[6] - yaw)) < 0.03  # heading up to the π ambiguity
    np.testing.assert_allclose(box[3:5], [4.0, 1.8], atol=0.1)
    np.testing.assert_allclose(box[:2], [15.0, 6.0], atol=0.1)
    # the smallest enclosing rectangle cannot tell an L from its hypotenuse (same area): give it all four sides
    full = np.r_[local, -local] @ np.array([[c, s], [-s, c]]) + [15.0, 6.0]
    box = box_from_footprint(fit_footprint(full, "min_area", 1.0), -1.7, -0.2, None)
    assert abs(np.sin(box[6] - yaw)) < 0.03
    np.testing.assert_allclose(box[3:5], [4.0, 1.8], atol=0.1)


def test_completion_grows_away_from_the_sensor_and_reads_an_end_on_face_as_width() -> None:
    # a car seen from behind at 20 m: only its 1.6 m rear face (perpendicular to the sight line)
    t = np.linspace(-0.8, 0.8, 60)
    rear = np.c_[np.full_like(t, 20.0), t]
    fp = fit_footprint(rear, "lshape", 1.0)
    assert end_on(fp)
    box = box_from_footprint(fp, -1.7, -0.2, (3.9, 1.6, 1.56), width_seen=True)
    assert abs(np.sin(box[6])) < 0.05  # heading along the sight line
    np.testing.assert_allclose(box[[0, 3, 4]], [20.0 + 3.9 / 2, 3.9, 1.6], atol=0.05)  # grown away from us


def test_rules_name_the_classes() -> None:
    assert classify(Measurement(4.2, 1.7, 1.5, 300, 3.0, False))[0] == "Car"
    assert classify(Measurement(0.6, 0.5, 1.75, 80, 0.5, False))[0] == "Pedestrian"
    assert classify(Measurement(1.7, 0.5, 1.7, 120, 0.5, False))[0] == "Cyclist"
    assert classify(Measurement(1.7, 0.4, 1.5, 120, 1.6, True))[0] == "Car"  # a car's rear: wide at the top
    assert classify(Measurement(0.15, 0.15, 2.0, 60, 0.1, False))[0] == "Unknown"  # a sign post
    assert classify(Measurement(12.0, 0.6, 1.1, 900, 12.0, False))[0] == "Unknown"  # a hedge
    assert classify(Measurement(3.0, 2.0, 2.9, 400, 3.0, False))[0] == "Unknown"  # too tall


# -- the whole -----------------------------------------------------------------------------------
def test_finds_the_visible_cars_within_40_m(hdl64_frames: list[Scene]) -> None:
    sut = create("classic")
    found = total = 0
    for scene in hdl64_frames:
        dets = sut.detect(scene)
        assert validate_detections(dets, sut.classes) is None
        assert np.all((dets.scores >= 0) & (dets.scores <= 1))
        b = scene.boxes
        near = np.hypot(*b.centers[:, :2].T) < 40
        gt = b.select((b.labels == "Car") & near & (b.occlusion == 0) & (b.truncation < 0.3))
        m = match_boxes(gt, dets, min_iou=0.5)
        found += len(m.pairs)
        total += len(gt)
    assert total >= 5 and found / total >= 0.8, (found, total)


def test_deterministic_configurable_and_robust_to_empty_input(hdl64_frames: list[Scene]) -> None:
    scene = hdl64_frames[0]
    a, b = ClassicPipeline().detect(scene), ClassicPipeline().detect(scene)
    assert a.allclose(b, atol=0) and np.array_equal(a.scores, b.scores)
    for options in ({"ground": "grid"}, {"cluster": "euclidean"}, {"box": "min_area"}, {"use_roi": False}):
        assert validate_detections(ClassicPipeline(**options).detect(scene), ("Car", "Pedestrian", "Cyclist")) is None
    empty = scene.with_points(np.zeros((0, len(scene.points.channels)), np.float32))
    assert len(ClassicPipeline().detect(empty)) == 0
    assert len(ClassicPipeline().detect(scene.replace(roi=None))) > 0
    assert ClassicPipeline(ground="grid").fingerprint() != ClassicPipeline().fingerprint()
    assert set(ClassicPipeline().times.seconds) == set()  # filled per call
    with pytest.raises(ValueError):
        ClassicPipeline(ground="magic")
    tiny = Scene(PointCloud(np.array([[5.0, 0.0, -1.7, 0.1]] * 2, np.float32)), boxes=Boxes3D.empty())
    assert len(ClassicPipeline().detect(tiny)) == 0
