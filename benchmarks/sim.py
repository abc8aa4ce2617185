"""Throughput of the built-in LiDAR simulator: frame rendering, per-stage cost, and whole data sets.

Usage: ``.venv/bin/python benchmarks/sim.py [--frames 1000] [--sequence-frames 200] [--quick]``

``--quick`` shrinks every size (2 scenes, 3 repeats, 16 + 8 data set frames) for a smoke run;
``--frames 0`` skips the end-to-end data set runs.

Prints Markdown tables, each figure a median of several runs, with ratios against
baselines measured in the same run:

1. rendering at HDL-64E resolution (~133k rays) on pre-compiled worlds, single process and
   in ``--workers`` processes, against (a) the bare Embree trace of the same rays on a
   pre-built Embree scene (the lower bound: everything else is scene upload, noise, labels,
   ROI) and (b) the same rays through trimesh's generic ray API
   (``RayMeshIntersector.intersects_location``/``intersects_first``), as many public Python
   tools cast rays;
2. rendering per sensor preset;
3. where one independent frame's time goes: scene generation, world compilation,
   renderer set-up, rendering, writing (what ``generate_dataset`` does per frame);
4. end to end: ``generate_dataset`` of ``--frames`` independent frames and of a
   ``--sequence-frames`` sequence, into a temporary folder deleted afterwards (1,000
   frames take ~3 GB).

Every section prints CPU time (``time.process_time`` of the process doing the work, or
``getrusage`` of the worker processes) beside wall time, and the load average: on a shared
machine wall time measures the neighbours as much as the simulator. BLAS threads are pinned to
one before numpy loads (the simulator's work is not matrix algebra; extra BLAS threads only
oversubscribe the cores).

Targets (2 CPU cores, issue 25): ≥ 40 frames/s for independent HDL-64E frames; a 1,000-frame
train/val data set in under 45 s end to end. Section 3's CPU sum bounds the first from above
(two free cores render at most 2,000 / CPU ms frames a second).
"""

from __future__ import annotations

import os

for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")  # before numpy loads here and in every worker (they inherit it)

import argparse  # noqa: E402
import importlib.metadata  # noqa: E402
import multiprocessing  # noqa: E402
import multiprocessing.forkserver  # noqa: E402
import platform  # noqa: E402
import resource  # noqa: E402
import shutil  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable  # noqa: E402
from concurrent.futures import ProcessPoolExecutor  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402
import trimesh  # noqa: E402
from embreex import rtcore_scene  # noqa: E402
from embreex.mesh_construction import TriangleMesh  # noqa: E402
from trimesh.ray.ray_pyembree import RayMeshIntersector  # noqa: E402

from lidarfuzz.io.atomic import write_text  # noqa: E402
from lidarfuzz.io.kitti import write_kitti_frame  # noqa: E402
from lidarfuzz.sim.dataset import GenerationConfig, frame_seed, generate_dataset  # noqa: E402
from lidarfuzz.sim.generate import generate_scene  # noqa: E402
from lidarfuzz.sim.meshes import Mesh  # noqa: E402
from lidarfuzz.sim.render import Renderer  # noqa: E402
from lidarfuzz.sim.sensor import SENSOR_PRESETS  # noqa: E402
from lidarfuzz.sim.world import compile_world  # noqa: E402

RENDER_TARGET_FPS = 40.0
DATASET_TARGET_S = 45.0
DATASET_TARGET_FRAMES = 1000


# ---------------------------------------------------------------------------- helpers
def samples(fn: Callable[[], object], repeat: int) -> list[float]:
    """Seconds per call over ``repeat`` calls, after one warm-up call."""
    fn()
    out = []
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        out.append(time.perf_counter() - start)
    return out


def load() -> str:
    """The 1-, 5- and 15-minute load averages, to print beside every timing."""
    return "load average " + ", ".join(f"{v:.2f}" for v in os.getloadavg())


def children_cpu() -> float:
    """CPU seconds (user + system) of the finished worker processes.

    Pool workers are children of the forkserver, which reaps them; stopping the forkserver
    (a private but stable hook that multiprocessing's own tests use) reaps it in turn, so its
    children's time reaches this process's ``RUSAGE_CHILDREN``. The next pool starts a new one.
    """
    stop = getattr(getattr(multiprocessing.forkserver, "_forkserver", None), "_stop", None)
    if stop is not None:
        stop()
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def median_ms(values: list[float]) -> float:
    return statistics.median(values) * 1e3


