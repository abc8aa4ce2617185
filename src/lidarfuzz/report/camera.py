"""A camera task in the report: its headline, and each finding as DeepTest's Figure 7 draws it —
the original and the transformed image side by side, the steering angles drawn as arrows.

On the original: the label (green) and the system's prediction (blue); on the transformed image:
the label again and the prediction there (red). An arrow starts at the bottom centre and points
where the wheels would: straight up for 0, turned left for a positive angle (left positive, the
convention of the labels), at the angle itself (not exaggerated), with the values written beside.
The transformed image is rebuilt from the finding's stored operator and params, as ``lidarfuzz
replay`` rebuilds it: no random number is drawn again.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from lidarfuzz.errors import LidarfuzzError
from lidarfuzz.store.contracts import TaskSummary

#: Arrow colours (RGB): the label, the prediction on the original, on the transformed image.
LABEL, ORIGINAL, TRANSFORMED = (60, 220, 90), (90, 160, 255), (255, 70, 70)
WIDTH = 480  # pixels of each image in a picture


def is_camera(summary: TaskSummary) -> bool:
    return summary.kind_summary.get("modality") == "camera"


def headline(summary: TaskSummary) -> str | None:
    """The report's first paragraph for a camera task (None for another kind)."""
    if not is_camera(summary):
        return None
    data, task = summary.kind_summary, summary.task
    settings = sum(1 for s in summary.subtasks[1:] if s.operator != "guided")
    parts = [f"lidarfuzz tested the steering system {task.model.name} on {data.get('images', task.frames)} images of "
             f"{task.dataset.name} under {settings} transformation setting(s), as DeepTest does."]
    mse = data.get("mse_orig")
    if mse is None:
        parts.append("No image has a steering label, so MSE_orig is undefined and DeepTest's relation (Eq. 2) judged "
                     "nothing: label the data (a CSV of angles) to test it.")
    else:
        parts.append(f"Its mean squared error on the original images (MSE_orig) is {mse:.4g} over "
                     f"{data.get('labelled', 0)} labelled image(s).")
    table = summary.deeptest
    if table is not None and table.counts:
        lam, eps = table.configured_lambda, table.configured_epsilon
        try:
            i, j = table.lambdas.index(lam), table.epsilons.index(eps)
            parts.append(f"At λ = {lam:g} and ε = {eps:g} it shows {table.counts[i][j]} erroneous behaviour(s) "
                         "(Table 7 below gives every λ and ε).")
        except ValueError:
            pass
    guided = next((s for s in summary.subtasks if s.operator == "guided"), None)
    if guided is not None and guided.search is not None:
        stats, coverage = guided.search.stats, guided.search.coverage
        nc = coverage.get("nc")
        parts.append(f"The guided search generated {stats.get('tests', 0)} test(s), kept {stats.get('accepted', 0)} "
                     f"that raised coverage{'' if nc is None else f' (neuron coverage {100 * nc:.1f} %)'} and "
                     f"{stats.get('violating', 0)} violated Eq. 2.")
    return " ".join(parts)


