"""ROS 1 / ROS 2 bags and MCAP files: round trips, foreign layouts, definition checks, errors."""

from __future__ import annotations

import pickle
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from mcap.writer import Writer as McapWriter
from rosbags.rosbag1 import Writer as Ros1Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from lidarfuzz.errors import DataFormatError
from lidarfuzz.io.atomic import OutputExistsError
from lidarfuzz.io.common import NonFiniteWarning
from lidarfuzz.io.logs import BagLog, PointField, decode, encode, inspect_bag, write_log
from lidarfuzz.io.logs.pointcloud2 import FLOAT32, FLOAT64, INT16, UINT8, UINT16
from lidarfuzz.scene.points import PointCloud
from lidarfuzz.scene.scene import Scene
from tests.strategies import clouds

ROS1 = get_typestore(Stores.ROS1_NOETIC)
ROS2 = get_typestore(Stores.ROS2_HUMBLE)
PC2 = "sensor_msgs/msg/PointCloud2"
APOLLO_TOPIC = "/apollo/sensor/velodyne64/compensator/PointCloud2"
CHANNELS = ("x", "y", "z", "intensity", "ring", "time")

#: (kind argument, file name, extra write_log arguments, expected BagLog.format)
KINDS = [
    pytest.param("ros1", "log.bag", {}, "ros1", id="ros1"),
    pytest.param("ros2", "log", {}, "ros2", id="ros2-sqlite3"),
    pytest.param("ros2", "log", {"storage": "mcap"}, "ros2", id="ros2-mcap"),
    pytest.param("mcap", "log.mcap", {}, "mcap", id="mcap"),
]


def make_scenes(n_points: tuple[int, ...] = (50, 0, 7), seed: int = 0) -> list[Scene]:
    rng = np.random.default_rng(seed)
    scenes = []
    for i, n in enumerate(n_points):
        data = rng.normal(size=(n, len(CHANNELS))).astype(np.float32) * 20
        data[:, 4] = rng.integers(0, 64, n)  # ring
        data[:, 5] = rng.uniform(0, 0.1, n)  # time
        scenes.append(Scene(PointCloud(data, CHANNELS), timestamp=1_600_000_000.0 + 0.1 * i + 1e-7 * i))
    return scenes


def same_bits(a: PointCloud, b: PointCloud) -> bool:
    return a.channels == b.channels and np.array_equal(a.data.view(np.uint32), b.data.view(np.uint32))


def pc2_message(
    store: Any,
    *,
    fields: list[PointField],
    point_step: int,
    data: bytes,
    width: int,
    height: int = 1,
    row_step: int | None = None,
    is_bigendian: bool = False,
    stamp_ns: int = 1_513_807_000_500_000_000,
    frame_id: str = "velodyne64",
) -> Any:
    """A PointCloud2 message object for ``store`` (ROS 1 or ROS 2) with raw point bytes."""
    types = store.types
    time = types["builtin_interfaces/msg/Time"](sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9)
    header_fields = {"stamp": time, "frame_id": frame_id}
    if "seq" in [name for name, _ in store.fielddefs["std_msgs/msg/Header"][1]]:
        header_fields["seq"] = 0
    point_field = types["sensor_msgs/msg/PointField"]
    return types[PC2](
        header=types["std_msgs/msg/Header"](**header_fields),
        height=height,
        width=width,
        fields=[point_field(name=f.name, offset=f.offset, datatype=f.datatype, count=f.count) for f in fields],
        is_bigendian=is_bigendian,
        point_step=point_step,
        row_step=width * point_step if row_step is None else row_step,
        data=np.frombuffer(data, np.uint8),
        is_dense=False,
    )


def write_ros1(path: Path, topics: dict[str, tuple[str, list[tuple[int, Any]]]], store: Any = ROS1) -> Path:
    """A ROS 1 bag written with the raw rosbags writer: ``{topic: (msgtype, [(log time ns, msg)])}``."""
    with Ros1Writer(path) as writer:
        for topic, (msgtype, messages) in topics.items():
            connection = writer.add_connection(topic, msgtype, typestore=store)
            for log_time, msg in messages:
                writer.write(connection, log_time, store.serialize_ros1(msg, msgtype))
    return path