def version(name: str) -> str:
    try:
        return importlib.metadata.version(name)
    except importlib.metadata.PackageNotFoundError:
        return "?"


def cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "?"


def folder_bytes(root: Path) -> int:
    return sum(f.stat().st_size for f in root.rglob("*") if f.is_file())


def table(header: tuple[str, ...], rows: list[tuple[Any, ...]], align: str) -> None:
    """A Markdown table; ``align`` holds one ``l`` or ``r`` per column."""
    print("| " + " | ".join(header) + " |")
    print("|" + "|".join("---" if a == "l" else "---:" for a in align) + "|")
    for row in rows:
        print("| " + " | ".join(str(c) for c in row) + " |")
    print(flush=True)


def progress(message: str) -> None:
    print(f"  … {message}", file=sys.stderr, flush=True)


def _pool(workers: int) -> ProcessPoolExecutor:
    # Same start method as generate_dataset: children never inherit the parent's Embree thread pool.
    method = "forkserver" if sys.platform.startswith("linux") else "spawn"
    return ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context(method))


def trimesh_of(renderer: Renderer, actors: Mesh) -> trimesh.Trimesh:
    """Static world + road users as one trimesh mesh (no processing: same triangles Embree gets)."""
    static = renderer.world.static
    vertices = np.vstack([static.vertices, actors.vertices]) if len(actors) else static.vertices
    faces = np.vstack([static.faces, actors.faces + len(static.vertices)]) if len(actors) else static.faces
    return trimesh.Trimesh(vertices=vertices, faces=faces, process=False)


def embree_scene(renderer: Renderer, actors: Mesh) -> rtcore_scene.EmbreeScene:
    """Everything in one Embree scene (static world and all road users), as a naive renderer
    would rebuild it per frame (committed by a first query)."""
    scene = rtcore_scene.EmbreeScene(renderer._device)
    static = renderer.world.static
    TriangleMesh(scene, static.vertices.astype(np.float32), static.faces)
    if len(actors):
        TriangleMesh(scene, actors.vertices.astype(np.float32), actors.faces)
    return scene


