"""Point clouds as one N×C float32 array with named channels.

The first four channels are always ``x, y, z, intensity`` in that order (metres in
the LiDAR frame: x forward, y left, z up). Optional channels follow, in any order:

========== ==============================================================
``ring``     laser/beam index (0 = the lowest beam, as ROS drivers number them)
``time``     firing time in seconds relative to the frame timestamp (negative
             before it; the simulator's frames span [-period/2, period/2))
``label``    per-point semantic class id
``instance`` per-point object instance (track) id (-1 = background)
========== ==============================================================

Other names are allowed (foreign formats carry e.g. ``ambient`` or ``range``) and
are kept through every reader and writer that can store them.

Arrays held by a :class:`PointCloud` are read-only views, so code that mutates a
cloud by accident fails loudly instead of silently changing the caller's data.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

STANDARD_CHANNELS: tuple[str, ...] = ("x", "y", "z", "intensity")
OPTIONAL_CHANNELS: tuple[str, ...] = ("ring", "time", "label", "instance")

#: Value a channel takes for points that come from a source without it.
CHANNEL_DEFAULTS: dict[str, float] = {
    "ring": -1.0,
    "time": 0.0,
    "label": 0.0,
    "instance": -1.0,
}


def frozen(array: NDArray[Any]) -> NDArray[Any]:
    """Return a read-only view of ``array`` without copying (the caller's array keeps its flags)."""
    view = array.view()
    view.flags.writeable = False
    return view


def _check_channels(channels: Sequence[str]) -> tuple[str, ...]:
    names = tuple(channels)
    if names[:4] != STANDARD_CHANNELS:
        raise ValueError(
            f"the first four channels must be {STANDARD_CHANNELS}, got {names[:4]}"
        )
    if len(set(names)) != len(names):
        dupes = sorted({n for n in names if names.count(n) > 1})
        raise ValueError(f"duplicate channel names: {dupes}")
    for name in names:
        if not name.isidentifier():
            raise ValueError(f"channel name {name!r} is not an identifier")
    return names


class PointCloud:
    """An immutable N×C float32 point array with named channels.

    Args:
        data: N×C values; converted to float32 (no copy when already float32).
        channels: Channel names, starting with ``x, y, z, intensity``.

    Example:
        >>> cloud = PointCloud(np.zeros((3, 4)))
        >>> cloud.xyz.shape, cloud.channels
        ((3, 3), ('x', 'y', 'z', 'intensity'))
        >>> cloud.with_channel("ring", [0, 1, 2]).channel("ring").tolist()
        [0.0, 1.0, 2.0]
    """

    __slots__ = ("_channels", "_data")

    def __init__(self, data: ArrayLike, channels: Sequence[str] = STANDARD_CHANNELS) -> None:
        names = _check_channels(channels)
        array = np.asarray(data, dtype=np.float32)
        if array.ndim == 1 and array.size == 0:
            array = array.reshape(0, len(names))
        if array.ndim != 2 or array.shape[1] != len(names):
            raise ValueError(
                f"points must be an N×{len(names)} array for channels {names}, "
                f"got shape {array.shape}"
            )
        self._data = frozen(array)
        self._channels = names

    # -- construction -----------------------------------------------------------------
    @classmethod
    def empty(cls, channels: Sequence[str] = STANDARD_CHANNELS) -> PointCloud:
        """A cloud with zero points (valid everywhere a cloud is)."""
        return cls(np.zeros((0, len(channels)), np.float32), channels)

    @classmethod
    def from_channels(cls, columns: dict[str, ArrayLike]) -> PointCloud:
        """Build from a mapping of channel name to 1-D values.

        ``intensity`` defaults to zeros when absent; the others must be present.
        """
        for name in ("x", "y", "z"):
            if name not in columns:
                raise ValueError(f"missing required channel {name!r}")
        n = len(np.asarray(columns["x"]))
        cols = dict(columns)
        cols.setdefault("intensity", np.zeros(n, np.float32))
        names = list(STANDARD_CHANNELS) + [k for k in cols if k not in STANDARD_CHANNELS]
        data = np.empty((n, len(names)), np.float32)
        for i, name in enumerate(names):
            values = np.asarray(cols[name])
            if values.shape != (n,):
                raise ValueError(f"channel {name!r} has shape {values.shape}, expected ({n},)")
            data[:, i] = values
        return cls(data, names)

    # -- access -----------------------------------------------------------------------
    @property
    def data(self) -> NDArray[np.float32]:
        """The read-only N×C float32 array."""
        return self._data

    @property
    def channels(self) -> tuple[str, ...]:
        return self._channels

    @property
    def xyz(self) -> NDArray[np.float32]:
        """N×3 coordinates (a read-only view)."""
        return self._data[:, :3]

    @property
    def intensity(self) -> NDArray[np.float32]:
        return self._data[:, 3]

    def has(self, name: str) -> bool:
        return name in self._channels

    def index(self, name: str) -> int:
        try:
            return self._channels.index(name)
        except ValueError:
            raise KeyError(f"no channel {name!r}; channels are {self._channels}") from None

    def channel(self, name: str) -> NDArray[np.float32]:
        """The values of one channel (a read-only view)."""
        return self._data[:, self.index(name)]

    def __len__(self) -> int:
        return int(self._data.shape[0])

    def __repr__(self) -> str:
        return f"PointCloud(n={len(self)}, channels={self._channels})"

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, PointCloud):
            return NotImplemented
        return self._channels == other._channels and np.array_equal(
            self._data, other._data, equal_nan=True
        )

    __hash__ = None  # type: ignore[assignment]

    # -- derivation (always new objects) ----------------------------------------------
    def select(self, index: ArrayLike) -> PointCloud:
        """Points picked by a boolean mask or an integer index array."""
        index = np.asarray(index)
        if index.dtype == bool and index.shape == (len(self),):
            return PointCloud(np.compress(index, self._data, axis=0), self._channels)  # 5x faster than data[mask]
        return PointCloud(self._data[index], self._channels)

    def with_data(self, data: ArrayLike) -> PointCloud:
        """Same channels, new values."""
        return PointCloud(data, self._channels)

    def with_xyz(self, xyz: ArrayLike) -> PointCloud:
        """Same points with new coordinates; every other channel is kept."""
        data = self._data.copy()
        data[:, :3] = xyz
        return PointCloud(data, self._channels)

    def with_channel(self, name: str, values: ArrayLike) -> PointCloud:
        """Replace a channel's values, or append it when absent."""
        values = np.asarray(values, dtype=np.float32)
        if values.shape != (len(self),):
            raise ValueError(f"channel {name!r} needs {len(self)} values, got {values.shape}")
        if name in self._channels:
            data = self._data.copy()
            data[:, self.index(name)] = values
            return PointCloud(data, self._channels)
        data = np.concatenate([self._data, values[:, None]], axis=1)
        return PointCloud(data, (*self._channels, name))

    def without_channels(self, names: Iterable[str]) -> PointCloud:
        drop = set(names) - set(STANDARD_CHANNELS)
        keep = [i for i, n in enumerate(self._channels) if n not in drop]
        return PointCloud(self._data[:, keep], [self._channels[i] for i in keep])

    def conform(self, channels: Sequence[str]) -> PointCloud:
        """Reorder/extend to exactly ``channels``; missing ones get their default value."""
        names = _check_channels(channels)
        if names == self._channels:
            return self
        data = np.empty((len(self), len(names)), np.float32)
        for i, name in enumerate(names):
            if name in self._channels:
                data[:, i] = self._data[:, self._channels.index(name)]
            else:
                data[:, i] = CHANNEL_DEFAULTS.get(name, 0.0)
        return PointCloud(data, names)

    @staticmethod
    def concat(clouds: Sequence[PointCloud]) -> PointCloud:
        """Stack clouds; the result has the union of channels (first cloud's order first)."""
        if not clouds:
            return PointCloud.empty()
        names = list(clouds[0].channels)
        for cloud in clouds[1:]:
            names += [n for n in cloud.channels if n not in names]
        parts = [c.conform(names).data for c in clouds]
        return PointCloud(np.concatenate(parts, axis=0), names)
