"""Camera topics of recorded logs: ``sensor_msgs/Image`` and ``sensor_msgs/CompressedImage`` in ROS 1
bags, ROS 2 bags and MCAP files, as a log of :class:`~lidarfuzz.scene.image.ImageSample`.

Opening, indexing and fetching one message are :class:`~lidarfuzz.io.logs.reader.TopicLog`'s (the
same as for PointCloud2 topics): frame ids are message indices (``"000000"`` …) in log-time order,
timestamps header stamps (the log time where a stamp is zero).

* ``Image``: encodings ``rgb8``, ``bgr8``, ``mono8``, ``rgba8``, ``bgra8``; rows may be padded
  (``step`` > width × channels); the data must hold exactly height × step bytes.
* ``CompressedImage``: PNG or JPEG data (recognised by its bytes; ``format`` is kept in the
  metadata), checked complete before decoding (:mod:`lidarfuzz.io.images.decode`).

Steering labels come from a companion topic when one is named (``steering_topic``, e.g. Udacity's
``/vehicle/steering_report``): linear interpolation at each image's log time
(:mod:`lidarfuzz.io.images.steering`); images outside that topic's span are unlabelled (a warning).
No depth and no intrinsics (``sensor_msgs/CameraInfo`` is not read).
"""

from __future__ import annotations

from os import PathLike
from typing import Any, ClassVar

from lidarfuzz.errors import DataFormatError, LidarfuzzError
from lidarfuzz.io.common import Problem
from lidarfuzz.io.images.decode import decode_image, decode_raw
from lidarfuzz.io.images.steering import SteeringTrack, read_steering
from lidarfuzz.io.logs.messages import NS, typestore
from lidarfuzz.io.logs.reader import TopicLog
from lidarfuzz.scene.image import ImageSample

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED_IMAGE = "sensor_msgs/msg/CompressedImage"


class ImageLog(TopicLog[ImageSample]):
    """One ``sensor_msgs/Image`` or ``sensor_msgs/CompressedImage`` topic of a log.

    Args:
        path: A ``.bag`` file, a ROS 2 bag directory (or its ``metadata.yaml``), or an ``.mcap`` file.
        topic: The image topic; may be left out when the log has only one.
        steering_topic: A topic whose messages carry the steering angle (see
            :mod:`lidarfuzz.io.images.steering`); without one the images are unlabelled.
        steering_field: The field of those messages that holds it (``drive.steering_angle``);
            by default the first of :data:`~lidarfuzz.io.images.steering.STEERING_FIELDS`.
        name: Display name (defaults to the file name).

    Each sample's metadata holds ``source``, ``format`` (``ros1``/``ros2``/``mcap``), ``topic``,
    ``sensor_frame_id``, ``message_index``, ``encoding`` (Image) or ``compression`` (CompressedImage's
    ``format``) and ``size``.
    """

    msgtypes: ClassVar[tuple[str, ...]] = (IMAGE, COMPRESSED_IMAGE)
    what: ClassVar[str] = "sensor_msgs/Image or sensor_msgs/CompressedImage"

    def __init__(self, path: str | PathLike[str], topic: str | None = None, *, steering_topic: str | None = None,
                 steering_field: str | None = None, name: str | None = None) -> None:
        super().__init__(path, topic, name=name)
        self.steering: SteeringTrack | None = None
        if steering_field is not None and steering_topic is None:
            raise LidarfuzzError(f"{self.path}: steering_field={steering_field!r} needs a steering_topic")
        if steering_topic is not None:
            self.steering = read_steering(self.path, self._kind, steering_topic, steering_field)
            times = self.steering.times
            outside = sum(1 for entry in self._entries
                          if not len(times) or not times[0] <= entry.log_time <= times[-1])
            if outside:
                self._problems.append(Problem("warning", str(self.path), f"{outside} of {len(self._entries)} "
                                              f"image(s) lie outside the messages of {steering_topic}: unlabelled"))

    def _sample(self, index: int, log_time: int, raw: bytes | memoryview) -> ImageSample:
        encoding = self._topic.encoding
        msgtype = self._topic.msgtype
        where = f"topic {self._topic.name}, message {index}"
        store = typestore(encoding)
        try:
            msg = store.deserialize_ros1(raw, msgtype) if encoding == "ros1" else store.deserialize_cdr(raw, msgtype)
        except Exception as err:
            raise DataFormatError(self.path, f"{where}: cannot deserialize {msgtype}: {err}") from err
        stamp = int(msg.header.stamp.sec) * NS + int(msg.header.stamp.nanosec)
        metadata: dict[str, Any] = {"source": str(self.path), "format": self._kind, "topic": self._topic.name,
                                    "sensor_frame_id": str(msg.header.frame_id), "message_index": index}
        if msgtype == IMAGE:
            image = decode_raw(int(msg.height), int(msg.width), str(msg.encoding), int(msg.step), msg.data,
                               self.path, where)
            metadata["encoding"] = str(msg.encoding)
        else:
            try:
                image = decode_image(bytes(msg.data), self.path)
            except DataFormatError as exc:
                raise DataFormatError(self.path, f"{where}: {exc.message}", field="data", hint=exc.hint) from None
            metadata["compression"] = str(msg.format)
        metadata["size"] = [int(image.shape[0]), int(image.shape[1])]
        steering = None
        if self.steering is not None:
            steering = self.steering.at(log_time)
            metadata["steering_topic"] = self.steering.topic
        return ImageSample(image, frame_id=f"{index:06d}", steering=steering,
                           timestamp=(stamp if stamp else log_time) / NS, metadata=metadata)


def image_topics(path: Any) -> tuple[list[str], list[str]]:
    """Names of the (image, PointCloud2) topics of a log — to tell which modality it records."""
    from lidarfuzz.io.logs.backends import open_backend
    from lidarfuzz.io.logs.containers import detect_kind, reading
    from lidarfuzz.io.logs.messages import POINTCLOUD2

    source, kind = detect_kind(path)
    backend = open_backend(source, kind)
    try:
        with reading(source, "list the topics"):
            topics = backend.topics()
    finally:
        backend.close()
    return ([t.name for t in topics if t.msgtype in ImageLog.msgtypes],
            [t.name for t in topics if t.msgtype == POINTCLOUD2])
