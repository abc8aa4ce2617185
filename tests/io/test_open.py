import numpy as np
import pytest

from lidarfuzz.errors import DataFormatError
from lidarfuzz.io import FrameFolder, KittiLog, SingleFrame, open_dataset, write_frame
from lidarfuzz.io.logs import BagLog, write_log
from lidarfuzz.io.open import source_kind
from lidarfuzz.scene import PointCloud, Scene


def _scene(n: int = 4, frame_id: str = "f") -> Scene:
    return Scene(PointCloud(np.arange(4 * n, dtype=np.float32).reshape(n, 4)), frame_id=frame_id)


def test_kinds_are_recognised(tmp_path, kitti_log):
    write_frame(tmp_path / "a.pcd", _scene())
    write_log(tmp_path / "l.mcap", [_scene()])
    assert source_kind(kitti_log) == "kitti" and isinstance(open_dataset(kitti_log), KittiLog)
    assert isinstance(open_dataset(tmp_path / "a.pcd"), SingleFrame)
    assert isinstance(open_dataset(tmp_path / "l.mcap"), BagLog)
    folder = tmp_path / "frames"
    for i in range(3):
        write_frame(folder / f"{i:03d}.ply", _scene(frame_id=str(i)))
    dataset = open_dataset(folder)
    assert isinstance(dataset, FrameFolder) and list(dataset.frame_ids()) == ["000", "001", "002"]
    assert dataset["001"].points == _scene().points and dataset[-1].frame_id == "002"
    with pytest.raises(KeyError, match="no frame with id 'zzz'"):
        dataset["zzz"]


def test_duplicate_frame_ids_in_a_folder(tmp_path):
    write_frame(tmp_path / "000001.bin", _scene())
    write_frame(tmp_path / "000001.pcd", _scene())
    with pytest.raises(DataFormatError, match="duplicate frame id '000001'"):
        open_dataset(tmp_path)


def test_empty_and_missing_sources(tmp_path):
    with pytest.raises(DataFormatError, match="no point-cloud frames found"):
        open_dataset(tmp_path)
    with pytest.raises(DataFormatError, match="no such file or folder"):
        open_dataset(tmp_path / "nope")
    (tmp_path / "notes.txt").write_text("x")
    with pytest.raises(DataFormatError, match="unsupported file type"):
        open_dataset(tmp_path / "notes.txt")


def test_iteration_is_lazy(tmp_path):
    for i in range(3):
        write_frame(tmp_path / f"{i}.bin", _scene())
    (tmp_path / "1.bin").write_bytes(b"\0" * 5)  # broken, but only when loaded
    dataset = open_dataset(tmp_path)
    frames = iter(dataset)
    assert next(frames).frame_id == "0"
    with pytest.raises(DataFormatError, match=r"1\.bin: size 5 bytes"):
        next(frames)