def write_mcap(path: Path, messages: list[tuple[int, bytes]], *, ros1: bool = False, **options: Any) -> Path:
    """An MCAP file with one PointCloud2 channel (ROS 2 CDR, or ROS 1 encoding)."""
    store = ROS1 if ros1 else ROS2
    schema_text = store.generate_msgdef(PC2, **({} if ros1 else {"ros_version": 2}))[0]
    with open(path, "wb") as stream:
        writer = McapWriter(stream, **options)
        writer.start(profile="ros1" if ros1 else "ros2", library="test")
        schema = writer.register_schema(
            "sensor_msgs/PointCloud2" if ros1 else PC2, "ros1msg" if ros1 else "ros2msg", schema_text.encode()
        )
        channel = writer.register_channel("/points", "ros1" if ros1 else "cdr", schema)
        for log_time, data in messages:
            writer.add_message(channel, log_time, data, log_time)
        writer.finish()
    return path


def xyz_fields() -> list[PointField]:
    return [PointField("x", 0, FLOAT32), PointField("y", 4, FLOAT32), PointField("z", 8, FLOAT32)]


def string_msg(store: Any = ROS1) -> Any:
    return store.types["std_msgs/msg/String"](data="hello")


# ---------------------------------------------------------------- round trips
@pytest.mark.parametrize(("kind", "name", "extra", "expected"), KINDS)
def test_round_trip_each_kind(tmp_path, kind, name, extra, expected):
    scenes = make_scenes()
    path = write_log(tmp_path / name, scenes, kind=kind, **extra)
    log = BagLog(path)
    assert log.format == expected and log.topic == "/points"
    assert log.storage == (extra.get("storage", "sqlite3") if kind == "ros2" else None)
    assert list(log.frame_ids()) == ["000000", "000001", "000002"]
    assert log.timestamps().tolist() == [s.timestamp for s in scenes]
    assert log.poses() is None and log.problems() == []
    streamed = list(log)
    for i, (scene, back) in enumerate(zip(scenes, streamed, strict=True)):
        assert same_bits(scene.points, back.points), i
        assert back.timestamp == scene.timestamp and back.frame_id == f"{i:06d}"
        assert back.metadata == {
            "source": str(path),
            "format": expected,
            "topic": "/points",
            "sensor_frame_id": "velodyne",
            "message_index": i,
        }
        assert log.load(f"{i:06d}") == back  # random access gives the same frame
    assert same_bits(log[-1].points, scenes[-1].points) and len(log["000001"]) == 0
    log.close()


@pytest.mark.parametrize(("kind", "name", "extra", "expected"), KINDS)
def test_frame_order_kept_and_default_timestamps(tmp_path, kind, name, extra, expected):
    # Without timestamps frames are 0.1 s apart; order must survive the log's time index.
    scenes = [Scene(PointCloud(np.full((3, 4), i, np.float32))) for i in range(12)]
    log = BagLog(write_log(tmp_path / name, scenes, kind=kind, **extra))
    assert [float(s.points.data[0, 0]) for s in log] == list(range(12))
    assert log.timestamps().tolist() == [i / 10 for i in range(12)]


@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    cloud_list=st.lists(clouds(max_points=40), min_size=1, max_size=3),
    stamps_ns=st.lists(st.integers(0, (2**31 - 2) * 10**9), min_size=3, max_size=3),
    case=st.sampled_from(
        [("ros1", "a.bag", {}), ("ros2", "b", {}), ("ros2", "c", {"storage": "mcap"}), ("mcap", "d.mcap", {})]
    ),
)
def test_round_trip_property(cloud_list, stamps_ns, case):
    kind, name, extra = case
    stamps = sorted(stamps_ns)[: len(cloud_list)]
    scenes = [Scene(c, timestamp=ns / 10**9) for c, ns in zip(cloud_list, stamps, strict=False)]
    with tempfile.TemporaryDirectory() as tmp:
        log = BagLog(write_log(Path(tmp) / name, scenes, kind=kind, **extra))
        back = list(log)
        assert [s.timestamp for s in back] == [s.timestamp for s in scenes] == log.timestamps().tolist()
        for scene, got in zip(scenes, back, strict=True):
            assert same_bits(scene.points, got.points)


