"""Steering labels for the images of a log, from a companion topic.

A recording keeps the steering angle on its own topic, at its own rate: Udacity's bags publish
``dbw_mkz_msgs/SteeringReport`` (``steering_wheel_angle``, radians, left positive) at about 50 Hz
beside the cameras' 20 Hz. :func:`read_steering` reads one such topic whole — any message type
the log defines (its stored definition is registered, so vendor types need no package), taking
the value of a named field or of the first of :data:`STEERING_FIELDS` the type has (a field of
a nested message counts: ``drive.steering_angle`` of ``ackermann_msgs/AckermannDriveStamped``).
An image is labelled by linear interpolation between the steering messages around its log
(receive) time — what Udacity's ``interpolated.csv`` does — and is unlabelled outside their
span (no extrapolation).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from lidarfuzz.errors import DataFormatError

#: Field names taken as the steering value, in this order (top level first, then one level down).
STEERING_FIELDS = ("steering_wheel_angle", "steering_angle", "steering", "angle", "data")


@dataclass(frozen=True)
class SteeringTrack:
    """Steering values of one topic by log time."""

    topic: str
    field: str
    times: NDArray[np.int64]  # log time, ns, non-decreasing
    values: NDArray[np.float64]
    _relative: NDArray[np.float64] = dataclasses.field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        # times relative to the first keep nanoseconds exact in float64 (absolute ones lose ~0.2 µs)
        relative = (self.times - self.times[0]).astype(np.float64) if len(self.times) else np.zeros(0)
        object.__setattr__(self, "_relative", relative)

    def at(self, log_time: int) -> float | None:
        """The value at ``log_time`` interpolated linearly, or None outside the topic's span."""
        if not len(self.times) or log_time < self.times[0] or log_time > self.times[-1]:
            return None
        return float(np.interp(float(log_time - self.times[0]), self._relative, self.values))


def _store(encoding: str, msgtype: str, definition: tuple[str, str] | None, source: Path, topic: str) -> Any:
    """A type store that knows ``msgtype`` (the reference one, plus the log's own definition when needed)."""
    # rosbags is slow to import: loaded only when a log is touched
    from rosbags.typesys import Stores, get_types_from_idl, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC if encoding == "ros1" else Stores.ROS2_HUMBLE)
    if msgtype in store.fielddefs:
        return store
    if definition is None:
        raise DataFormatError(source, f"topic {topic!r}: type {msgtype} is unknown and the log stores no definition "
                              "of it", field="steering_topic")
    text, fmt = definition
    try:
        types = get_types_from_idl(text) if fmt == "idl" else get_types_from_msg(text, msgtype)
        store.register({name: spec for name, spec in types.items() if name not in store.fielddefs})
    except Exception as err:
        raise DataFormatError(source, f"topic {topic!r}: the log's definition of {msgtype} cannot be read: {err}",
                              field="steering_topic") from err
    return store


def _field_path(store: Any, msgtype: str, wanted: str | None) -> list[str] | None:
    """The path (``["drive", "steering_angle"]``) of the steering field in ``msgtype``, or None."""
    fields = dict(store.fielddefs[msgtype][1])
    if wanted is not None:
        path = wanted.split(".")
        current = msgtype
        for part in path:
            known = dict(store.fielddefs[current][1])
            if part not in known:
                return None
            kind, spec = known[part]
            current = spec if getattr(kind, "name", "") == "NAME" else current
        return path
    for name in STEERING_FIELDS:
        if name in fields and getattr(fields[name][0], "name", "") == "BASE":
            return [name]
    for outer, (kind, spec) in fields.items():
        if getattr(kind, "name", "") == "NAME" and spec in store.fielddefs:
            inner = dict(store.fielddefs[spec][1])
            for name in STEERING_FIELDS:
                if name in inner and getattr(inner[name][0], "name", "") == "BASE":
                    return [outer, name]
    return None


def read_steering(source: Path, kind: str, topic: str, field: str | None = None) -> SteeringTrack:
    """Every steering value of ``topic`` in a log (see the module docstring).

    Raises:
        DataFormatError: No such topic, a type whose definition is unknown, no steering field (naming
            the fields there are), or a message whose value is not a finite number (naming its index).
    """
    from lidarfuzz.io.logs.backends import open_backend
    from lidarfuzz.io.logs.containers import reading

    backend = open_backend(source, kind)  # type: ignore[arg-type]
    try:
        with reading(source, "list the topics"):
            topics = {t.name: t for t in backend.topics()}
            found = topics.get(topic)
            if found is None:
                raise DataFormatError(source, f"no topic {topic!r}; topics: {', '.join(sorted(topics)) or 'none'}",
                                      field="steering_topic")
            definition = backend.definition(topic)
        msgtype = found.msgtype
        if not msgtype:
            raise DataFormatError(source, f"topic {topic!r} has no single message type", field="steering_topic")
        store = _store(found.encoding, msgtype, definition, source, topic)
        path = _field_path(store, msgtype, field)
        if path is None:
            names = ", ".join(name for name, _ in store.fielddefs[msgtype][1])
            what = f"no field {field!r}" if field else f"no steering field ({', '.join(STEERING_FIELDS)})"
            raise DataFormatError(source, f"topic {topic!r} ({msgtype}) has {what}; its fields: {names}",
                                  field="steering_field")
        times: list[int] = []
        values: list[float] = []
        with reading(source, f"read topic {topic!r}"):
            for index, (log_time, raw) in enumerate(backend.messages(topic)):
                if found.encoding == "ros1":
                    msg = store.deserialize_ros1(raw, msgtype)
                else:
                    msg = store.deserialize_cdr(raw, msgtype)
                value = msg
                for part in path:
                    value = getattr(value, part)
                number = float(value)
                if not math.isfinite(number):
                    raise DataFormatError(source, f"topic {topic}, message {index}: {number} is not a finite number",
                                          field=".".join(path))
                times.append(int(log_time))
                values.append(number)
    finally:
        backend.close()
    return SteeringTrack(topic, ".".join(path), np.array(times, dtype=np.int64), np.array(values, dtype=np.float64))
