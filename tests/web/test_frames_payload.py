"""The viewer's payload beyond the points (:mod:`lidarfuzz.web.frames`): each box's partner and IoU in
its cloud and in the other cloud of a pair, the ``aligned_change`` channel of a geometric operator's
pair (the mutant mapped back by the inverse transform), and lidarfuzz's own errors, which are not the
system's failures (``failed`` stays false and the detections are sent)."""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient

from lidarfuzz.report.bev import FindingPair
from lidarfuzz.scene.boxes import Boxes3D
from lidarfuzz.scene.points import PointCloud
from lidarfuzz.scene.scene import Scene
from lidarfuzz.store import Store
from lidarfuzz.store.contracts import FailureRecord
from lidarfuzz.store.models import Finding, FrameResult
from lidarfuzz.web.frames import ONLY_MUTANT, ONLY_ORIGINAL, SAME, aligned_change_flags, decode, pair_payload

NAN = float("nan")
#: 90° about z, source → mutant: (x, y) → (-y, x)
QUARTER = np.array([[0.0, -1, 0, 0], [1, 0, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])
#: a Car 4 × 2 m and the same box 0.5 m further along its length: 3.5 × 2 = 7 m² shared of
#: 8 + 8 - 7 = 9 m², a BEV IoU of 7 / 9
SHIFTED_IOU = round(7 / 9, 4)


def _points(rows: list[list[float]]) -> PointCloud:
    data = np.array([[*r, 0.5] for r in rows], np.float32)
    return PointCloud(data, ("x", "y", "z", "intensity"))


def _pair(tool_error: str = "") -> FindingPair:
    """A rotate-by-90° finding built by hand: three original points, two of them turned in the mutant and
    one new point; a Car detected 0.5 m off its ground truth, turned with the scene."""
    source_gt = Boxes3D.create([[10, 0, 0], [NAN, NAN, NAN], [20, 20, 0]], [[4, 2, 1.5], [NAN] * 3, [0.8, 0.6, 1.7]],
                               [0, NAN, 0], ["Car", "DontCare", "Pedestrian"])
    mutant_gt = Boxes3D.create([[0, 10, 0], [NAN, NAN, NAN], [-20, 20, 0]],
                               [[4, 2, 1.5], [NAN] * 3, [0.8, 0.6, 1.7]], [math.pi / 2, NAN, math.pi / 2],
                               ["Car", "DontCare", "Pedestrian"])
    source_detections = Boxes3D.create([[10.5, 0, 0], [30, -5, 0]], [[4, 2, 1.5], [0.8, 0.6, 1.7]], [0, 0],
                                       ["Car", "Pedestrian"], scores=[0.9, 0.4])
    follow_detections = Boxes3D.create([[0, 10.5, 0]], [[4, 2, 1.5]], [math.pi / 2], ["Car"], scores=[0.8])
    source = Scene(_points([[10, 0, 0], [0, 5, 1], [20, 20, 0]]), source_gt, frame_id="000007")
    mutant = Scene(_points([[0, 10, 0], [-5, 0, 1], [3, 3, 3]]), mutant_gt, frame_id="000007")
    finding = {"id": 1, "kind": "missing", "frame_id": "000007"}
    return FindingPair(finding, source, mutant, source_detections, follow_detections, transform=QUARTER,
                       tool_error=tool_error)


def test_each_box_has_its_partner_and_iou_in_its_cloud_and_in_the_other() -> None:
    header, _ = decode(pair_payload(_pair()))
    original, mutant = header["boxes"]["original"], header["boxes"]["mutant"]
    # DontCare is not sent: the Pedestrian is ground truth 1 on both sides
    assert original["gt_labels"] == mutant["gt_labels"] == ["Car", "Pedestrian"]
    # in the original: the Car detection matches the Car 0.5 m away; the far Pedestrian matches nothing
    assert original["gt_partner"] == [0, -1] and original["gt_iou"] == [SHIFTED_IOU, None]
    assert original["detection_partner"] == [0, -1] and original["detection_iou"] == [SHIFTED_IOU, None]
    assert mutant["detection_partner"] == [0] and mutant["detection_iou"] == [SHIFTED_IOU]
    assert mutant["gt_partner"] == [0, -1]
    # across the pair: ground truth by position (same labels in the same order), the Car detection
    # turned by 90° lands exactly on the mutant's (IoU 1), the Pedestrian on nothing
    assert original["gt_other"] == [0, 1] and mutant["gt_other"] == [0, 1]
    assert original["detection_other"] == [0, -1] and original["detection_other_iou"] == [1.0, None]
    assert mutant["detection_other"] == [0] and mutant["detection_other_iou"] == [1.0]
    assert original["scores"] == [0.9, 0.4] and mutant["scores"] == [0.8]


def test_a_geometric_pair_carries_its_transform_and_the_aligned_change() -> None:
    header, clouds = decode(pair_payload(_pair()))
    assert header["transform"] == QUARTER.tolist()
    assert header["clouds"][0]["channels"] == ["x", "y", "z", "intensity", "change", "aligned_change"]
    # as sent, every point moved: nothing is in both clouds bit for bit
    assert clouds["original"][:, 4].tolist() == [ONLY_ORIGINAL] * 3
    assert clouds["mutant"][:, 4].tolist() == [ONLY_MUTANT] * 3
    # mapped back by the inverse (x, y) → (y, -x): (0, 10) → (10, 0) and (-5, 0) → (0, 5) are the
    # original's first two points; (3, 3, 3) → (3, -3, 3) is new; the original's (20, 20, 0) is gone
    assert clouds["mutant"][:, 5].tolist() == [SAME, SAME, ONLY_MUTANT]
    assert clouds["original"][:, 5].tolist() == [SAME, SAME, ONLY_ORIGINAL]


def test_aligned_change_tolerates_float32_rounding_and_not_a_real_move() -> None:
    rng = np.random.default_rng(5)
    original = (rng.uniform(-80, 80, (2000, 3))).astype(np.float32)
    angle = math.radians(33)
    turn = np.eye(4)
    turn[:2, :2] = [[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]]
    turn[:3, 3] = [1.5, -2.0, 0.25]
    mutant = (original.astype(np.float64) @ turn[:3, :3].T + turn[:3, 3]).astype(np.float32)
    mutant[7, 2] += 0.01  # one point really moved, 1 cm up: both of its copies are changes
    before, after = aligned_change_flags(original, mutant, turn)
    assert int(np.sum(after == SAME)) == 1999 and after[7] == ONLY_MUTANT
    assert int(np.sum(before == SAME)) == 1999 and before[7] == ONLY_ORIGINAL


def test_a_data_set_frame_did_not_fail() -> None:
    from lidarfuzz.web.frames import scene_payload

    header, _ = decode(scene_payload(_pair().source))
    # no system ran on a data set's frame: no detections, and nothing failed
    assert header["boxes"]["frame"]["failed"] is False and header["boxes"]["frame"]["detections"] == []
    assert header["boxes"]["frame"]["gt_partner"] == [-1, -1]


def test_lidarfuzzs_own_error_is_not_the_systems_failure() -> None:
    message = "relation gt_recall: IndexError: index 0 is out of bounds for axis 0 with size 0"
    header, _ = decode(pair_payload(_pair(tool_error=message)))
    mutant = header["boxes"]["mutant"]
    assert mutant["failed"] is False and len(mutant["detections"]) == 1
    expected = "lidarfuzz's relation gt_recall raised: IndexError: index 0 is out of bounds for axis 0 with size 0"
    assert mutant["tool_error"] == header["tool_error"] == expected
    assert header["boxes"]["original"]["tool_error"] == ""


def test_a_stored_oracle_error_draws_the_detections_and_a_crash_does_not(finished: tuple[TestClient, int]) -> None:
    client, task_id = finished
    workspace = Path(client.get("/api/health").json()["workspace"])
    finding_id = client.get(f"/api/tasks/{task_id}/findings").json()["items"][0]["id"]
    store = Store(workspace)
    with store.session() as s:
        row = s.get(FrameResult, s.get(Finding, finding_id).frame_result_id)
        detections = len(row.detections.boxes())
        row.failure = FailureRecord(kind="oracle_error", detail="gt_recall",
                                    message="relation gt_recall: IndexError: list index out of range")
    header, _ = decode(client.get(f"/api/findings/{finding_id}/frames").content)
    mutant = header["boxes"]["mutant"]
    assert mutant["failed"] is False and len(mutant["detections"]) == detections > 0
    assert mutant["tool_error"] == "lidarfuzz's relation gt_recall raised: IndexError: list index out of range"
    with store.session() as s:
        s.get(FrameResult, s.get(Finding, finding_id).frame_result_id).failure = FailureRecord(
            kind="crash", message="segmentation fault")
    header, _ = decode(client.get(f"/api/findings/{finding_id}/frames").content)
    assert header["boxes"]["mutant"]["failed"] is True and header["boxes"]["mutant"]["detections"] == []
    assert header["boxes"]["mutant"]["tool_error"] == ""
    store.close()


def test_a_log_lists_its_frames_in_replay_order_with_their_times(
        make_client: Callable[..., TestClient], tmp_path: Path) -> None:
    from lidarfuzz.sim.dataset import GenerationConfig, generate_dataset
    from lidarfuzz.store.inventory import add_dataset

    # one scene driven through at 10 Hz: frame k at k / 10 s
    generate_dataset(tmp_path / "log", GenerationConfig(frames=3, seed=1, sequence=True), workers=1, overwrite=True)
    store = Store(tmp_path / "ws")
    add_dataset(store, "log", tmp_path / "log")
    store.close()
    client = make_client()
    listing = client.get("/api/datasets/log/frames").json()
    assert listing["order"] == "timestamps" and listing["frame_ids"] == ["000000", "000001", "000002"]
    assert listing["timestamps"] == pytest.approx([0.0, 0.1, 0.2])
    window = client.get("/api/datasets/log/frames", params={"offset": 1, "limit": 1}).json()
    assert window["frame_ids"] == ["000001"] and window["timestamps"] == pytest.approx([0.1]) and window["total"] == 3
