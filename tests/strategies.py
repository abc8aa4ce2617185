"""Hypothesis strategies for clouds and boxes, shared by the round-trip tests."""

from __future__ import annotations

import numpy as np
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from lidarfuzz.io.common import FIELD_ALIASES
from lidarfuzz.scene import OPTIONAL_CHANNELS, STANDARD_CHANNELS, Boxes3D, PointCloud

finite32 = st.floats(width=32, allow_nan=False, allow_infinity=False)
# Channel names no reader maps onto another channel (aliases such as "beam" would read back as "ring").
ALIASES = set(FIELD_ALIASES) | {a for names in FIELD_ALIASES.values() for a in names}
custom_names = st.from_regex(r"[a-z][a-z0-9_]{0,10}", fullmatch=True).filter(lambda n: n not in ALIASES)


@st.composite
def clouds(draw: st.DrawFn, max_points: int = 150) -> PointCloud:
    """Finite float32 clouds with 0–4 optional or custom channels."""
    extra = draw(st.lists(st.sampled_from(OPTIONAL_CHANNELS) | custom_names, unique=True, max_size=4))
    n = draw(st.integers(0, max_points))
    data = draw(hnp.arrays(np.float32, (n, 4 + len(extra)), elements=finite32))
    return PointCloud(data, (*STANDARD_CHANNELS, *extra))


@st.composite
def boxes(draw: st.DrawFn, max_boxes: int = 6, classes: tuple[str, ...] = ("Car", "Pedestrian", "Cyclist")) -> Boxes3D:
    n = draw(st.integers(0, max_boxes))
    coord = st.floats(-80, 80, allow_nan=False)
    size = st.floats(0.1, 12.0, allow_nan=False)
    centers = draw(hnp.arrays(np.float64, (n, 3), elements=coord))
    sizes = draw(hnp.arrays(np.float64, (n, 3), elements=size))
    yaw = draw(hnp.arrays(np.float64, (n,), elements=st.floats(-np.pi, np.pi, allow_nan=False)))
    labels = draw(st.lists(st.sampled_from(classes), min_size=n, max_size=n))
    return Boxes3D.create(centers, sizes, yaw, labels)