# ---------------------------------------------------------------------------- 1. rendering
def bench_rendering(seeds: list[int], repeat: int) -> dict[str, float]:
    """Single-process rendering and ray-casting baselines at HDL-64E resolution."""
    rows: dict[str, list[float]] = {}
    hits_ours: list[int] = []
    hits_trimesh: list[int] = []
    intersector_class = ""

    def add(name: str, values: list[float]) -> None:
        rows.setdefault(name, []).extend(values)

    for seed in seeds:
        world = compile_world(generate_scene(seed, sensor="HDL-64E"))
        renderer = Renderer(world)
        times = renderer.actor_times(0.0)
        actors, _owner, _poses = renderer._actor_meshes(times)
        parts = renderer.moving_parts(0.0, times)
        origins, directions = renderer.rays(0.0)
        add("render_new", samples(lambda w=world: Renderer(w).render(0.0, frame_id="000000"), repeat))
        add("render", samples(lambda r=renderer: r.render(0.0, frame_id="000000"), repeat))
        add("cast", samples(lambda r=renderer, o=origins, d=directions, p=parts: r.cast(o, d, p), repeat))
        scene = embree_scene(renderer, actors)
        limit = np.full(len(origins), renderer.sensor.max_range, np.float32)

        def build(r: Renderer = renderer, a: Mesh = actors, o: np.ndarray = origins,
                  d: np.ndarray = directions) -> None:
            embree_scene(r, a).run(o[:1], d[:1])

        add("build", samples(build, repeat))

        def upload(r: Renderer = renderer, a: Mesh = actors) -> None:
            embree_scene(r, a)  # embreex copies the triangles in; Embree builds the BVH on the first query

        add("upload", samples(upload, repeat))
        add("trace", samples(lambda s=scene, o=origins, d=directions, lim=limit: s.run(o, d, dists=lim, output=1),
                             repeat))
        add("trace0", samples(lambda s=scene, o=origins, d=directions: s.run(o, d), repeat))
        add("rays", samples(lambda r=renderer: r.rays(0.0), repeat))
        add("actors", samples(lambda r=renderer: r._actor_meshes(r.actor_times(0.0)), repeat))

        mesh = trimesh_of(renderer, actors)
        intersector_class = f"{type(mesh.ray).__module__}.{type(mesh.ray).__name__}"

        def fresh_location(r: Renderer = renderer, a: Mesh = actors, o: np.ndarray = origins,
                           d: np.ndarray = directions) -> None:
            RayMeshIntersector(trimesh_of(r, a)).intersects_location(o, d, multiple_hits=False)

        add("tm_fresh_location", samples(fresh_location, repeat))
        cached = RayMeshIntersector(mesh)
        add("tm_location", samples(lambda i=cached, o=origins, d=directions:
                                   i.intersects_location(o, d, multiple_hits=False), repeat))
        add("tm_first", samples(lambda i=cached, o=origins, d=directions: i.intersects_first(o, d), repeat))
        hits_ours.append(int((renderer.cast(origins, directions, parts).geometry >= 0).sum()))
        hits_trimesh.append(int((cached.intersects_first(origins, directions) >= 0).sum()))
        progress(f"rendering: scene {seed} done")

    ms = {name: median_ms(values) for name, values in rows.items()}
    trace = ms["trace"]
    reference = ms["tm_fresh_location"]
    labels = [
        ("render_new", "`Renderer.render`, first frame of a world (static Embree scene built)"),
        ("render", "`Renderer.render`, next frames (full frame: actors, rays, cast, noise, labels, ROI)"),
        ("cast", "`Renderer.cast` (static scene + moving road users' scene, nearest hits)"),
        ("build", "naive alternative: one scene of everything rebuilt (upload + BVH, 1 ray)"),
        ("upload", "  of which: embreex `TriangleMesh` upload alone (no BVH build)"),
        ("trace", "baseline (a): bare embreex trace, pre-built scene, `output=1` (lower bound)"),
        ("trace0", "bare embreex trace, pre-built scene, hit ids only (`output=0`)"),
        ("rays", "`Renderer.rays` (world-frame rays, rolling shutter)"),
        ("actors", "`actor_times` + `_actor_meshes` (posed road users)"),
        ("tm_fresh_location", "baseline (b): trimesh `intersects_location`, new intersector (BVH build)"),
        ("tm_location", "trimesh `intersects_location`, cached intersector"),
        ("tm_first", "trimesh `intersects_first`, cached intersector"),
    ]
    rays = SENSOR_PRESETS["HDL-64E"].rays
    print(f"## 1. Rendering at HDL-64E resolution ({rays:,} rays), single process\n")
    print(f"{len(seeds)} generated scenes × {repeat} repeats; median ms. trimesh ray class in use: "
          f"`{intersector_class}`.\n")
    table(("operation", "median (ms)", "frames/s", "× bare trace (a)", "speed-up vs trimesh (b)"),
          [(label, f"{ms[key]:.1f}", f"{1e3 / ms[key]:.1f}", f"{ms[key] / trace:.2f}", f"{reference / ms[key]:.2f}")
           for key, label in labels], "lrrrr")
    print(f"Derived: rendering beyond `Renderer.cast` (noise, physics, labels, ROI, poses) ≈ "
          f"{ms['render'] - ms['cast']:.1f} ms/frame; `Renderer.cast` beyond one bare trace ≈ "
          f"{ms['cast'] - trace:.1f} ms (the moving road users' scene and its trace); a new world's "
          f"static scene ≈ {ms['render_new'] - ms['render']:.1f} ms once.")
    print(f"Hits per frame (mean): ours {np.mean(hits_ours):,.0f} (within max range), "
          f"trimesh {np.mean(hits_trimesh):,.0f} (unbounded).\n", flush=True)
    return ms


