"""Registering a data set through the web API with a point layout: nuScenes-like sweeps uploaded
as plain .bin frames are refused as KITTI scans (naming the layout that fits) and accepted with
``layout``, which the app then uses to read the frames."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from fastapi.testclient import TestClient


def _sweep(seed: int) -> bytes:
    """x y z intensity ring float32, 300 points (6,000 bytes: 375 KITTI records too)."""
    rng = np.random.default_rng(seed)
    columns = [rng.uniform(-40, 40, (300, 3)), rng.integers(0, 235, (300, 1)), rng.integers(0, 32, (300, 1))]
    return np.hstack(columns).astype("<f4").tobytes()


def test_upload_with_a_layout(make_client: Callable[..., TestClient]) -> None:
    client = make_client()
    files = [("files", (f"00000{i}.bin", _sweep(i))) for i in range(2)]
    refused = client.post("/api/datasets/upload", data={"name": "sweeps"}, files=files)
    assert refused.status_code == 422 and "try --layout nuscenes" in refused.json()["detail"]
    bad = client.post("/api/datasets/upload", data={"name": "sweeps", "layout": "x,y:f4"}, files=files)
    assert bad.status_code == 422 and bad.json()["detail"].startswith("layout 'x,y:f4': no 'z' column")
    reply = client.post("/api/datasets/upload", data={"name": "sweeps", "layout": "nuscenes",
                                                      "allow_unlabelled": "true"}, files=files)
    assert reply.status_code == 201, reply.text
    assert reply.json()["options"] == {"layout": "nuscenes", "allow_unlabelled": True}
    frame = client.get("/api/datasets/sweeps/frames/000001")
    assert frame.status_code == 200  # read with the stored layout (as KITTI it would be refused)