def test_encode_decode_round_trip_and_layout():
    cloud = make_scenes((5,))[0].points
    msg = encode(cloud)
    assert msg["point_step"] == 24 and msg["row_step"] == 120 and msg["height"] == 1 and msg["is_dense"]
    assert [f.name for f in msg["fields"]] == list(CHANNELS)
    back, dropped = decode(
        **{k: msg[k] for k in ("fields", "point_step", "row_step", "height", "width", "is_bigendian", "data")},
        path="x.bag",
    )
    assert dropped == 0 and same_bits(back, cloud)


# ---------------------------------------------------------------- foreign layouts
def apollo_bytes(n: int, stamp: float) -> tuple[bytes, np.ndarray]:
    """Apollo's ROS-era layout: xyz float32, intensity uint8 @16, timestamp float64 @24, step 32."""
    dtype = np.dtype(
        {
            "names": ["x", "y", "z", "intensity", "timestamp"],
            "formats": ["<f4", "<f4", "<f4", "u1", "<f8"],
            "offsets": [0, 4, 8, 16, 24],
            "itemsize": 32,
        }
    )
    rng = np.random.default_rng(3)
    raw = bytearray(b"\xab" * (32 * n))  # the padding bytes hold junk, as in real drivers
    points = np.frombuffer(raw, dtype=dtype)  # a writable view: fields are set, padding stays junk
    points["x"], points["y"], points["z"] = (rng.normal(size=(3, n)) * 30).astype(np.float32)
    points["intensity"] = rng.integers(0, 256, n)
    points["timestamp"] = stamp + np.linspace(0, 0.099, n)
    values = points.copy()
    return bytes(raw), values


def test_apollo_velodyne64_topic(tmp_path):
    stamp_ns = 1_513_807_000_500_000_000
    raw, values = apollo_bytes(1000, stamp_ns / 1e9)
    fields = [*xyz_fields(), PointField("intensity", 16, UINT8), PointField("timestamp", 24, FLOAT64)]
    messages = [
        (
            stamp_ns + k * 100_000_000,
            pc2_message(ROS1, fields=fields, point_step=32, data=raw, width=1000, stamp_ns=stamp_ns + k * 100_000_000),
        )
        for k in range(2)
    ]
    path = write_ros1(
        tmp_path / "apollo.bag",
        {
            APOLLO_TOPIC: (PC2, messages),
            "/apollo/canbus/chassis_detail": ("std_msgs/msg/String", [(stamp_ns, string_msg())]),
        },
    )
    log = BagLog(path)  # the only PointCloud2 topic is chosen
    assert log.topic == APOLLO_TOPIC and len(log) == 2
    scene = log.load("000000")
    assert scene.points.channels == ("x", "y", "z", "intensity", "time")
    assert np.array_equal(scene.points.data[:, 0], values["x"])
    assert np.array_equal(scene.points.data[:, 2], values["z"])
    assert np.array_equal(scene.points.intensity, values["intensity"].astype(np.float32))
    # Absolute float64 stamps become seconds since the header stamp (float32 cannot hold epoch time).
    assert np.allclose(scene.points.channel("time"), np.linspace(0, 0.099, 1000), atol=1e-6)
    assert scene.timestamp == stamp_ns / 1e9
    assert scene.metadata["sensor_frame_id"] == "velodyne64" and scene.metadata["topic"] == APOLLO_TOPIC
    assert log.timestamps().tolist() == [stamp_ns / 1e9, (stamp_ns + 100_000_000) / 1e9]

    info = inspect_bag(path)
    assert info["format"] == "ros1" and info["message_count"] == 3
    assert info["pointcloud2_topics"] == [APOLLO_TOPIC]
    topic = next(t for t in info["topics"] if t["name"] == APOLLO_TOPIC)
    assert topic["count"] == 2 and topic["point_step"] == 32 and topic["standard_definition"]
    assert [(f["name"], f["datatype_name"], f["offset"], f["count"]) for f in topic["fields"]] == [
        ("x", "FLOAT32", 0, 1),
        ("y", "FLOAT32", 4, 1),
        ("z", "FLOAT32", 8, 1),
        ("intensity", "UINT8", 16, 1),
        ("timestamp", "FLOAT64", 24, 1),
    ]
    other = next(t for t in info["topics"] if t["name"] == "/apollo/canbus/chassis_detail")
    assert other["type"] == "std_msgs/msg/String" and not other["pointcloud2"]
    assert info["duration"] == pytest.approx(0.1)