def _parallel_worker(seeds: list[int], repeat: int, rounds: int, barrier: Any,
                     ) -> list[tuple[float, int, float]]:
    """Worker: compile its worlds, warm up, then per round (started together) render every world ``repeat``×."""
    # One tracing thread per worker, as generate_dataset gives its workers when they fill the cores.
    renderers = [Renderer(compile_world(generate_scene(seed, sensor="HDL-64E")), threads=1) for seed in seeds]
    for renderer in renderers:
        renderer.render(0.0)
    out = []
    for _ in range(rounds):
        barrier.wait()
        start, cpu = time.perf_counter(), time.process_time()
        for renderer in renderers:
            for _ in range(repeat):
                renderer.render(0.0, frame_id="000000")
        out.append((time.perf_counter() - start, len(renderers) * repeat, time.process_time() - cpu))
    return out


def bench_parallel(seeds: list[int], repeat: int, rounds: int, workers: int, single_ms: float) -> float:
    """Frames/s with ``workers`` processes rendering independent frames at once."""
    context = multiprocessing.get_context("forkserver" if sys.platform.startswith("linux") else "spawn")
    with context.Manager() as manager, _pool(workers) as pool:
        barrier = manager.Barrier(workers)
        shares = [seeds[k::workers] or seeds for k in range(workers)]
        futures = [pool.submit(_parallel_worker, share, repeat, rounds, barrier) for share in shares]
        results = [f.result() for f in futures]
    # The barrier aligns each round's start; the round lasts as long as its slowest worker.
    fps = [sum(r[i][1] for r in results) / max(r[i][0] for r in results) for i in range(rounds)]
    best = statistics.median(fps)
    single_fps = 1e3 / single_ms
    frames = sum(r[0][1] for r in results)
    cpu_ms = statistics.median(sum(r[i][2] for r in results) / sum(r[i][1] for r in results) * 1e3
                               for i in range(rounds))
    print(f"### Rendering in {workers} processes (independent frames, {frames} frames per round, "
          f"median of {rounds} rounds)\n")
    table(("configuration", "frames/s", "ms/frame (wall)", "CPU ms/frame", "× single process", "target"),
          [("1 process", f"{single_fps:.1f}", f"{single_ms:.1f}", "", "1.00", ""),
           (f"{workers} processes", f"{best:.1f}", f"{1e3 / best:.1f}", f"{cpu_ms:.1f}", f"{best / single_fps:.2f}",
            f"≥ {RENDER_TARGET_FPS:.0f} frames/s: {'met' if best >= RENDER_TARGET_FPS else 'NOT met'}")],
          "lrrrrl")
    print(f"CPU ms/frame: the workers' own CPU time (all their threads) per frame rendered; {load()}.\n")
    return best


# ---------------------------------------------------------------------------- 2. presets
def bench_presets(seeds: list[int], repeat: int) -> None:
    rows = []
    for name, sensor in SENSOR_PRESETS.items():
        render, trace, points = [], [], []
        for seed in seeds:
            spec = generate_scene(seed).model_copy(update={"sensor": name})
            renderer = Renderer(compile_world(spec))
            render += samples(lambda r=renderer: r.render(0.0, frame_id="000000"), repeat)
            actors, _owner, _poses = renderer._actor_meshes(renderer.actor_times(0.0))
            origins, directions = renderer.rays(0.0)
            scene = embree_scene(renderer, actors)
            limit = np.full(len(origins), sensor.max_range, np.float32)
            trace += samples(lambda s=scene, o=origins, d=directions, lim=limit: s.run(o, d, dists=lim, output=1),
                             repeat)
            points.append(len(renderer.render(0.0).points))
        ms, trace_ms = median_ms(render), median_ms(trace)
        rows.append((name, f"{sensor.beams} × {sensor.columns}", f"{sensor.rays:,}", f"{np.mean(points):,.0f}",
                     f"{ms:.1f}", f"{1e3 / ms:.1f}", f"{trace_ms:.1f}", f"{ms / trace_ms:.2f}",
                     f"{ms * 1e3 / sensor.rays:.2f}"))
        progress(f"presets: {name} done")
    print(f"## 2. Rendering per sensor preset, single process ({len(seeds)} scenes × {repeat} repeats)\n")
    table(("preset", "beams × columns", "rays", "points/frame", "render (ms)", "frames/s", "bare trace (ms)",
           "× bare trace", "µs per 1k rays"), rows, "llrrrrrrr")


