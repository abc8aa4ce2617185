"""Ground truth and detections in KITTI label files, loaded for :func:`evaluate_kitti`.

The ground truth is a KITTI ``label_2`` folder (or a KITTI root holding ``label_2/`` or
``training/label_2/``); the detections are a folder of files in the same format with a
16th ``score`` column, matched to the ground truth by file name stem (``000042.txt``), as
the devkit and OpenPCDet's ``kitti_object_eval_python`` expect them. Detection lines
whose 2D box is ``-1 -1 -1 -1`` or whose alpha is ``-10`` get both by projection at
evaluation time. Class names are matched whatever their case, as the devkit compares them
(``strcasecmp``): ``car`` is a Car, ``dontcare`` a DontCare region.

Example:
    >>> from lidarfuzz.oracles.kitti_eval import evaluate_kitti
    >>> loaded = load_kitti_eval_frames("kitti/training", "results/data")  # doctest: +SKIP
    >>> evaluate_kitti(loaded.frames).get("3d", "Car", "moderate")  # doctest: +SKIP
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from os import PathLike
from pathlib import Path

import numpy as np

from lidarfuzz.errors import DataFormatError
from lidarfuzz.io.guards import reading
from lidarfuzz.io.kitti import png_size
from lidarfuzz.io.kitti.labels import KITTI_CLASSES, parse_labels
from lidarfuzz.oracles.kitti_eval import KittiFrame
from lidarfuzz.scene.boxes import Boxes3D
from lidarfuzz.scene.calib import KittiCalibration


@dataclass(frozen=True)
class KittiEvalFiles:
    """Frames ready for :func:`~lidarfuzz.oracles.kitti_eval.evaluate_kitti`, and where they came from.

    Attributes:
        frames: One frame per ground-truth file, in sorted frame-id order.
        frame_ids: The frames' ids (file name stems), same order.
        label_dir: The ground-truth folder actually read.
        detection_dir: The detection folder.
        calib_dir: The calibration folder used, or ``None`` when every frame got
            :meth:`KittiCalibration.default`.
        missing_detections: Ids of ground-truth frames without a detection file; they
            are evaluated as frames with no detections (every object a miss).
        notes: Things the user should know about how the files were read (e.g. that the
            default calibration stands in for a missing ``calib/``).
    """

    frames: list[KittiFrame]
    frame_ids: list[str]
    label_dir: Path
    detection_dir: Path
    calib_dir: Path | None
    missing_detections: list[str]
    notes: list[str]


def find_label_dir(path: str | PathLike[str]) -> Path:
    """The ground-truth label folder: ``path`` itself, ``path/label_2`` or ``path/training/label_2``.

    Raises:
        DataFormatError: ``path`` is not a folder, or holds neither label files nor a ``label_2/``.
    """
    path = Path(path)
    if not path.is_dir():
        raise DataFormatError(path, "no such folder (expected a KITTI label_2 folder or a KITTI root)")
    for candidate in (path / "label_2", path / "training" / "label_2"):
        if candidate.is_dir():
            return candidate
    if any(path.glob("*.txt")):
        return path
    raise DataFormatError(
        path,
        "no label files here (*.txt) and no label_2/ or training/label_2/ below",
        hint="pass a KITTI label_2 folder or the KITTI root that holds it",
    )


_CANONICAL_CLASSES = {name.lower(): name for name in KITTI_CLASSES}
_FIRST_TOKEN = re.compile(r"^(\s*)(\S+)")


def canonical_class_names(text: str) -> str:
    r"""Label lines with each known class name in KITTI's spelling, whatever its case.

    The devkit compares class names with ``strcasecmp`` (in ``cleanData`` and when it decides
    which classes were detected), so ``car``, ``CAR`` and ``Car`` are one class and ``dontcare``
    marks a DontCare region. Unknown names are left as written (the reader names them).
    Lines keep their numbers, so an error still points at the right line.

    Example:
        >>> canonical_class_names("car 0 0 -10 ...\n  DONTCARE -1 -1 ...\nbus 0 0 ...")
        'Car 0 0 -10 ...\n  DontCare -1 -1 ...\nbus 0 0 ...'
    """

    def canonical(match: re.Match[str]) -> str:
        return match.group(1) + _CANONICAL_CLASSES.get(match.group(2).lower(), match.group(2))

    return "\n".join(_FIRST_TOKEN.sub(canonical, line, count=1) for line in text.splitlines())


def read_eval_labels(path: Path, calib: KittiCalibration) -> Boxes3D:
    """A ground-truth or detection file, class names matched case-insensitively (see :func:`canonical_class_names`)."""
    with reading(path, "read the KITTI label lines"):
        text = path.read_bytes().decode("utf-8")
    return parse_labels(canonical_class_names(text), calib, path)


def _label_files(folder: Path) -> dict[str, Path]:
    return {p.stem: p for p in sorted(folder.glob("*.txt")) if p.is_file()}


def _calibration(calib_dir: Path | None, image_dir: Path | None, frame_id: str) -> KittiCalibration:
    if calib_dir is None:
        return KittiCalibration.default()
    path = calib_dir / f"{frame_id}.txt"
    if not path.is_file():
        raise DataFormatError(
            path,
            f"no calibration file for frame {frame_id!r}",
            hint="every ground-truth frame needs one, or pass a different --calib-dir",
        )
    calib = KittiCalibration.from_file(path)
    # The image size clips projected 2D boxes; KITTI's images differ by a few pixels.
    image = image_dir / f"{frame_id}.png" if image_dir is not None else None
    if image is not None and image.is_file():
        shape = png_size(image)
        if shape is not None and shape != calib.image_shape:
            calib = KittiCalibration.from_mapping(
                {k: getattr(calib, k) for k in ("P0", "P1", "P2", "P3", "R0_rect", "Tr_velo_to_cam", "Tr_imu_to_velo")},
                image_shape=shape,
            )
    return calib


def load_kitti_eval_frames(
    gt_dir: str | PathLike[str],
    dt_dir: str | PathLike[str],
    calib_dir: str | PathLike[str] | None = None,
    *,
    allow_unlabelled: bool = False,
) -> KittiEvalFiles:
    """Read ground-truth and detection label files into :class:`KittiFrame` objects.

    Args:
        gt_dir: A KITTI ``label_2`` folder, or a KITTI root holding ``label_2/`` or
            ``training/label_2/``.
        dt_dir: Detection files in KITTI label format with a score column, one per frame,
            named like the ground truth. A ground-truth frame without one has no detections.
        calib_dir: The ``calib`` folder; by default the ``calib/`` next to the label folder
            when there is one, else every frame gets :meth:`KittiCalibration.default`
            (boxes are then placed and projected with an idealised KITTI rig). PNG images in
            an ``image_2/`` beside the calibration folder set each frame's image size.
        allow_unlabelled: Leave out detection files of frames that have no label file (what
            ``lidarfuzz detect`` writes for the unlabelled frames of a mixed folder), with a note,
            instead of refusing them.

    Raises:
        DataFormatError: A folder is missing or holds no label files; a detection file has
            no ground-truth frame; a line is malformed (file, line and field named); a
            detection has no score; a frame has no calibration file in ``calib_dir``.
    """
    label_dir = find_label_dir(gt_dir)
    detection_dir = Path(dt_dir)
    if not detection_dir.is_dir():
        raise DataFormatError(detection_dir, "no such folder (expected detection files in KITTI label format)")
    gt_files = _label_files(label_dir)
    if not gt_files:
        raise DataFormatError(label_dir, "no label files (*.txt) in this folder")
    dt_files = _label_files(detection_dir)
    if not dt_files:
        raise DataFormatError(
            detection_dir, "no detection files (*.txt) in this folder",
            hint="give the folder holding one <frame id>.txt per frame, e.g. what lidarfuzz detect --out wrote",
        )
    stray = sorted(set(dt_files) - set(gt_files))
    notes: list[str] = []
    if stray and allow_unlabelled:
        shown = ", ".join(stray[:5]) + (", …" if len(stray) > 5 else "")
        notes.append(f"{len(stray)} detection file(s) of frames without a label file left out ({shown})")
        dt_files = {k: v for k, v in dt_files.items() if k in gt_files}
    elif stray:
        more = f" (and {len(stray) - 1} more)" if len(stray) > 1 else ""
        raise DataFormatError(
            dt_files[stray[0]],
            f"detection file without a ground-truth frame in {label_dir}{more}",
            hint="detection files must be named like the label files they answer; for frames that have no "
                 "labels pass --allow-unlabelled",
        )

    calib_path: Path | None
    if calib_dir is not None:
        calib_path = Path(calib_dir)
        if not calib_path.is_dir():
            raise DataFormatError(calib_path, "no such calibration folder")
    else:
        beside = label_dir.parent / "calib"
        calib_path = beside if beside.is_dir() else None
        if calib_path is None:
            notes.append(
                f"no calib/ folder next to {label_dir}: every frame uses the default KITTI-like "
                "calibration (pass --calib-dir to use the real one)"
            )
    image_dir = calib_path.parent / "image_2" if calib_path is not None else None

    frames: list[KittiFrame] = []
    missing: list[str] = []
    for frame_id, gt_path in gt_files.items():
        calib = _calibration(calib_path, image_dir, frame_id)
        gt = read_eval_labels(gt_path, calib)
        dt_path = dt_files.get(frame_id)
        if dt_path is None:
            missing.append(frame_id)
            detections = Boxes3D.empty()
        else:
            detections = read_eval_labels(dt_path, calib)
            if len(detections) and not np.all(np.isfinite(detections.scores)):
                raise DataFormatError(
                    dt_path,
                    "detections need a score: no line has the 16th column",
                    field="score",
                    hint="write detection files as a detector's KITTI output, with scores",
                )
        frames.append(KittiFrame(gt=gt, detections=detections, calib=calib))
    return KittiEvalFiles(
        frames=frames,
        frame_ids=list(gt_files),
        label_dir=label_dir,
        detection_dir=detection_dir,
        calib_dir=calib_path,
        missing_detections=missing,
        notes=notes,
    )


__all__ = ["KittiEvalFiles", "canonical_class_names", "find_label_dir", "load_kitti_eval_frames", "read_eval_labels"]