def test_big_endian_points(tmp_path):
    xyz = np.array([[1.5, -2.0, 3.25], [4.0, 5.5, -6.0]], np.float32)
    dtype = np.dtype(
        {
            "names": ["x", "y", "z", "ring", "intensity"],
            "formats": [">f4", ">f4", ">f4", ">u2", ">i2"],
            "offsets": [0, 4, 8, 12, 14],
            "itemsize": 16,
        }
    )
    points = np.zeros(2, dtype)
    points["x"], points["y"], points["z"] = xyz.T
    points["ring"], points["intensity"] = [7, 300], [-5, 1000]
    fields = [*xyz_fields(), PointField("ring", 12, UINT16), PointField("intensity", 14, INT16)]
    msg = pc2_message(ROS1, fields=fields, point_step=16, data=points.tobytes(), width=2, is_bigendian=True)
    scene = BagLog(write_ros1(tmp_path / "be.bag", {"/points": (PC2, [(10**9, msg)])}))["000000"]
    assert np.array_equal(scene.points.xyz, xyz)
    assert scene.points.intensity.tolist() == [-5.0, 1000.0]
    assert scene.points.channel("ring").tolist() == [7.0, 300.0]


def test_row_step_padding_and_organised_cloud(tmp_path):
    values = np.arange(2 * 3 * 3, dtype=np.float32).reshape(2, 3, 3)  # 2 rows × 3 points
    rows = [values[r].tobytes() + b"\xee" * 8 for r in range(2)]  # 8 junk bytes after each row
    msg = pc2_message(ROS2, fields=xyz_fields(), point_step=12, data=b"".join(rows), width=3, height=2, row_step=44)
    scene = BagLog(write_mcap(tmp_path / "rows.mcap", [(5, bytes(ROS2.serialize_cdr(msg, PC2)))]))["000000"]
    assert np.array_equal(scene.points.xyz, values.reshape(6, 3))
    assert np.array_equal(scene.points.intensity, np.zeros(6))  # no intensity field → zeros


def test_count_greater_than_one_becomes_numbered_channels():
    data = np.array([[1, 2, 3, 10, 20]], "<f4").tobytes()
    fields = [*xyz_fields(), PointField("normal", 12, FLOAT32, count=2)]
    cloud, _ = decode(fields, 20, 20, 1, 1, False, data, path="n.bag")
    assert cloud.channels == ("x", "y", "z", "intensity", "normal_0", "normal_1")
    assert cloud.data.tolist() == [[1, 2, 3, 0, 10, 20]]


@pytest.mark.parametrize(
    ("stamps", "reference", "expected"),
    [
        ([1.5e9 + 0.01, 1.5e9 + 0.05], 1.5e9, [0.01, 0.05]),  # absolute seconds (Apollo, Hesai)
        ([1.5e18 + 1e7, 1.5e18 + 5e7], 1.5e9, [0.01, 0.05]),  # absolute nanoseconds (Livox)
        ([5.01, 5.05], 5.0, [0.01, 0.05]),  # absolute seconds in a sim-time log
        ([0.01, 0.05], 5.0, [0.01, 0.05]),  # already relative: kept
    ],
)
def test_float64_point_times_become_relative(stamps, reference, expected):
    dtype = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("t", "<f8")])
    points = np.zeros(2, dtype)
    points["t"] = stamps
    fields = [*xyz_fields(), PointField("t", 12, FLOAT64)]
    cloud, _ = decode(fields, 20, 40, 1, 2, False, points.tobytes(), path="t.bag", time_reference=reference)
    assert np.allclose(cloud.channel("time"), expected, atol=1e-6)


