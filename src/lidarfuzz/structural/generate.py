"""Generated logs (Neves et al., Section IV): new point clouds made per segment and merged into it.

Given a base log L' — the segments a heuristic selected (or the tester chose), replayed in the
log's order — a *strategy* makes new frames inside each segment of k frames:

* a **unary** strategy St(pc) ↦ pc' inserts each mutated frame right after its source:
  ``pc1 pc1' pc2 pc2' … pck pck'`` — 2k frames. ``HGT`` is the paper's: every point's z plus a
  constant c (:class:`~lidarfuzz.operators.lidar.geometric.HeightShift` with ``offset_range``
  [c, c]; the paper's c is 10, here in metres, the default). Any other registered operator is used
  the same way, at a severity (3 by default), each mutant drawn from
  ``generator(seed, source frame id, stream, 0)`` where ``stream`` is the operator's seed stream
  in campaigns (:func:`operator_stream`): the same frame, seed and operator give the same mutant
  here and in a campaign.
* a **binary** strategy St(pc, pc) ↦ pc' inserts each combined frame between its two sources:
  ``pc1 avg(1,2) pc2 … avg(k−1,k) pck`` — 2k − 1 frames. ``AVG`` is the paper's, point-wise
  averages of consecutive frames (:class:`~lidarfuzz.operators.lidar.log.FrameAverage`: matched by
  range-image cell when both frames have rings, else by mutual nearest neighbours).
* ``none`` copies the segments unchanged: the reduced base log L' itself.

Frames are never combined across two segments. Copied frames keep their timestamps; an
inserted frame lies half-way between its neighbours (AVG: between its two sources; a unary
mutant: between its source and the next frame of the segment, or half the segment's last gap
after the last one). A parent without timestamps (a sequence of poses) gives a generated log
timed at 10 Hz by position, so the result is always a log :func:`~lidarfuzz.structural.logs.open_log`
opens in the same order.

The generated log is a KITTI-layout folder with ``timestamps.txt`` and ``generated_log.json``
(:class:`GeneratedLog`: the parent log, heuristic, strategy, seed, segments, and per frame its
provenance — the source frame(s), operator spec and concrete params). It is written into a
temporary folder renamed into place at the end (:func:`lidarfuzz.io.atomic.atomic_folder`): a
failure on any frame leaves nothing behind.
"""

from __future__ import annotations

import json
import zlib
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import asdict, dataclass, field
from os import PathLike
from pathlib import Path
from typing import Any, Literal

from lidarfuzz.errors import LidarfuzzError
from lidarfuzz.io.atomic import atomic_folder
from lidarfuzz.io.kitti import KittiWriter
from lidarfuzz.operators.base import Operator, generator
from lidarfuzz.operators.lidar.log import FrameAverage
from lidarfuzz.operators.registry import get
from lidarfuzz.scene.scene import Scene
from lidarfuzz.structural.logs import OrderedLog
from lidarfuzz.structural.segments import Segment

#: The paper's height constant for HGT.
PAPER_HEIGHT = 10.0
#: The manifest written beside the frames.
MANIFEST = "generated_log.json"
#: Seconds between frames of a generated log whose parent has no clock.
UNTIMED_PERIOD = 0.1


class GenerationError(LidarfuzzError):
    """A strategy that cannot be built, or that failed on a frame (named)."""


def operator_stream(name: str) -> int:
    """An operator's seed stream: the same number campaigns use for it at any severity
    (:func:`lidarfuzz.campaign.plan.operator_stream` without a config; not imported, so the
    engine may depend on this package)."""
    return zlib.crc32(name.encode("utf-8")) & 0x7FFFFFFF


@dataclass(frozen=True)
class Strategy:
    """How new frames are made: ``arity`` 0 (copy), 1 (a mutation after each frame) or 2 (a
    combination between consecutive frames)."""

    name: str
    arity: Literal[0, 1, 2]
    operator: Operator[Scene, Any, Any] | None = None
    average: FrameAverage | None = None

    @property
    def stream(self) -> int:
        return operator_stream(self.operator.name) if self.operator is not None else 0


