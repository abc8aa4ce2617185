"""``Gate`` (:mod:`tests.campaign.structural_system`) as a program speaking the worker protocol for logs,
for the structural campaign's ``worker:`` test. Run from the repository's root."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository: tests is a package there

from lidarfuzz.scene.points import PointCloud
from lidarfuzz.scene.scene import Scene
from tests.campaign.structural_system import Gate


def main() -> int:
    gate = Gate()
    for line in sys.stdin:
        if not line.strip():
            return 0
        request = json.loads(line)
        if request.get("reset"):
            gate.reset()
            print(json.dumps({"ok": True, "id": request["id"]}), flush=True)
            continue
        points = np.fromfile(request["points"], dtype=np.float32).reshape(-1, 4)
        decision = gate.step(Scene(PointCloud(points), frame_id=str(request.get("frame_id", ""))))
        print(json.dumps({**decision.to_dict(), "id": request["id"]}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