def test_nan_points_dropped_with_warning(tmp_path):
    data = np.array([[1, 2, 3], [np.nan, 0, 0], [4, 5, 6], [np.inf, 1, 1]], np.float32)
    msg = pc2_message(ROS1, fields=xyz_fields(), point_step=12, data=data.tobytes(), width=4)
    path = write_ros1(tmp_path / "nan.bag", {"/points": (PC2, [(10**9, msg)])})
    with pytest.warns(NonFiniteWarning, match="dropped 2 point"):
        scene = BagLog(path).load("000000")
    assert scene.points.xyz.tolist() == [[1, 2, 3], [4, 5, 6]]
    assert scene.metadata["dropped_nonfinite"] == 2
    with pytest.raises(DataFormatError, match="NaN/Inf coordinates"):
        BagLog(path, nonfinite="reject").load("000000")


def test_zero_header_stamp_falls_back_to_log_time(tmp_path):
    msg = pc2_message(ROS1, fields=xyz_fields(), point_step=12, data=bytes(12), width=1, stamp_ns=0)
    log = BagLog(write_ros1(tmp_path / "zero.bag", {"/points": (PC2, [(42 * 10**9, msg)])}))
    assert log.timestamps().tolist() == [42.0] and log["000000"].timestamp == 42.0
    assert any("zero header stamp" in p.message for p in log.problems())


def test_pickled_log_reopens(tmp_path):
    log = BagLog(write_log(tmp_path / "p.mcap", make_scenes()))
    log.load("000000")  # opens the cached reader
    clone = pickle.loads(pickle.dumps(log))
    assert clone.load("000002") == log.load("000002")


def test_ros1_encoded_mcap_channel(tmp_path):
    xyz = np.arange(6, dtype=np.float32).reshape(2, 3)
    msg = pc2_message(ROS1, fields=xyz_fields(), point_step=12, data=xyz.tobytes(), width=2, stamp_ns=7 * 10**9)
    log = BagLog(write_mcap(tmp_path / "ros1.mcap", [(8 * 10**9, bytes(ROS1.serialize_ros1(msg, PC2)))], ros1=True))
    scene = log["000000"]
    assert np.array_equal(scene.points.xyz, xyz) and scene.timestamp == 7.0
    assert inspect_bag(log.path)["topics"][0]["encoding"] == "ros1"


def test_unindexed_mcap_is_scanned(tmp_path):
    from mcap.writer import IndexType

    raws = []
    for i in range(3):
        cloud = encode(PointCloud(np.full((2, 4), i, np.float32)))
        msg = pc2_message(
            ROS2,
            fields=cloud["fields"],
            point_step=16,
            data=cloud["data"].tobytes(),
            width=2,
            stamp_ns=(i + 1) * 10**9,
        )
        raws.append(((i + 1) * 10**9, bytes(ROS2.serialize_cdr(msg, PC2))))
    path = write_mcap(
        tmp_path / "stream.mcap",
        raws,
        index_types=IndexType.NONE,
        use_statistics=False,
        repeat_channels=False,
        repeat_schemas=False,
        use_summary_offsets=False,
    )
    log = BagLog(path)
    assert log.timestamps().tolist() == [1.0, 2.0, 3.0]
    assert log.load("000002").points.data[0, 0] == 2 and [s.points.data[0, 0] for s in log] == [0, 1, 2]
    assert inspect_bag(path)["message_count"] == 3


def test_message_too_short_for_a_header(tmp_path):
    with Ros1Writer(tmp_path / "short.bag") as writer:
        connection = writer.add_connection("/points", PC2, typestore=ROS1)
        writer.write(connection, 10**9, b"\x00\x00")
    with pytest.raises(DataFormatError, match=r"topic /points, message 0: 2 bytes are too few to hold a header"):
        BagLog(tmp_path / "short.bag")


