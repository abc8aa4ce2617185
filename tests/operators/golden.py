"""Every LiDAR operator's output on fixed frames and seeds, as recorded before the speed work of
issue 25, so that a faster implementation is checked against what the operator computed before.

Each case (operator, severity, frame) is kept as the SHA-256 of the mutant's exact bytes (points,
boxes, labels, the drawn params) and, for a machine whose SIMD dispatch differs from the one that
recorded it (numpy's transcendental functions may then differ in the last bit), a fingerprint:
the point count and float64 sums of every channel and of the boxes.

Recorded with ``python -m tests.operators.golden --write`` (on the code before the change); the
test is ``tests/operators/test_bit_identity.py``.
"""

from __future__ import annotations

import argparse
import hashlib
import json
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np

from lidarfuzz.operators import available, generator
from lidarfuzz.scene.scene import Scene

GOLDEN = Path(__file__).with_name("golden_outputs.json")
SEVERITIES = (1, 5)
SEED = 7


@cache
def frames() -> dict[str, Scene]:
    """A VLP-16 frame of a simulated sequence (labelled, timed, posed, with a ROI) and an HDL-64E
    frame of an independent scene (~110k points), both from the built-in simulator."""
    from lidarfuzz.sim.dataset import GenerationConfig, render_frames

    vlp = next(iter(render_frames(GenerationConfig(frames=1, seed=7, sequence=True, sensor="VLP-16"))))
    hdl = next(iter(render_frames(GenerationConfig(frames=1, seed=11))))
    return {"vlp16": vlp, "hdl64": hdl}


def simd_features() -> list[str]:
    """The CPU features numpy dispatches on here (a recorded digest holds for the same set)."""
    from numpy._core._multiarray_umath import __cpu_features__

    return sorted(name for name, present in __cpu_features__.items() if present)


def operators() -> list[str]:
    return sorted(name for name, cls in available().items() if cls.modality == "lidar")


def run_case(name: str, severity: int, frame: str) -> tuple[Scene, Any] | str:
    """The mutant and its params (or the operator's exception, as ``Type: message``)."""
    op = available()[name].at_severity(severity)
    try:
        return op(frames()[frame], generator(campaign_seed=SEED, frame_id=frame, operator_index=0, trial=0))
    except Exception as exc:  # recorded as it is: a refusal is a result too
        return f"{type(exc).__name__}: {exc}"


def describe(name: str, severity: int, frame: str) -> dict[str, Any]:
    """The case's digest and fingerprint (see the module docstring)."""
    outcome = run_case(name, severity, frame)
    if isinstance(outcome, str):
        return {"error": outcome}
    mutant, params = outcome
    points = np.ascontiguousarray(mutant.points.data)
    boxes = np.ascontiguousarray(mutant.boxes.as_array(), dtype=np.float64)
    params_json = json.dumps(params.model_dump(mode="json"), sort_keys=True, default=str)
    digest = hashlib.sha256()
    for part in (points.tobytes(), str(points.dtype).encode(), json.dumps(list(mutant.points.channels)).encode(),
                 boxes.tobytes(), json.dumps(list(mutant.boxes.labels)).encode(), params_json.encode()):
        digest.update(hashlib.sha256(part).digest())
    return {"sha256": digest.hexdigest(), "points": int(points.shape[0]),
            "channel_sums": [float(v) for v in points.astype(np.float64).sum(axis=0)],
            "box_sum": float(boxes.sum()), "boxes": int(boxes.shape[0]), "params": params_json}


def record() -> dict[str, Any]:
    cases = {f"{name}@{severity}/{frame}": describe(name, severity, frame)
             for name in operators() for severity in SEVERITIES for frame in frames()}
    return {"simd": simd_features(), "numpy": np.__version__, "cases": cases}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--write", action="store_true", help=f"record the outputs into {GOLDEN.name}")
    args = parser.parse_args()
    recorded = record()
    if args.write:
        GOLDEN.write_text(json.dumps(recorded, indent=1, sort_keys=True) + "\n")
        print(f"wrote {len(recorded['cases'])} cases to {GOLDEN}")
    else:
        print(json.dumps(recorded, indent=1, sort_keys=True))


if __name__ == "__main__":
    main()
