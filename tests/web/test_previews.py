"""Operator previews (``GET /api/operators/{name}/preview.png``): the picture's layout, the changed
points highlighted as the viewer's change channel colours them, and the disk cache."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
from fastapi.testclient import TestClient

from lidarfuzz.scene.boxes import Boxes3D
from lidarfuzz.scene.points import PointCloud
from lidarfuzz.scene.scene import Scene
from lidarfuzz.web import previews
from lidarfuzz.web.previews import ADDED, HEADER, KEPT, REMOVED, preview_picture

# by hand: a 60 m × 60 m view at 6 px/m is a 360 × 360 panel; two panels, a 6 px gap, a 44 px header
WIDTH, HEIGHT = 2 * 360 + 6, 44 + 360


def decode(png: bytes) -> np.ndarray:
    """RGB pixels of a PNG."""
    return cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)[:, :, ::-1]


def scene(xyz: list[list[float]]) -> Scene:
    data = np.zeros((len(xyz), 4), np.float32)
    data[:, :3] = xyz
    return Scene(points=PointCloud(data, ("x", "y", "z", "intensity")), boxes=Boxes3D.empty(), frame_id="f")


def test_changed_points_are_drawn_in_the_viewers_colours() -> None:
    # three points on the road; the mutant keeps the first, moves the second 2 m left, drops the third
    original = scene([[20.0, 0.0, 1.5], [30.0, 10.0, 1.5], [40.0, -10.0, 1.5]])
    mutant = scene([[20.0, 0.0, 1.5], [30.0, 12.0, 1.5]])
    image = preview_picture(original, mutant, "op@3")
    assert image.shape == (HEIGHT, WIDTH, 3)

    def pixel(panel: int, x: float, y: float) -> tuple[int, ...]:
        # row = (50 - x) * 6 below the header, column = (30 - y) * 6, plus 366 for the right panel
        return tuple(int(v) for v in image[HEADER + round((50 - x) * 6), round((30 - y) * 6) + panel * 366])

    # z = 1.5 m is at the top of the height scale: the grey at its lightest, KEPT * 1.25
    kept = tuple(min(255, int(c * 1.25)) for c in KEPT)
    assert pixel(0, 20.0, 0.0) == kept and pixel(1, 20.0, 0.0) == kept  # unchanged: grey on both sides
    assert pixel(0, 30.0, 10.0) == REMOVED and pixel(0, 40.0, -10.0) == REMOVED  # only the original's: red
    assert pixel(1, 30.0, 12.0) == ADDED  # only the mutant's (moved): green
    assert pixel(1, 40.0, -10.0) != REMOVED  # the dropped point is not drawn on the mutant's side


def test_a_preview_highlights_what_the_operator_changed(client: TestClient, tmp_path: Path) -> None:
    def panels(name: str, severity: int) -> tuple[np.ndarray, np.ndarray]:
        reply = client.get(f"/api/operators/{name}/preview.png", params={"severity": severity})
        assert reply.status_code == 200 and reply.headers["content-type"] == "image/png"
        image = decode(reply.content)
        assert image.shape == (HEIGHT, WIDTH, 3)
        return image[HEADER:, :360], image[HEADER:, 366:]

    def count(panel: np.ndarray, colour: tuple[int, int, int]) -> int:
        return int((panel == colour).all(axis=-1).sum())

    left, right = panels("rotate_z", 0)  # severity 0: the identity, nothing changes
    assert count(left, REMOVED) == count(right, ADDED) == 0
    left, right = panels("rotate_z", 3)  # every point turns about the sensor: moved on both sides
    assert count(left, REMOVED) > 5000 and count(right, ADDED) > 5000
    left, right = panels("fog", 5)  # fog loses far returns (red) and adds a few near the sensor (green)
    assert count(left, REMOVED) > 1000 and count(left, REMOVED) > count(right, ADDED)
    cached = sorted(p.name for p in (tmp_path / "ws" / "cache" / "web" / "previews").glob("*.png"))
    assert [n.split("-")[:2] for n in cached] == [["fog", "s5"], ["rotate_z", "s0"], ["rotate_z", "s3"]]


def test_a_preview_is_drawn_once(client: TestClient, tmp_path: Path) -> None:
    """The second request reads the file the first wrote (its time is benchmarks/web_previews.py's, not a
    test's: timings do not fail tests). The preview frame is cut to 60 m around the sensor, as the view needs."""
    reply = client.get("/api/operators/global_scale/preview.png", params={"severity": 3})
    assert reply.status_code == 200
    folder = tmp_path / "ws" / "cache" / "web"
    (path,) = (folder / "previews").glob("global_scale-s3-*.png")
    written = path.stat().st_mtime_ns
    assert client.get("/api/operators/global_scale/preview.png", params={"severity": 3}).content == reply.content
    assert path.stat().st_mtime_ns == written
    xy = np.asarray(previews.preview_frame(folder).points.xyz[:, :2], dtype=np.float64)
    assert len(xy) > 50_000 and np.hypot(xy[:, 0], xy[:, 1]).max() <= previews.RADIUS


def test_a_failures_thumbnail_is_framed_in_red() -> None:
    """A finding where the system gave no output: the mutant from above in a red frame (bev's
    HIGHLIGHT_COLOUR #d7191c), 160 × 120; with an output, no frame."""
    from lidarfuzz.report.bev import FindingPair, draw_thumbnail
    from lidarfuzz.report.charts import figure_png

    frame = scene([[20.0, 0.0, 0.0], [25.0, 5.0, 0.5]])
    failed = FindingPair({"id": 1, "kind": "crash"}, frame, frame, Boxes3D.empty(), None)
    image = decode(figure_png(draw_thumbnail(failed), colours=64))
    assert image.shape == (120, 160, 3)
    red = (np.abs(image.astype(int) - (215, 25, 28)).max(axis=-1) < 40)
    assert red[0].mean() > 0.9 and red[-1].mean() > 0.9 and red[:, 0].mean() > 0.9  # top, bottom, left edges
    held = FindingPair({"id": 1, "kind": "equivariance"}, frame, frame, Boxes3D.empty(), Boxes3D.empty())
    assert not (np.abs(decode(figure_png(draw_thumbnail(held))).astype(int) - (215, 25, 28)).max(axis=-1) < 40).any()