# ---------------------------------------------------------------------------- 3. breakdown
def bench_breakdown(frames: int, workers: int) -> float:
    """Per-stage time of independent frames, as ``generate_dataset`` produces them (frame seeds of seed 0)."""
    keys = ("generate", "compile", "renderer", "render", "spec", "kitti")
    stages: dict[str, list[float]] = {k: [] for k in keys}
    cpu_stages: dict[str, list[float]] = {k: [] for k in keys}
    sizes = []
    work = Path(tempfile.mkdtemp(prefix="lidarfuzz-bench-sim-"))
    try:
        for index in range(frames + 1):  # the first frame warms imports and caches; not counted
            frame_id = f"{index:06d}"
            clock = [(time.perf_counter(), time.process_time())]
            spec = generate_scene(frame_seed(0, index))
            clock.append((time.perf_counter(), time.process_time()))
            world = compile_world(spec)
            clock.append((time.perf_counter(), time.process_time()))
            renderer = Renderer(world, threads=1)  # as in a data set worker when the workers fill the cores
            clock.append((time.perf_counter(), time.process_time()))
            scene = renderer.render(0.0, frame_id=frame_id).replace(pose=None)
            clock.append((time.perf_counter(), time.process_time()))
            write_text(work / "scenes" / f"{frame_id}.json", spec.to_json(), overwrite=True, durable=False)
            clock.append((time.perf_counter(), time.process_time()))
            write_kitti_frame(work, scene, frame_id, overwrite=True, durable=False, labelled_set=True)
            clock.append((time.perf_counter(), time.process_time()))
            if index:
                for key, a, b in zip(keys, clock[:-1], clock[1:], strict=True):
                    stages[key].append(b[0] - a[0])
                    cpu_stages[key].append(b[1] - a[1])
        sizes = [folder_bytes(work) / (frames + 1)]
    finally:
        shutil.rmtree(work, ignore_errors=True)
    ms = {key: median_ms(values) for key, values in stages.items()}
    cpu = {key: median_ms(values) for key, values in cpu_stages.items()}
    total = sum(ms.values())
    cpu_total = sum(cpu.values())
    labels = {
        "generate": "`generate_scene` (procedural layout)",
        "compile": "`compile_world` (meshes, trajectories)",
        "renderer": "`Renderer(world)` (ray tables)",
        "render": "`Renderer.render`",
        "spec": "write scene JSON (`scenes/*.json`)",
        "kitti": "`write_kitti_frame` (bin, npz, calib, labels, roi)",
    }
    print(f"## 3. One independent HDL-64E frame, stage by stage (median of {frames} frames, single process)\n")
    table(("stage", "median wall (ms)", "median CPU (ms)", "share of CPU"),
          [*((labels[k], f"{v:.1f}", f"{cpu[k]:.1f}", f"{100 * cpu[k] / cpu_total:.0f} %") for k, v in ms.items()),
           ("**sum**", f"**{total:.1f}**", f"**{cpu_total:.1f}**", "100 %")], "lrrr")
    print(f"One tracing thread; {load()}. Serial cost {cpu_total:.0f} ms of CPU per frame ({total:.0f} ms wall) → "
          f"at best {workers * 1e3 / cpu_total:.1f} frames/s on {workers} free cores (ideal scaling): "
          f"{DATASET_TARGET_FRAMES:,} frames in ≥ {DATASET_TARGET_FRAMES * cpu_total / 1e3 / workers:.0f} s. "
          f"Written: {sizes[0] / 1e6:.2f} MB/frame.\n", flush=True)
    return cpu_total