def strategy(name: str, *, height: float = PAPER_HEIGHT, severity: int = 3, radius: float = 0.5) -> Strategy:
    """The strategy called ``name``: ``HGT`` (z + ``height``), ``AVG`` (pairs within ``radius``
    when there are no rings), ``none``, or any registered operator at ``severity``.

    Raises:
        GenerationError: An unknown name or severity, in one line.
    """
    key = name.strip().lower().replace("-", "_")
    if key in ("none", "base"):
        return Strategy("none", 0)
    if key in ("avg", "frame_average"):
        return Strategy("AVG", 2, average=FrameAverage(radius=radius))
    try:
        cls = get(name)
    except LidarfuzzError as exc:
        raise GenerationError(f"--strategy {name!r}: {exc} (or HGT, AVG, none)") from None
    if cls.name == "height_shift" and key == "hgt":
        return Strategy("HGT", 1, operator=cls(offset_range=(height, height)))
    try:
        return Strategy(cls.name, 1, operator=cls.at_severity(severity))
    except ValueError as exc:
        raise GenerationError(f"--severity {severity}: {exc}") from None


@dataclass(frozen=True)
class Provenance:
    """Where one frame of a generated log comes from.

    Attributes:
        position: Its place in the generated log.
        frame_id: Its id there.
        segment: The parent's segment it belongs to.
        sources: The parent's frame id(s) it was made from (one for a copy or a mutant, two for AVG).
        operator: The operator's spec; ``None`` for a frame copied unchanged.
        params: The concrete params (an operator's; AVG's correspondence and radius).
    """

    position: int
    frame_id: str
    segment: int
    sources: tuple[str, ...]
    operator: dict[str, Any] | None = None
    params: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class GeneratedLog:
    """A generated log's record (what ``generated_log.json`` holds)."""

    path: str
    parent: str
    parent_frames: int
    heuristic: str | None
    strategy: str
    seed: int
    segment_size: int
    segments: tuple[int, ...]
    frames: tuple[Provenance, ...]

    def to_json(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> GeneratedLog:
        frames = tuple(Provenance(**{**f, "sources": tuple(f["sources"])}) for f in data["frames"])
        return cls(**{**data, "segments": tuple(data["segments"]), "frames": frames})

    @classmethod
    def read(cls, folder: str | PathLike[str]) -> GeneratedLog:
        return cls.from_json(json.loads((Path(folder) / MANIFEST).read_text(encoding="utf-8")))


def expected_frames(segment_frames: int, arity: int) -> int:
    """Frames a segment of k frames becomes: k (copy), 2k (unary), 2k − 1 (binary)."""
    if arity == 0:
        return segment_frames
    return 2 * segment_frames if arity == 1 else 2 * segment_frames - 1


def _midpoint(a: float | None, b: float | None) -> float | None:
    return None if a is None or b is None else (a + b) / 2


def _segment_frames(log: OrderedLog, segment: Segment, chosen: Strategy, seed: int,
                    ) -> Iterator[tuple[Scene, tuple[str, ...], dict[str, Any] | None, dict[str, Any]]]:
    """(frame, sources, operator spec, params) for one segment, in the generated order."""
    frames = list(log.frames(segment.positions))
    times = [f.timestamp for f in frames]
    for i, frame in enumerate(frames):
        source = frame.frame_id or log.frame_ids[segment.first + i]
        if chosen.arity == 2 and i:
            assert chosen.average is not None
            previous = frames[i - 1]
            combined = chosen.average.apply(previous, frame)
            params = {"correspondence": combined.metadata.get("frame_average_correspondence"),
                      "radius": chosen.average.radius}
            yield combined, (previous.frame_id or "", source), {"name": "AVG"}, params
        yield frame, (source,), None, {}
        if chosen.arity == 1:
            assert chosen.operator is not None
            mutant, params = chosen.operator(frame, generator(seed, source, chosen.stream, 0))
            if i + 1 < len(frames):
                stamp = _midpoint(times[i], times[i + 1])
            elif i and times[i] is not None and times[i - 1] is not None:
                stamp = times[i] + (times[i] - times[i - 1]) / 2  # type: ignore[operator]
            else:
                stamp = None if times[i] is None else times[i] + 1e-6  # type: ignore[operator]
            yield (mutant.replace(timestamp=stamp), (source,), chosen.operator.spec(),
                   params.model_dump(mode="json"))


def generate_frames(log: OrderedLog, segments: Sequence[Segment], chosen: Strategy, *, seed: int = 0,
                    ) -> Iterator[tuple[Scene, Provenance]]:
    """The generated log's frames with their provenance, segments in the log's order.

    Raises:
        GenerationError: The strategy failed on a frame (naming it, its segment and the strategy).
    """
    position = 0
    for segment in sorted(segments, key=lambda s: s.index):
        made = _segment_frames(log, segment, chosen, seed)
        while True:
            try:
                item = next(made, None)
            except LidarfuzzError:
                raise
            except Exception as exc:
                raise GenerationError(f"{log.path}: strategy {chosen.name} failed in segment {segment.id} "
                                      f"(frames {segment.frame_ids[0]}..{segment.frame_ids[-1]}): {exc}") from exc
            if item is None:
                break
            scene, sources, spec, params = item
            frame_id = f"{position:06d}"
            yield scene.replace(frame_id=frame_id), Provenance(position, frame_id, segment.index, sources, spec,
                                                               params)
            position += 1


def write_generated_log(log: OrderedLog, segments: Sequence[Segment], chosen: Strategy, out: str | PathLike[str], *,
                        seed: int = 0, heuristic: str | None = None, segment_size: int | None = None,
                        overwrite: bool = False) -> GeneratedLog:
    """Write the generated log of ``segments`` (of ``log``) under ``chosen`` to the new folder ``out``.

    Args:
        log: The parent log.
        segments: The segments to generate from (any order; written in the log's).
        chosen: The strategy (:func:`strategy`).
        out: A new folder (an existing one only with ``overwrite``; replaced only once complete).
        seed: Seeds every mutant.
        heuristic: The heuristic that chose the segments (recorded; ``None``: chosen by hand).
        segment_size: The partition's size (recorded; default: the longest segment's length).
        overwrite: Replace an existing ``out``.

    Raises:
        GenerationError: No segments, a segment outside the log, or the strategy failed on a frame;
            nothing is written then.
    """
    if not segments:
        raise GenerationError(f"{log.path}: no segments to generate from")
    for s in segments:
        if s.last >= len(log) or s.first < 0:
            raise GenerationError(f"{log.path}: segment {s.id} (frames {s.first}..{s.last}) lies outside the log "
                                  f"of {len(log)} frames")
    return write_log(log, generate_frames(log, segments, chosen, seed=seed), out, strategy=chosen.name, seed=seed,
                     heuristic=heuristic, segment_size=segment_size or max(len(s) for s in segments),
                     segments=tuple(s.index for s in sorted(segments, key=lambda s: s.index)), overwrite=overwrite)


def write_log(log: OrderedLog, frames: Iterable[tuple[Scene, Provenance]], out: str | PathLike[str], *,
              strategy: str, seed: int, heuristic: str | None, segment_size: int, segments: tuple[int, ...],
              overwrite: bool = False) -> GeneratedLog:
    """Write frames made from ``log``, with their provenance, as a generated log in the new folder ``out``
    (KITTI layout, ``timestamps.txt`` and :data:`MANIFEST`), atomically: when ``frames`` raises,
    nothing is left. :func:`write_generated_log` writes a strategy's frames with it; other generators
    (:mod:`lidarfuzz.structural.search`) their own."""
    destination = Path(out)
    records: list[Provenance] = []
    timed = log.timestamps is not None
    with atomic_folder(destination, overwrite=overwrite) as tmp:
        writer = KittiWriter(tmp, durable=False)  # the folder's rename is what makes it visible
        for scene, record in frames:
            if not timed or scene.timestamp is None:
                scene = scene.replace(timestamp=record.position * UNTIMED_PERIOD)
            writer.add(scene)
            records.append(record)
        writer.close()
        made = GeneratedLog(str(destination), str(log.path), len(log), heuristic, strategy, seed, segment_size,
                            segments, tuple(records))
        (tmp / MANIFEST).write_text(json.dumps(made.to_json(), indent=1) + "\n", encoding="utf-8")
    return made


__all__ = [
    "MANIFEST", "PAPER_HEIGHT", "GeneratedLog", "GenerationError", "Provenance", "Strategy", "expected_frames",
    "generate_frames", "operator_stream", "strategy", "write_generated_log", "write_log",
]
