"""sensor_msgs/Image and CompressedImage topics of ROS 1 bags, ROS 2 bags and MCAP files."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from mcap.writer import Writer as McapWriter
from rosbags.rosbag1 import Writer as Ros1Writer
from rosbags.rosbag2 import Writer as Ros2Writer
from rosbags.typesys import Stores, get_typestore

from lidarfuzz.errors import DataFormatError
from lidarfuzz.io.dataset import Log
from lidarfuzz.io.images import ImageLog, open_image_dataset
from lidarfuzz.io.open import open_dataset, source_modality
from tests.io.images.util import PIXELS, png_bytes

ROS1 = get_typestore(Stores.ROS1_NOETIC)
ROS2 = get_typestore(Stores.ROS2_HUMBLE)
IMAGE = "sensor_msgs/msg/Image"
COMPRESSED = "sensor_msgs/msg/CompressedImage"
STAMP = 1_700_000_000_250_000_000  # ns


def header(store: Any, stamp_ns: int) -> Any:
    types = store.types
    time = types["builtin_interfaces/msg/Time"](sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9)
    fields: dict[str, Any] = {"stamp": time, "frame_id": "camera_front"}
    if "seq" in [name for name, _ in store.fielddefs["std_msgs/msg/Header"][1]]:  # ROS 1 headers have one
        fields["seq"] = 0
    return types["std_msgs/msg/Header"](**fields)


def bgr8_padded(store: Any, stamp_ns: int, *, height: int = 2, cut: int = 0) -> Any:
    """PIXELS as bgr8 with every row padded to 12 bytes (9 bytes of pixels + 3 of padding)."""
    rows = [np.concatenate([PIXELS[r, :, ::-1].reshape(-1), np.full(3, 77, np.uint8)]) for r in range(2)]
    data = np.concatenate(rows)[: len(rows) * 12 - cut]
    return store.types[IMAGE](header=header(store, stamp_ns), height=height, width=3, encoding="bgr8",
                              is_bigendian=0, step=12, data=data)


def compressed(store: Any, stamp_ns: int, data: bytes | None = None) -> Any:
    payload = np.frombuffer(png_bytes(PIXELS[::-1].copy()) if data is None else data, np.uint8)
    return store.types[COMPRESSED](header=header(store, stamp_ns), format="png", data=payload)


def write_ros1(path: Path, messages: dict[str, list[Any]]) -> Path:
    with Ros1Writer(path) as writer:
        for topic, msgs in messages.items():
            msgtype = IMAGE if msgs and hasattr(msgs[0], "encoding") else COMPRESSED
            connection = writer.add_connection(topic, msgtype, typestore=ROS1)
            for i, msg in enumerate(msgs):
                writer.write(connection, STAMP + i * 100_000_000, ROS1.serialize_ros1(msg, msgtype))
    return path


def write_ros2(path: Path, messages: dict[str, list[Any]]) -> Path:
    with Ros2Writer(path, version=8) as writer:
        for topic, msgs in messages.items():
            msgtype = IMAGE if msgs and hasattr(msgs[0], "encoding") else COMPRESSED
            connection = writer.add_connection(topic, msgtype, typestore=ROS2)
            for i, msg in enumerate(msgs):
                writer.write(connection, STAMP + i * 100_000_000, ROS2.serialize_cdr(msg, msgtype))
    return path


def write_mcap(path: Path, messages: dict[str, list[Any]]) -> Path:
    with open(path, "wb") as stream:
        writer = McapWriter(stream)
        writer.start(profile="ros2", library="test")
        for topic, msgs in messages.items():
            msgtype = IMAGE if msgs and hasattr(msgs[0], "encoding") else COMPRESSED
            text, _ = ROS2.generate_msgdef(msgtype, ros_version=2)
            schema = writer.register_schema(msgtype, "ros2msg", text.encode())
            channel = writer.register_channel(topic, "cdr", schema)
            for i, msg in enumerate(msgs):
                time = STAMP + i * 100_000_000
                writer.add_message(channel, log_time=time, data=ROS2.serialize_cdr(msg, msgtype), publish_time=time)
        writer.finish()
    return path


WRITERS = [
    pytest.param(write_ros1, ROS1, "log.bag", "ros1", id="ros1"),
    pytest.param(write_ros2, ROS2, "log", "ros2", id="ros2"),
    pytest.param(write_mcap, ROS2, "log.mcap", "mcap", id="mcap"),
]


@pytest.mark.parametrize(("write", "store", "name", "kind"), WRITERS)
def test_raw_and_compressed_topics(tmp_path, write, store, name, kind):
    path = write(tmp_path / name, {
        "/camera/raw": [bgr8_padded(store, STAMP), bgr8_padded(store, 0)],
        "/camera/compressed": [compressed(store, STAMP + 5)],
    })
    raw = open_image_dataset(path, topic="/camera/raw")
    assert isinstance(raw, ImageLog) and isinstance(raw, Log) and raw.format == kind
    assert list(raw.frame_ids()) == ["000000", "000001"]
    first = raw["000000"]
    assert np.array_equal(first.image, PIXELS)  # bgr8 → RGB, the 3 padding bytes of each row dropped
    assert first.timestamp == 1_700_000_000.25 and first.steering is None
    assert first.metadata["encoding"] == "bgr8" and first.metadata["sensor_frame_id"] == "camera_front"
    # the second message has a zero stamp: its log time (0.1 s after the first) stands in
    assert raw.timestamps().tolist() == [1_700_000_000.25, 1_700_000_000.35]
    assert [np.array_equal(s.image, PIXELS) for s in raw] == [True, True]  # streaming reads the same pixels

    packed = open_image_dataset(path, topic="/camera/compressed")
    sample = packed[0]
    assert np.array_equal(sample.image, PIXELS[::-1]) and sample.metadata["compression"] == "png"

    with pytest.raises(DataFormatError, match=r"2 sensor_msgs/Image or sensor_msgs/CompressedImage topics"):
        open_image_dataset(path)
    with pytest.raises(DataFormatError, match="no topic '/lidar'; sensor_msgs/Image or sensor_msgs/CompressedImage "
                                              "topics: /camera/"):
        open_image_dataset(path, topic="/lidar")


@pytest.mark.parametrize(("write", "store", "name", "kind"), WRITERS)
def test_data_shorter_than_height_times_step(tmp_path, write, store, name, kind):
    path = write(tmp_path / name, {"/cam": [bgr8_padded(store, STAMP, cut=1)]})
    log = open_image_dataset(path)
    with pytest.raises(DataFormatError, match=r"field 'data': topic /cam, message 0: data has 23 bytes but height × "
                                              r"step is 2 × 12 = 24") as info:
        log[0]
    assert info.value.path == path


def test_truncated_compressed_image(tmp_path):
    cut = png_bytes()[:-12]
    path = write_ros1(tmp_path / "log.bag", {"/cam": [compressed(ROS1, STAMP, cut)]})
    with pytest.raises(DataFormatError, match=r"log\.bag: field 'data': topic /cam, message 0: truncated PNG: no "
                                              r"IEND chunk"):
        open_image_dataset(path)[0]


def test_an_image_only_log_opens_as_the_camera_modality(tmp_path):
    path = write_mcap(tmp_path / "log.mcap", {"/cam": [compressed(ROS2, STAMP)]})
    assert source_modality(path) == "camera"
    assert source_modality(path, "/cam") == "camera"
    with pytest.raises(DataFormatError, match="no sensor_msgs/PointCloud2 messages"):
        open_dataset(path)  # the LiDAR reader's own message, unchanged
    assert len(open_dataset(path, modality="camera")) == 1


STEERING_REPORT = "dbw_mkz_msgs/msg/SteeringReport"


def test_steering_from_a_vendor_topic_is_interpolated_at_each_image(tmp_path):
    """Udacity-style: a SteeringReport type no reference store knows, defined only inside the bag."""
    from rosbags.typesys import get_types_from_msg

    store = get_typestore(Stores.ROS1_NOETIC)
    store.register(get_types_from_msg("std_msgs/Header header\nfloat32 steering_wheel_angle\nfloat32 speed\n",
                                      STEERING_REPORT))
    path = tmp_path / "drive.bag"
    with Ros1Writer(path) as writer:
        images = writer.add_connection("/center_camera/image_color", IMAGE, typestore=store)
        steering = writer.add_connection("/vehicle/steering_report", STEERING_REPORT, typestore=store)
        for i in range(3):  # images at T, T + 0.1 s, T + 0.2 s
            time = STAMP + i * 100_000_000
            writer.write(images, time, store.serialize_ros1(bgr8_padded(store, time), IMAGE))
        for offset, angle in ((50_000_000, 0.125), (150_000_000, 0.375)):  # steering at T + 0.05 s, T + 0.15 s
            report = store.types[STEERING_REPORT](header=header(store, 0), steering_wheel_angle=angle, speed=8.0)
            writer.write(steering, STAMP + offset, store.serialize_ros1(report, STEERING_REPORT))

    log = open_image_dataset(path, topic="/center_camera/image_color", steering_topic="/vehicle/steering_report")
    # T + 0.1 s lies halfway between the two reports: (0.125 + 0.375) / 2 = 0.25; T and T + 0.2 s lie
    # outside them: unlabelled, not extrapolated
    assert [s.steering for s in log] == [None, 0.25, None]
    assert log[1].metadata["steering_topic"] == "/vehicle/steering_report"
    assert [p.message for p in log.problems()] == [
        "2 of 3 image(s) lie outside the messages of /vehicle/steering_report: unlabelled"]
    with pytest.raises(DataFormatError, match=r"field 'steering_field': topic '/vehicle/steering_report' "
                                              r"\(dbw_mkz_msgs/msg/SteeringReport\) has no field 'wheel'; its "
                                              r"fields: header, steering_wheel_angle, speed"):
        open_image_dataset(path, steering_topic="/vehicle/steering_report", steering_field="wheel")


def _float_topic(path: Path, values: list[float]) -> Path:
    with open(path, "wb") as stream:
        writer = McapWriter(stream)
        writer.start(profile="ros2", library="test")
        for topic, msgtype in (("/cam", COMPRESSED), ("/steering", "std_msgs/msg/Float64")):
            text, _ = ROS2.generate_msgdef(msgtype, ros_version=2)
            schema = writer.register_schema(msgtype, "ros2msg", text.encode())
            channel = writer.register_channel(topic, "cdr", schema)
            if topic == "/cam":
                for i in range(2):
                    time = STAMP + i * 100_000_000
                    writer.add_message(channel, log_time=time, publish_time=time,
                                       data=ROS2.serialize_cdr(compressed(ROS2, time), COMPRESSED))
            else:
                for i, value in enumerate(values):  # at T and T + 0.1 s
                    time = STAMP + i * 100_000_000
                    msg = ROS2.types[msgtype](data=value)
                    writer.add_message(channel, log_time=time, publish_time=time, data=ROS2.serialize_cdr(msg, msgtype))
        writer.finish()
    return path


def test_steering_from_a_float64_topic_and_bad_values(tmp_path):
    log = open_image_dataset(_float_topic(tmp_path / "a.mcap", [-0.5, 0.5]), steering_topic="/steering")
    assert [s.steering for s in log] == [-0.5, 0.5] and log.steering.field == "data"
    with pytest.raises(DataFormatError, match=r"field 'data': topic /steering, message 1: nan is not a finite number"):
        open_image_dataset(_float_topic(tmp_path / "b.mcap", [0.0, float("nan")]), steering_topic="/steering")
    with pytest.raises(DataFormatError, match=r"field 'steering_topic': no topic '/wheel'; topics: /cam, /steering"):
        open_image_dataset(tmp_path / "a.mcap", steering_topic="/wheel")
