"""Small functions whose control-flow graphs are counted by hand in the structural tests.

The tests name lines by number: change nothing above the last function, only append below it.
Each function's comment gives its blocks (by their lines) and edges, worked out by hand from
the rule in :mod:`lidarfuzz.structural.python_coverage`.
"""

from __future__ import annotations

import numpy as np


# blocks: [15, 16]; edges: entry(-14)->15, 15->exit   (1 node, 2 edges)
def straight(a: float, b: float) -> float:
    total = a + b
    return total * 2


# blocks: [22] (if: two successors), [23], [25], [26] (two predecessors)
# edges: entry(-21)->22, 22->23, 22->25, 23->26, 25->26, 26->exit   (4 nodes, 6 edges)
def sign(x: float) -> str:
    if x > 0:  # noqa: SIM108 (the if/else is what is counted)
        word = "positive"
    else:
        word = "not positive"
    return word


# lines 34 found=None, 35 for, 36 if, 37 found=v, 38 break, 39 return
# blocks: [34] (its successor 35 has two predecessors), [35] (for: two successors),
#   [36] (if: two successors), [37, 38] (break), [39] (predecessors 35 and 38)
# edges: entry(-33)->34, 34->35, 35->36, 35->39, 36->35, 36->37, 37->39, 39->exit (5 nodes, 8 edges)
def first_negative(values: list[float]) -> float | None:
    found = None
    for v in values:
        if v < 0:
            found = v
            break
    return found


# lines 48 try, 49 value=int, 50 except, 51 value=-1, 52 return
# coverage.py lists the arcs 48->49, 49->52, 50->51, 51->52: none into the except clause.
# blocks: [48, 49], [50, 51] (an except clause starts a block), [52]
# edges: entry(-47)->48, 48->52, 48->50 (exception edge from the try's block), 50->52, 52->exit
#   (3 nodes, 5 edges)
def parse(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = -1
    return value


class Rectangle:
    """A class target's methods: area and is_square."""

    # blocks: [61] (if with or: two successors), [62], [63]
    # edges: entry(-60)->61, 61->62, 61->63, 62->exit, 63->exit (3 nodes, 5 edges)
    def area(self, width: float, height: float) -> float:
        if width <= 0 or height <= 0:
            return 0.0
        return width * height

    # blocks: [67]; edges: entry(-66)->67, 67->exit
    def is_square(self, width: float, height: float) -> bool:
        return width == height


def ground_height(cloud: np.ndarray) -> float:
    """numpy-heavy: the median height of the lowest tenth of the points near the sensor."""
    near = cloud[np.hypot(cloud[:, 0], cloud[:, 1]) < 20.0]
    if len(near) == 0:
        return 0.0
    low = np.sort(near[:, 2])[: max(1, len(near) // 10)]
    return float(np.median(low))


def steer(obstacles: list[tuple[float, float]], speed: float) -> tuple[float, float]:
    """Branchy pure Python: a steering angle and speed from obstacles (distance, bearing)."""
    left = right = 0.0
    nearest = float("inf")
    for distance, bearing in obstacles:
        if distance <= 0:
            continue
        weight = 1.0 / distance
        if bearing > 0:
            left += weight
        elif bearing < 0:
            right += weight
        else:
            left += weight / 2
            right += weight / 2
        nearest = min(nearest, distance)
    if nearest < 2.0:
        return 0.0, 0.0
    angle = 0.3 if right > left else -0.3 if left > right else 0.0
    if nearest < 10.0:
        speed = min(speed, nearest / 2)
    elif speed < 10.0:
        speed += 1.0
    return angle, speed


def tagged(function):
    """A decorator, for countdown below."""
    function.tagged = True
    return function


# decorated: coverage.py names the entry and exit by the decorator's line (117), its code object's first line
# lines 117 decorator, 118 def, 119 def halve, 120 (halve's), 121 out=[], 122 while, 123 append, 124 n-=1, 125 return
# countdown's blocks: [119, 121] (121's successor 122 has two predecessors), [122] (while: two successors),
#   [123, 124], [125]
# edges: entry(-117)->119, 119->122, 122->123, 122->125, 123->122, 125->exit (4 nodes, 6 edges)
# halve (nested, its own function): block [120]; edges entry(-119)->120, 120->exit
@tagged
def countdown(n: int) -> list[int]:
    def halve(k: int) -> int:
        return k // 2
    out = []
    while n > 0:
        out.append(halve(n))
        n -= 1
    return out
