"""Camera modality figures (issue 21): one section per function, each printing a Markdown table.

Usage: ``.venv/bin/python benchmarks/camera.py [--section NAME ...] [--repeat N]``

Sections (all by default):

* ``transforms`` — each registered image transformation (``sample`` + ``apply``) on a 640×480
  frame at severity 3, median of ``--repeat`` runs after one warm-up, wall and CPU time
  (``time.process_time``: on a shared machine the wall clock also counts other processes);
  the ten blur filters of Table 4 one by one; fog on a photo without depth (ground prior).
  Baseline measured in the same run: copying the image. Target: ≤ 5 ms each.

Everything runs on one core (``sched_setaffinity``, ``cv2.setNumThreads(1)``).
"""

from __future__ import annotations

import argparse
import contextlib
import os
import statistics
import time
from collections.abc import Callable

import numpy as np

from lidarfuzz.scene.image import ImageSample

#: Issue 21: each image transformation ≤ 5 ms on a 640×480 image, fog and rain included.
TRANSFORM_TARGET_MS = 5.0


def timed(fn: Callable[[], object], repeat: int) -> tuple[float, float]:
    """Median wall and CPU milliseconds of ``fn`` over ``repeat`` runs after one warm-up."""
    fn()
    wall, cpu = [], []
    for _ in range(repeat):
        started, started_cpu = time.perf_counter(), time.process_time()
        fn()
        cpu.append(time.process_time() - started_cpu)
        wall.append(time.perf_counter() - started)
    return statistics.median(wall) * 1e3, statistics.median(cpu) * 1e3


def road_frame(width: int = 640, height: int = 480) -> ImageSample:
    """A textured 640×480 frame with the inputs fog reads: a z-depth map (a flat road 1.65 m below
    a level camera with a 60° field of view, sky above the horizon) and its camera matrix."""
    rng = np.random.default_rng(0)
    f = width / (2 * np.tan(np.radians(30)))
    k = np.array([[f, 0.0, (width - 1) / 2], [0.0, f, (height - 1) / 2], [0.0, 0.0, 1.0]])
    below = np.arange(height, dtype=np.float64) - k[1, 2]
    depth = np.where(below > 0, f * 1.65 / np.where(below > 0, below, 1.0), np.inf).astype(np.float32)
    image = rng.integers(0, 64, (height, width, 3)) + np.linspace(40, 190, height)[:, None, None]
    return ImageSample(image.astype(np.uint8), frame_id="bench", steering=0.0,
                       depth=np.repeat(depth[:, None], width, axis=1), intrinsics=k)


def transforms(repeat: int) -> None:
    """Per-transformation time on a 640×480 frame at severity 3 (see the module docstring)."""
    from lidarfuzz.operators import available, generator
    from lidarfuzz.operators.camera.convolutional import FILTERS_BY_STRENGTH

    frame = road_frame()
    photo = frame.replace(depth=None, intrinsics=None)
    camera = {name: cls for name, cls in sorted(available().items()) if cls.modality == "camera"}
    print(f"## Image transformations: 640×480, severity 3, median of {repeat}, one core\n")
    copy_wall, copy_cpu = timed(lambda: frame.image.copy(), repeat)
    print("| transformation | wall (ms) | CPU (ms) | CPU × copy | target | met (CPU) |")
    print("|---|---:|---:|---:|---:|---|")
    print(f"| baseline: copy the image | {copy_wall:.3f} | {copy_cpu:.3f} | 1 | | |")
    rows = [(name, cls.at_severity(3), frame) for name, cls in camera.items()]
    rows.append(("image_fog, photo without depth (ground prior)", camera["image_fog"].at_severity(3), photo))
    rows += [(f"image_blur {text}", camera["image_blur"](filters=(text,)), frame) for text in FILTERS_BY_STRENGTH]
    for trial, (label, op, sample) in enumerate(rows):
        wall, cpu = timed(lambda op=op, sample=sample, trial=trial: op(sample, generator(0, "bench", 0, trial)),
                          repeat)
        print(f"| {label} | {wall:.2f} | {cpu:.2f} | {cpu / copy_cpu:.0f} | ≤ {TRANSFORM_TARGET_MS:g} | "
              f"{'yes' if cpu <= TRANSFORM_TARGET_MS else '**no**'} |", flush=True)
    print()


SECTIONS: dict[str, Callable[[int], None]] = {"transforms": transforms}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--section", action="append", choices=sorted(SECTIONS), help="repeatable; default: all")
    parser.add_argument("--repeat", type=int, default=21)
    args = parser.parse_args()
    with contextlib.suppress(AttributeError, OSError):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    import cv2

    cv2.setNumThreads(1)
    for name in args.section or list(SECTIONS):
        SECTIONS[name](args.repeat)
    print(f"OpenCV {cv2.__version__}, numpy {np.__version__}; {os.cpu_count()} CPUs on the machine, "
          f"load average {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