# ---------------------------------------------------------------- writing
def test_write_refuses_to_overwrite_unless_asked(tmp_path):
    scenes = make_scenes((4,))
    for name in ("a.bag", "b", "c.mcap"):
        path = write_log(tmp_path / name, scenes)
        with pytest.raises(OutputExistsError):
            write_log(path, scenes)
        write_log(path, make_scenes((9,)), overwrite=True)
        assert len(BagLog(path)["000000"]) == 9
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.bag", "b", "c.mcap"]  # no staging left
    assert sorted(p.name for p in (tmp_path / "b").iterdir()) == ["b.db3", "metadata.yaml"]


def test_write_errors(tmp_path):
    with pytest.raises(ValueError, match="suffix"):
        write_log(tmp_path / "x.txt", make_scenes())
    with pytest.raises(ValueError, match="not negative"):
        write_log(tmp_path / "x.bag", [Scene(PointCloud.empty(), timestamp=-1.0)])
    assert not (tmp_path / "x.bag").exists()  # a failed write leaves nothing behind
    assert list(tmp_path.iterdir()) == []


# ---------------------------------------------------------------- errors
def test_no_pointcloud2_topic(tmp_path):
    path = write_ros1(tmp_path / "chat.bag", {"/chatter": ("std_msgs/msg/String", [(10**9, string_msg())])})
    with pytest.raises(DataFormatError, match="no sensor_msgs/PointCloud2 messages in") as err:
        BagLog(path)
    assert str(path) in str(err.value) and "/chatter (std_msgs/msg/String, 1 messages)" in str(err.value)


def test_several_pointcloud2_topics_need_a_choice(tmp_path):
    msg = pc2_message(ROS1, fields=xyz_fields(), point_step=12, data=bytes(24), width=2)
    path = write_ros1(
        tmp_path / "two.bag",
        {
            "/lidar/front": (PC2, [(10**9, msg)]),
            "/lidar/rear": (PC2, [(10**9, msg), (2 * 10**9, msg)]),
        },
    )
    with pytest.raises(DataFormatError, match="2 sensor_msgs/PointCloud2 topics") as err:
        BagLog(path)
    assert "/lidar/front" in str(err.value) and "/lidar/rear" in str(err.value)
    assert "topic=" in str(err.value) and "--topic" in str(err.value)
    assert len(BagLog(path, topic="/lidar/rear")) == 2


def test_wrong_topic_name(tmp_path):
    msg = pc2_message(ROS1, fields=xyz_fields(), point_step=12, data=bytes(12), width=1)
    path = write_ros1(
        tmp_path / "one.bag",
        {
            "/points": (PC2, [(10**9, msg)]),
            "/chatter": ("std_msgs/msg/String", [(10**9, string_msg())]),
        },
    )
    with pytest.raises(DataFormatError, match=r"no topic '/velodyne_points'.*PointCloud2 topics: /points"):
        BagLog(path, topic="/velodyne_points")
    with pytest.raises(DataFormatError, match="carries std_msgs/msg/String, not sensor_msgs/PointCloud2"):
        BagLog(path, topic="/chatter")


CUSTOM_POINTCLOUD2 = """\
std_msgs/Header header
uint32 height
uint32 width
float32[] points
"""


def test_nonstandard_ros1_definition_is_refused(tmp_path):
    store = get_typestore(Stores.EMPTY)
    store.register({"std_msgs/msg/Header": ROS1.fielddefs["std_msgs/msg/Header"]})
    store.register(get_types_from_msg(CUSTOM_POINTCLOUD2, PC2))
    types = store.types
    header = types["std_msgs/msg/Header"](
        seq=0, stamp=types["builtin_interfaces/msg/Time"](sec=1, nanosec=0), frame_id="x"
    )
    msg = types[PC2](header=header, height=1, width=2, points=np.zeros(6, np.float32))
    path = write_ros1(tmp_path / "custom.bag", {APOLLO_TOPIC: (PC2, [(10**9, msg)])}, store=store)
    with pytest.raises(DataFormatError, match="definition differs") as err:
        BagLog(path)
    text = str(err.value)
    assert str(path) in text and APOLLO_TOPIC in text and "1158d486dd51d683ce2f1be655c3c181" in text
    assert "float32[] points" in text
    info = inspect_bag(path)
    assert info["topics"][0]["standard_definition"] is False and "fields" not in info["topics"][0]


