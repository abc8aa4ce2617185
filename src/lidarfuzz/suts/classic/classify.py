"""Rule-based classifier: car, pedestrian, cyclist or unknown from the cluster's measured size.

The rules read the footprint's long and short visible extents and the height above the
ground, as a hand-written perception stack would. Unknown objects (walls, poles, trees,
hedges, buildings, trucks) are not reported.
"""

from __future__ import annotations

from dataclasses import dataclass

#: Typical sizes (l, w, h) used to complete partly seen objects (KITTI's class means).
PRIORS: dict[str, tuple[float, float, float]] = {
    "Car": (3.9, 1.6, 1.56),
    "Pedestrian": (0.8, 0.6, 1.75),
    "Cyclist": (1.76, 0.6, 1.73),
}


@dataclass(frozen=True)
class Measurement:
    """What the classifier sees of a cluster.

    Attributes:
        length: Longer visible footprint extent (m).
        width: Shorter one.
        height: Top above the ground (m).
        points: Number of points.
        top_length: Extent along the long side of the points in the upper third (a rider's
            torso is narrow, a car's rear window is not).
        end_on: True when the long visible side faces the sensor squarely (the line of
            sight is within 30° of its normal): a car seen from behind shows its width.
    """

    length: float
    width: float
    height: float
    points: int
    top_length: float = 0.0
    end_on: bool = False


def classify(m: Measurement) -> tuple[str, float]:
    """(class, margin in [0, 1]): ``Unknown`` when no rule fits; the margin grows with how
    squarely the measurement sits inside the rule."""
    if m.height < 0.6 or m.height > 2.4:
        return "Unknown", 0.0
    if m.length <= 1.0 and 0.25 <= m.width <= 0.9 and 1.2 <= m.height <= 2.1 and m.points >= 15:
        return "Pedestrian", 1.0 - abs(m.height - 1.75) / 0.6
    narrow_top = m.top_length < 0.55 * m.length
    if 1.0 < m.length <= 2.1 and m.width <= 0.9 and 1.4 <= m.height <= 2.1 and narrow_top:
        return "Cyclist", 1.0 - abs(m.length - 1.76) / 1.0
    # far cars lose their upper half (glass returns little): a long low cluster is still a car
    low_ok = m.height >= 1.0 or (m.height >= 0.6 and m.length >= 1.4 and m.points >= 12)
    if 1.3 <= m.length <= 5.8 and m.width <= 2.4 and m.height <= 2.0 and low_ok:
        return "Car", 1.0 - abs(m.height - 1.5) / 1.0
    return "Unknown", 0.0