# ---------------------------------------------------------------------------- 4. end to end
def bench_dataset(frames: int, sequence_frames: int, workers: int, serial_ms: float, tmp: str | None) -> None:
    rows = []
    cases = [("independent frames", frames, False)]
    if sequence_frames:
        cases.append(("sequence", sequence_frames, True))
    for name, n, sequence in cases:
        work = Path(tempfile.mkdtemp(prefix="lidarfuzz-bench-sim-", dir=tmp))
        try:
            out = work / "dataset"
            children_before = children_cpu()
            start, parent_cpu = time.perf_counter(), time.process_time()
            summary = generate_dataset(out, GenerationConfig(frames=n, seed=0, sequence=sequence), workers=workers,
                                       overwrite=True)
            seconds = time.perf_counter() - start
            cpu_s = time.process_time() - parent_cpu + children_cpu() - children_before
            size = folder_bytes(out)
        finally:
            shutil.rmtree(work, ignore_errors=True)
        fps = n / seconds
        projected = DATASET_TARGET_FRAMES / fps
        verdict = ""
        if not sequence:
            verdict = f"< {DATASET_TARGET_S:.0f} s: {'met' if projected < DATASET_TARGET_S else 'NOT met'}"
        ideal = n * serial_ms / 1e3 / workers
        rows.append((name, f"{n:,}", f"{seconds:.1f}", f"{fps:.1f}", f"{1e3 * seconds / n:.0f}",
                     f"{1e3 * cpu_s / n:.0f}", f"{size / 1e6:,.0f}",
                     f"{size / 1e6 / n:.2f}", f"{summary.points_per_frame:,.0f}",
                     f"{seconds / ideal:.2f}" if not sequence else "—", f"{projected:.0f}", verdict))
        progress(f"data set: {name} done")
    print(f"## 4. End to end: `generate_dataset` with {workers} workers (one run each, temporary folder)\n")
    table(("data set", "frames", "total (s)", "frames/s", "ms/frame (wall)", "CPU ms/frame", "MB written",
           "MB/frame", "points/frame", "× ideal (§3 CPU sum / workers)", f"projected s for {DATASET_TARGET_FRAMES:,}",
           "target"), rows, "lrrrrrrrrrrl")
    print(f"CPU ms/frame: the parent's and every worker's CPU time (start-up and imports included) per frame; "
          f"{load()}.")
    print("Small runs are dominated by fixed costs (worker start-up by forkserver, imports, the pool's tail); "
          "the projection scales the measured rate linearly.\n", flush=True)


# ---------------------------------------------------------------------------- main
def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=None, help="independent frames end to end (default 1000)")
    parser.add_argument("--sequence-frames", type=int, default=None, help="sequence frames end to end (default 200)")
    parser.add_argument("--scenes", type=int, default=None, help="generated scenes for rendering (default 4)")
    parser.add_argument("--repeat", type=int, default=None, help="renders per scene (default 5)")
    parser.add_argument("--rounds", type=int, default=None, help="rounds of the multi-process render (default 3)")
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--tmp", default=None, help="folder for the end-to-end data sets (default: system temp)")
    parser.add_argument("--quick", action="store_true", help="small sizes for a smoke run")
    parser.add_argument("--sections", default="1234",
                        help="which numbered sections to run (default all: 1234); 1 is needed for 1's "
                             "multi-process part to print its single-process ratio")
    args = parser.parse_args()
    quick = {"frames": 16, "sequence_frames": 8, "scenes": 2, "repeat": 3, "rounds": 2}
    full = {"frames": DATASET_TARGET_FRAMES, "sequence_frames": 200, "scenes": 4, "repeat": 5, "rounds": 3}
    for key, value in (quick if args.quick else full).items():
        if getattr(args, key) is None:
            setattr(args, key, value)

    print("# lidarfuzz simulator throughput\n")
    affinity = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    print(f"Machine: {cpu_model()}, {os.cpu_count()} CPUs ({affinity} usable); Python {platform.python_version()}; "
          f"numpy {np.__version__}; embreex {version('embreex')}; trimesh {trimesh.__version__}; "
          f"lidarfuzz {version('lidarfuzz')}. Workers: {args.workers}.\n", flush=True)

    print(f"Start: {load()}.\n", flush=True)
    seeds = list(range(args.scenes))
    serial = float("nan")
    if "1" in args.sections:
        ms = bench_rendering(seeds, args.repeat)
        bench_parallel(seeds, args.repeat, args.rounds, args.workers, ms["render"])
    if "2" in args.sections:
        bench_presets(seeds, max(1, args.repeat // 2 + 1))
    if "3" in args.sections:
        serial = bench_breakdown(args.scenes * args.repeat, args.workers)
    if "4" in args.sections and args.frames > 0:
        bench_dataset(args.frames, args.sequence_frames, args.workers, serial, args.tmp)
    print(f"End: {load()}.", flush=True)


if __name__ == "__main__":
    main()
