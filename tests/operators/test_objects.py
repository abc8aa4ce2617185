"""Behaviour of the object-level operators (removal, in-box corruptions, moves, insertion)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from lidarfuzz.operators import from_spec, generator
from lidarfuzz.operators.lidar.objects import (
    GROUND_BAND,
    ObjectCutout,
    ObjectDensityLoss,
    ObjectInsertion,
    ObjectJitter,
    ObjectLibrary,
    ObjectRemoval,
    ObjectRemovalParams,
    ObjectRotate,
    ObjectRotateParams,
    ObjectScale,
    ObjectScaleParams,
    ObjectTranslate,
    ObjectTranslateParams,
)
from lidarfuzz.scene.boxes import Boxes3D
from lidarfuzz.scene.geometry import bev_corners, iou_bev, points_in_boxes
from lidarfuzz.scene.points import PointCloud
from lidarfuzz.scene.scene import Scene
from lidarfuzz.scene.semantics import SEMANTIC_ID
from lidarfuzz.sim import GenerationConfig, render_frames


def rng(trial: int = 0) -> np.random.Generator:
    return generator(3, "000000", 0, trial)


@pytest.fixture(scope="module")
def hdl() -> Scene:
    return next(render_frames(GenerationConfig(frames=1, seed=0)))


@pytest.fixture(scope="module")
def vlp(sample_scenes) -> Scene:
    return sample_scenes[0]


def rows(cloud: PointCloud) -> set[tuple[float, ...]]:
    return {tuple(r) for r in cloud.data.tolist()}


def biggest(scene: Scene, label: str | None = None) -> int:
    """The labelled object (of class ``label``) with the most points of its own."""
    inst = scene.points.channel("instance")
    ok = scene.boxes.has_geometry & ((scene.boxes.labels == label) if label else True)
    counts = [np.count_nonzero(inst == t) if g else -1 for t, g in zip(scene.boxes.track_ids, ok, strict=True)]
    return int(np.argmax(counts))


# --------------------------------------------------------------------------- removal
@pytest.mark.parametrize("fill", [False, True])
def test_removal_deletes_the_object_and_its_label_and_nothing_else(hdl, fill):
    i = biggest(hdl)
    box = hdl.boxes.as_array()[i]
    params = ObjectRemovalParams(objects=(i,), track_ids=(int(hdl.boxes.track_ids[i]),), fill_ground=fill, seed=1)
    mutant = ObjectRemoval().apply(hdl, params)
    bottom = box[2] - box[5] / 2
    inside = points_in_boxes(mutant.points.xyz, box[None])[:, 0]
    assert not np.any(mutant.points.xyz[inside, 2] > bottom + GROUND_BAND + 0.05)  # nothing above the ground band
    assert int(hdl.boxes.track_ids[i]) not in mutant.boxes.track_ids.tolist()
    others = np.flatnonzero(np.arange(len(hdl.boxes)) != i)
    assert mutant.boxes == hdl.boxes.select(others)
    # Every other object's points are untouched.
    other_boxes = hdl.boxes.as_array()[others][hdl.boxes.has_geometry[others]]
    before = hdl.points.select(points_in_boxes(hdl.points.xyz, other_boxes).any(axis=1))
    after = mutant.points.select(points_in_boxes(mutant.points.xyz, other_boxes).any(axis=1))
    assert rows(before) == rows(after)
    added = rows(mutant.points) - rows(hdl.points)
    assert bool(added) == fill


def test_removal_infill_puts_ground_returns_on_the_footprint(hdl):
    i = biggest(hdl, "Car")  # deep enough that rays through it reach the ground inside its footprint
    box = hdl.boxes.as_array()[i]
    tid = int(hdl.boxes.track_ids[i])
    bare = ObjectRemoval().apply(hdl, ObjectRemovalParams(objects=(i,), track_ids=(tid,), fill_ground=False, seed=1))
    filled = ObjectRemoval().apply(hdl, ObjectRemovalParams(objects=(i,), track_ids=(tid,), fill_ground=True, seed=1))
    column = box.copy()
    column[2], column[5] = 0.0, 100.0  # the footprint, any height
    in_bare = points_in_boxes(bare.points.xyz, column[None])[:, 0].sum()
    in_filled = points_in_boxes(filled.points.xyz, column[None])[:, 0]
    assert in_filled.sum() >= in_bare + 10
    new = filled.points.data[len(bare.points):]
    assert len(new) > 50
    assert np.all(np.abs(new[:, 2] - (box[2] - box[5] / 2)) < 0.2)  # on the ground, not floating
    assert np.all(new[:, filled.points.index("instance")] == -1)
    assert set(new[:, filled.points.index("label")].astype(int)) <= {SEMANTIC_ID[c] for c in
                                                                     ("road", "sidewalk", "terrain", "other-ground")}
    # Re-cast rays keep their beam: each lands where its ring's elevation says.
    ring = new[:, filled.points.index("ring")].astype(int)
    source_rings = hdl.points.channel("ring")[hdl.points.channel("instance") == hdl.boxes.track_ids[i]].astype(int)
    assert set(ring) <= set(source_rings)


def test_dontcare_regions_are_never_chosen(vlp):
    mutant, params = ObjectRemoval(count_range=(20, 20))(vlp, rng())
    assert all(vlp.boxes.has_geometry[list(params.objects)])
    assert list(mutant.boxes.labels) == ["DontCare"] * int((~vlp.boxes.has_geometry).sum())


def test_replay_on_another_frame_is_an_error(sample_scenes):
    _, params = ObjectRemoval()(sample_scenes[0], rng())
    other = sample_scenes[0].replace(boxes=sample_scenes[0].boxes.replace(track_ids=np.arange(len(
        sample_scenes[0].boxes)) + 100))
    with pytest.raises(ValueError, match="another frame"):
        ObjectRemoval().apply(other, params)


# --------------------------------------------------------------------------- in-box corruptions
def test_cutout_only_deletes_inside_the_chosen_box(hdl):
    mutant, params = ObjectCutout(fraction_range=(0.5, 0.5))(hdl, rng())
    gone = rows(hdl.points) - rows(mutant.points)
    assert gone and rows(mutant.points) <= rows(hdl.points)
    xyz = np.array(sorted(gone))[:, :3]
    assert points_in_boxes(xyz, hdl.boxes.as_array()[list(params.objects)], margin=0.06).any(axis=1).all()
    assert mutant.boxes == hdl.boxes


def test_density_loss_drops_the_share_of_the_objects_points(hdl):
    i = biggest(hdl)
    op = ObjectDensityLoss(ratio_range=(0.5, 0.5), classes=(str(hdl.boxes.labels[i]),), count_range=(1, 1))
    mutant, params = op(hdl, rng())
    j = params.objects[0]
    inst = hdl.points.channel("instance")
    own_before = np.count_nonzero(inst == hdl.boxes.track_ids[j])
    own_after = np.count_nonzero(mutant.points.channel("instance") == hdl.boxes.track_ids[j])
    assert 0.4 * own_before <= own_after <= 0.6 * own_before
    assert len(hdl.points) - len(mutant.points) == own_before - own_after  # nothing else lost
    assert mutant.boxes == hdl.boxes


def test_jitter_moves_only_the_objects_points_and_keeps_intensity(hdl):
    mutant, params = ObjectJitter(sigma_range=(0.1, 0.1), count_range=(2, 2))(hdl, rng())
    assert len(mutant.points) == len(hdl.points)
    assert np.array_equal(mutant.points.intensity, hdl.points.intensity)
    moved = np.any(mutant.points.xyz != hdl.points.xyz, axis=1)
    ids = set(hdl.points.channel("instance")[moved].astype(int).tolist())
    assert ids <= {int(hdl.boxes.track_ids[i]) for i in params.objects}
    offsets = (mutant.points.xyz - hdl.points.xyz)[moved]
    assert 0.07 < offsets.std() < 0.13


# --------------------------------------------------------------------------- moves
def _moved_points(source: Scene, mutant: Scene, track_id: int) -> np.ndarray:
    """Points of the object with ``track_id`` in the mutant that are not source points (they moved)."""
    inst = mutant.points.channel("instance") == track_id
    data = mutant.points.data[inst]
    before = rows(source.points)
    fresh = [r not in before for r in map(tuple, data.tolist())]
    return data[np.asarray(fresh, bool)][:, :3]


@pytest.mark.parametrize("kind", ["translate", "rotate", "scale"])
def test_defect_pin_boxes_move_with_their_objects(hdl, kind):
    """The public tools' defect "boxes left behind by object transforms": the moved object's points
    all lie in its updated box, the box moved by exactly the transform, the other boxes unchanged."""
    i = biggest(hdl)
    box = hdl.boxes.as_array()[i]
    tid = int(hdl.boxes.track_ids[i])
    common = {"object": i, "track_id": tid, "fill_ground": True, "seed": 0}
    expected = box.copy()
    if kind == "translate":
        params = ObjectTranslateParams(offset=(1.5, -0.7, 0.02), **common)
        mutant = ObjectTranslate().apply(hdl, params)
        expected[:3] += (1.5, -0.7, 0.02)
    elif kind == "rotate":
        mutant = ObjectRotate().apply(hdl, ObjectRotateParams(angle=30.0, **common))
        expected[6] = (box[6] + np.deg2rad(30.0) + np.pi) % (2 * np.pi) - np.pi
    else:
        mutant = ObjectScale().apply(hdl, ObjectScaleParams(factor=1.2, **common))
        expected[3:6] *= 1.2
        expected[2] = box[2] - box[5] / 2 + expected[5] / 2  # the bottom stays on the ground
    new_box = mutant.boxes.as_array()[i]
    np.testing.assert_allclose(new_box, expected, atol=1e-9)
    others = np.arange(len(hdl.boxes)) != i
    assert mutant.boxes.select(others) == hdl.boxes.select(others)
    moved = _moved_points(hdl, mutant, tid)
    assert len(moved) > 20
    assert points_in_boxes(moved, new_box[None], margin=0.051).all()
    # No point of the object stays behind at the old place outside the new box.
    inst = mutant.points.channel("instance") == tid
    left = points_in_boxes(mutant.points.xyz[inst], box[None])[:, 0] & ~points_in_boxes(
        mutant.points.xyz[inst], new_box[None], margin=0.06)[:, 0]
    assert not left.any()


def _scan(objects: list[np.ndarray], wall_x: float = 25.0) -> Scene:
    """A synthetic 32-beam scan of ±30° azimuth: ground at z = −1.7, a wall at x = ``wall_x``, and
    axis-aligned boxes (centre x, y, z, l, w, h), each ray returning its nearest hit."""
    elevation = np.deg2rad(np.linspace(-20.0, 5.0, 32))
    azimuth = np.deg2rad(np.arange(-30.0, 30.0, 0.2))
    el, az = (a.ravel() for a in np.meshgrid(elevation, azimuth, indexing="ij"))
    ring = np.repeat(np.arange(32), len(azimuth))
    d = np.column_stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(d[:, 2] < 0, -1.7 / d[:, 2], np.inf)
        t = np.minimum(t, np.where(d[:, 0] > 0, wall_x / d[:, 0], np.inf))
        hit_id = np.full(len(d), -1)
        for k, (cx, cy, cz, length, width, height) in enumerate(objects):
            lo, hi = np.array([cx - length / 2, cy - width / 2, cz - height / 2]), np.array(
                [cx + length / 2, cy + width / 2, cz + height / 2])
            t1, t2 = lo / d, hi / d
            near, far = np.nanmax(np.minimum(t1, t2), axis=1), np.nanmin(np.maximum(t1, t2), axis=1)
            hit = (near <= far) & (near > 0) & (near < t)
            t = np.where(hit, near, t)
            hit_id[hit] = k
    ok = np.isfinite(t)
    xyz = d[ok] * t[ok, None]
    cloud = PointCloud.from_channels({"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2],
                                      "intensity": np.full(len(xyz), 0.3), "ring": ring[ok],
                                      "time": np.rad2deg(az[ok]) / 3600, "instance": hit_id[ok]})
    boxes = Boxes3D.create([o[:3] for o in objects], [o[3:] for o in objects], np.zeros(len(objects)),
                           ["Car"] * len(objects), track_ids=np.arange(len(objects)))
    return Scene(cloud, boxes)


@pytest.mark.parametrize("with_ring", [True, False])
def test_moved_object_hides_what_is_behind_it_and_is_hidden_by_what_is_in_front(with_ring):
    car = np.array([12.0, 4.0, -0.95, 4.0, 1.8, 1.5])
    blocker = np.array([6.0, -0.2, -0.7, 0.6, 0.6, 2.0])  # a post in front of the destination
    scene = _scan([car, blocker])
    if not with_ring:  # beams found from the elevations alone
        scene = scene.with_points(scene.points.without_channels(["ring"]))
    params = ObjectTranslateParams(object=0, track_id=0, offset=(0.0, -4.0, 0.0), fill_ground=False, seed=0)
    mutant = ObjectTranslate().apply(scene, params)
    truth = _scan([car + np.array([0.0, -4.0, 0.0, 0, 0, 0]), blocker])  # the same world scanned with the car moved
    xyz, inst = mutant.points.xyz, mutant.points.channel("instance")
    # The wall behind the car's new place is hidden: no wall return there that the true scan lacks.
    new_box = mutant.boxes.as_array()[0]
    az = np.arctan2(xyz[:, 1], xyz[:, 0])
    corners = bev_corners(new_box[None])[0]
    az_lo, az_hi = np.arctan2(corners[:, 1], corners[:, 0]).min(), np.arctan2(corners[:, 1], corners[:, 0]).max()
    # Below the car's roof line (elevation of its far top edge) and above the ground, the wall is hidden.
    wall = (xyz[:, 0] > 24.0) & (az > az_lo + 0.01) & (az < az_hi - 0.01) & (xyz[:, 2] > -1.6) & (xyz[:, 2] < -0.5)
    assert not wall.any()
    assert np.any((truth.points.xyz[:, 0] > 24.0) & (truth.points.xyz[:, 2] > -1.6))  # the wall is there
    # The car's points behind the post are gone.
    car_points = xyz[inst == 0]
    behind_post = np.abs(np.arctan2(car_points[:, 1], car_points[:, 0]) - np.arctan2(-0.2, 6.0)) < np.deg2rad(1.5)
    assert not np.any(behind_post & (car_points[:, 2] < 1.0) & (car_points[:, 2] > -1.0))
    # One return per beam and firing: never more car points than the true scan of the moved car has.
    assert np.count_nonzero(inst == 0) <= 1.1 * np.count_nonzero(truth.points.channel("instance") == 0)
    assert np.count_nonzero(truth.points.channel("instance") == 0) > 50
    # Moved returns carry the beam and firing time of where they now are (time = azimuth° / 3600 here).
    moved = mutant.points.data[inst == 0]
    az_deg = np.rad2deg(np.arctan2(moved[:, 1], moved[:, 0]))
    np.testing.assert_allclose(moved[:, mutant.points.index("time")], az_deg / 3600, atol=0.3 / 3600)
    if with_ring:
        beam = np.rad2deg(np.arctan2(moved[:, 2], np.hypot(moved[:, 0], moved[:, 1])))
        expected = np.abs(beam[:, None] - np.linspace(-20.0, 5.0, 32)[None]).argmin(axis=1)
        assert np.array_equal(moved[:, mutant.points.index("ring")], expected)


def test_moves_replay_and_stay_free(vlp):
    for op in (ObjectTranslate.at_severity(3), ObjectRotate.at_severity(3), ObjectScale.at_severity(5)):
        mutant, params = op(vlp, rng(2))
        assert not params.is_identity()
        assert mutant == op.apply(vlp, op.parse_params(json.loads(params.model_dump_json())))
        moved = mutant.boxes.as_array()[params.object]
        others = [k for k in np.flatnonzero(vlp.boxes.has_geometry) if k != params.object]
        assert iou_bev(moved[None], vlp.boxes.as_array()[others]).max() == 0.0


def test_translation_keeps_road_objects_on_the_road(vlp):
    on_road = [k for k in np.flatnonzero(vlp.boxes.has_geometry)
               if vlp.roi.contains_xy(vlp.boxes.centers[k:k + 1, :2])[0]]
    assert on_road
    op = ObjectTranslate(distance_range=(3.0, 3.0), classes=tuple({str(vlp.boxes.labels[k]) for k in on_road}))
    for trial in range(4):
        mutant, params = op(vlp, rng(trial))
        if params.object in on_road:
            assert vlp.roi.contains_xy(bev_corners(mutant.boxes.as_array()[params.object][None])[0]).all()


# --------------------------------------------------------------------------- insertion
@pytest.fixture(scope="module")
def library_path(sample_scenes, tmp_path_factory) -> str:
    path = tmp_path_factory.mktemp("objects") / "library.npz"
    ObjectLibrary.from_scenes(sample_scenes, min_points=5).save(path)
    return str(path)


def test_library_round_trip_and_normalised_entries(sample_scenes, library_path):
    built = ObjectLibrary.from_scenes(sample_scenes, min_points=5)
    loaded = ObjectLibrary.load(library_path)
    assert len(loaded) == len(built) > 3 and loaded.fingerprint() == built.fingerprint()
    for i in range(len(loaded)):
        pts = loaded.entry_points(i)
        assert len(pts) == loaded.counts[i] >= 5
        assert np.all(np.abs(pts[:, :3]) <= loaded.sizes[i] / 2 + 0.051)  # box frame: centred, yaw 0
        assert pts[:, 3].min() >= 0.0 and pts[:, 3].max() <= 1.0
    assert set(loaded.classes) <= {"Car", "Van", "Truck", "Pedestrian", "Cyclist"}


def test_insertion_adds_a_labelled_occluding_object(hdl, library_path):
    op = ObjectInsertion(library=library_path, count_range=(1, 1), classes=("Car", "Truck"))
    mutant, params = op(hdl, rng(1))
    (ins,) = params.insertions
    assert len(mutant.boxes) == len(hdl.boxes) + 1
    assert mutant.boxes.labels[-1] in ("Car", "Truck")
    assert mutant.boxes.track_ids[-1] == ins.track_id and ins.track_id not in hdl.boxes.track_ids
    box = mutant.boxes.as_array()[-1]
    assert hdl.roi.contains_xy(bev_corners(box[None])[0]).all()
    new = mutant.points.channel("instance") == ins.track_id
    assert new.sum() > 0
    assert points_in_boxes(mutant.points.xyz[new], box[None], margin=0.06).all()
    assert set(mutant.points.channel("label")[new].astype(int)) == {SEMANTIC_ID[mutant.boxes.labels[-1].lower()]}
    assert np.all(mutant.points.channel("ring")[new] >= 0)
    assert np.isfinite(mutant.boxes.alpha[-1]) and mutant.boxes.occlusion[-1] in (0, 1, 2)
    assert mutant.boxes.truncation[-1] <= 0.15  # labels are the camera's: placed in its view
    # Background returns are removed only behind the object: farther than its near side.
    kept = rows(mutant.points)
    gone = np.array([r[:3] for r in map(tuple, hdl.points.data.tolist()) if r not in kept]).reshape(-1, 3)
    assert np.all(np.linalg.norm(gone, axis=1) > np.linalg.norm(box[:2]) - np.hypot(box[3], box[4]) / 2 - 0.3)
    # Replays from JSON.
    rebuilt = from_spec(json.loads(json.dumps(op.spec())))
    assert rebuilt.apply(hdl, rebuilt.parse_params(json.loads(params.model_dump_json()))) == mutant


def test_insertion_checks_the_library_on_replay(vlp, library_path, sample_scenes):
    op = ObjectInsertion(library=library_path)
    _, params = op(vlp, rng())
    other = ObjectInsertion(objects=ObjectLibrary.from_scenes(sample_scenes[:1], min_points=5))
    with pytest.raises(ValueError, match="library"):
        other.apply(vlp, params)
    with pytest.raises(ValueError, match="in-memory"):
        other.spec()


def test_default_library_is_built_once_and_cached(tmp_path, monkeypatch):
    monkeypatch.setenv("LIDARFUZZ_CACHE", str(tmp_path))
    library = ObjectLibrary.default()
    assert (tmp_path / "object_library_sim_v2.npz").exists() and len(library) > 5
    assert ObjectLibrary.default().fingerprint() == library.fingerprint()