def _arrow(image: NDArray[np.uint8], angle: float, colour: tuple[int, int, int], thickness: int) -> None:
    import cv2

    h, w = image.shape[:2]
    length = 0.42 * h
    start = (w // 2, h - 6)
    end = (round(start[0] - math.sin(angle) * length), round(start[1] - math.cos(angle) * length))
    cv2.arrowedLine(image, start, end, colour, thickness, cv2.LINE_AA, tipLength=0.12)


def _text(image: NDArray[np.uint8], lines: Sequence[tuple[str, tuple[int, int, int]]], *,
          backdrop: bool = True) -> None:
    """Lines of text at the top left, one pass each (a thicker outline pass would advance wider
    than the text itself and blur it), on a darkened box so they read on any picture."""
    import cv2

    font, scale = cv2.FONT_HERSHEY_SIMPLEX, 0.5
    if backdrop and lines:
        width = max(cv2.getTextSize(text, font, scale, 1)[0][0] for text, _ in lines) + 10
        height = 18 * len(lines) + 8
        box = image[:height, :width]
        box[:] = (box.astype(np.float32) * 0.45).astype(np.uint8)
    for k, (text, colour) in enumerate(lines):
        cv2.putText(image, text, (5, 17 + 18 * k), font, scale, colour, 1, cv2.LINE_AA)


def _fit(image: NDArray[np.uint8]) -> NDArray[np.uint8]:
    import cv2

    h, w = image.shape[:2]
    height = max(1, round(h * WIDTH / w))
    return np.ascontiguousarray(cv2.resize(image, (WIDTH, height), interpolation=cv2.INTER_AREA))


def pair_picture(original: NDArray[np.uint8], transformed: NDArray[np.uint8], *, label: float | None,
                 before: float | None, after: float | None, title: str) -> NDArray[np.uint8]:
    """Original | transformed (RGB), each with its arrows and values, a title strip above."""
    left, right = _fit(original), _fit(transformed)
    if right.shape[0] != left.shape[0]:  # a transformation that changed the size
        import cv2

        right = np.ascontiguousarray(cv2.resize(right, (WIDTH, left.shape[0]), interpolation=cv2.INTER_AREA))
    thickness = max(2, WIDTH // 160)
    for image, prediction, colour, name in ((left, before, ORIGINAL, "original"),
                                            (right, after, TRANSFORMED, "transformed")):
        lines = [(name, (255, 255, 255))]
        if label is not None:
            _arrow(image, label, LABEL, thickness)
            lines.append((f"label {label:+.4f}", LABEL))
        if prediction is not None and math.isfinite(prediction):
            _arrow(image, prediction, colour, thickness)
            lines.append((f"predicted {prediction:+.4f}", colour))
        _text(image, lines)
    strip = np.full((26, 2 * WIDTH + 4, 3), 250, np.uint8)
    _text(strip, [(title[:110], (30, 30, 30))], backdrop=False)
    body = np.concatenate([left, np.full((left.shape[0], 4, 3), 255, np.uint8), right], axis=1)
    return np.concatenate([strip, body], axis=0)


def frame_picture(image: NDArray[np.uint8], *, label: float | None, width: int | None = None,
                  caption: str | None = None) -> NDArray[np.uint8]:
    """One image (RGB) with its label's arrow (green) and value, as the pairs draw it; ``width``:
    resized to that many pixels first (a thumbnail), ``caption``: a first line of text."""
    import cv2

    picture = np.ascontiguousarray(image).copy()
    if width is not None and width != picture.shape[1]:
        height = max(1, round(picture.shape[0] * width / picture.shape[1]))
        picture = np.ascontiguousarray(cv2.resize(picture, (width, height), interpolation=cv2.INTER_AREA))
    lines = [] if caption is None else [(caption, (255, 255, 255))]
    if label is not None and math.isfinite(label):
        _arrow(picture, label, LABEL, max(2, picture.shape[1] // 160))
        lines.append((f"label {label:+.4f}", LABEL))
    if lines and picture.shape[1] >= 120:  # no text on a tiny thumbnail: the page writes the value
        _text(picture, lines)
    return picture


def png_bytes(image: NDArray[np.uint8]) -> bytes:
    import cv2

    ok, data = cv2.imencode(".png", np.ascontiguousarray(image[:, :, ::-1]))
    if not ok:
        raise LidarfuzzError("cannot encode the picture as PNG")
    return bytes(data.tobytes())


def finding_png(store: Any, finding_id: int, datasets: dict[str, Any] | None = None) -> bytes:
    from lidarfuzz.campaign.camera import finding_pair

    pair = finding_pair(store, finding_id, datasets)
    title = f"finding #{finding_id} | {pair['kind']} | frame {pair['frame_id']} | {pair['operator']}"
    return png_bytes(pair_picture(pair["original"].image.copy(), pair["transformed"].image.copy(),
                                  label=pair["label"], before=pair["before"], after=pair["after"], title=title))


def finding_images(store: Any, finding_ids: Sequence[int], *, limit: int = 12) -> dict[int, bytes | str]:
    """Pictures of the first ``limit`` findings: PNG bytes, or a note saying why there is none."""
    datasets: dict[str, Any] = {}
    images: dict[int, bytes | str] = {}
    for finding_id in list(finding_ids)[: max(0, limit)]:
        try:
            images[finding_id] = finding_png(store, finding_id, datasets)
        except (LidarfuzzError, OSError) as exc:
            images[finding_id] = f"No picture: {exc}"
    return images


__all__ = ["finding_images", "finding_png", "frame_picture", "headline", "is_camera", "pair_picture",
           "png_bytes"]