def test_nonstandard_mcap_schema_is_refused(tmp_path):
    path = tmp_path / "custom.mcap"
    with open(path, "wb") as stream:
        writer = McapWriter(stream)
        writer.start(profile="ros2", library="test")
        schema = writer.register_schema(PC2, "ros2msg", b"float64[] ranges\n")
        channel = writer.register_channel("/points", "cdr", schema)
        writer.add_message(channel, 1, b"\x00\x01\x00\x00" + bytes(8), 1)
        writer.finish()
    with pytest.raises(DataFormatError, match=r"'/points'.*definition differs.*float64\[\] ranges"):
        BagLog(path)


@pytest.mark.parametrize("damage", ["truncated", "garbage", "empty"])
@pytest.mark.parametrize("name", ["log.bag", "log.mcap"])
def test_damaged_files_name_the_file(tmp_path, damage, name):
    path = write_log(tmp_path / name, make_scenes((200, 200)))
    content = path.read_bytes()
    if damage == "truncated":
        path.write_bytes(content[: len(content) // 2])
    elif damage == "garbage":
        path.write_bytes(content[:16] + np.random.default_rng(1).bytes(4000))
    else:
        path.write_bytes(b"")
    with pytest.raises(DataFormatError) as err:
        BagLog(path)
    assert str(err.value).startswith(str(path))
    with pytest.raises(DataFormatError):
        inspect_bag(path)


def test_damaged_ros2_bag_and_odd_paths(tmp_path):
    bag = write_log(tmp_path / "r2", make_scenes())
    (bag / "r2.db3").write_bytes(b"not a database" * 100)
    with pytest.raises(DataFormatError, match="cannot open the ROS 2 bag") as err:
        BagLog(bag)
    assert str(err.value).startswith(str(bag))
    (tmp_path / "plain").mkdir()
    with pytest.raises(DataFormatError, match=r"no metadata\.yaml"):
        BagLog(tmp_path / "plain")
    with pytest.raises(DataFormatError, match="file not found"):
        BagLog(tmp_path / "missing.bag")
    with pytest.raises(KeyError):
        BagLog(write_log(tmp_path / "ok.bag", make_scenes())).load("3")


@pytest.mark.parametrize(
    ("fields", "point_step", "row_step", "height", "width", "size", "message"),
    [
        (xyz_fields(), 12, 48, 1, 4, 40, "data holds 40 bytes but height 1 × row_step 48 needs 48"),
        (xyz_fields(), 12, 48, 2, 4, 60, "needs 96"),
        ([*xyz_fields(), PointField("intensity", 10, FLOAT32)], 12, 12, 1, 1, 12, "runs past point_step 12"),
        ([*xyz_fields(), PointField("intensity", 12, 9)], 16, 16, 1, 1, 16, "unknown PointField datatype 9"),
        (xyz_fields(), 12, 20, 1, 2, 40, "row_step 20 is smaller than width 2"),
        ([PointField("x", 0, FLOAT32)], 4, 4, 1, 1, 4, "no 'y' field"),
    ],
)
def test_decode_rejects_inconsistent_sizes(fields, point_step, row_step, height, width, size, message):
    with pytest.raises(DataFormatError, match=message) as err:
        decode(
            fields,
            point_step,
            row_step,
            height,
            width,
            False,
            bytes(size),
            path="scan.bag",
            context="topic /points, message 7",
        )
    assert str(err.value).startswith("scan.bag: topic /points, message 7: ")


def test_bad_message_in_a_bag_names_topic_and_index(tmp_path):
    good = pc2_message(ROS1, fields=xyz_fields(), point_step=12, data=bytes(24), width=2)
    short = pc2_message(ROS1, fields=xyz_fields(), point_step=12, data=bytes(12), width=2)
    log = BagLog(write_ros1(tmp_path / "short.bag", {"/points": (PC2, [(10**9, good), (2 * 10**9, short)])}))
    with pytest.raises(DataFormatError, match=r"short.bag: topic /points, message 1: data holds 12 bytes"):
        log.load("000001")
    with pytest.raises(DataFormatError, match="message 1"):
        list(log)
