"""A small simulated world for campaign tests: 3 independent HDL-64E frames in KITTI layout
(dense enough for the classic pipeline to find objects; read-only)."""

from __future__ import annotations

from pathlib import Path

import pytest

from lidarfuzz.sim.dataset import GenerationConfig, generate_dataset


@pytest.fixture(scope="session")
def world(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("world") / "sim"
    generate_dataset(root, GenerationConfig(frames=3, seed=0), workers=1, overwrite=True)
    return root
