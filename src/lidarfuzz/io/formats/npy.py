"""NumPy files: ``.npy`` point arrays and ``.npz`` archives, including lidarfuzz's full-scene archive.

``.npy`` holds either a structured array whose named numeric fields become channels
(through the shared aliases: ``reflectance`` → ``intensity``, ...; a sub-array field
``normal`` of k values becomes ``normal_0`` … ``normal_{k-1}``), or a plain N×C
numeric array with C ≥ 3 whose columns are ``x, y, z, intensity`` and then ``c4``,
``c5``, … (intensity is zero when C = 3). lidarfuzz writes a structured array with one
float32 field per channel, so values round-trip bit-exactly; as in every format that
maps names, a channel named after an alias of an absent standard channel (``beam``
without ``ring``) reads back as that channel, and names are lower-cased.

``.npz`` written by lidarfuzz is a whole scene — points, channel names, every box
field, the calibration matrices, ROI (as GeoJSON text), pose, timestamp, frame id and
metadata (as JSON text) — and ``read(write(scene)) == scene`` exactly, frame id and
metadata included (the archive's own path is not added to the metadata, which must be
JSON-able; tuples in it come back as lists). Any other ``.npz`` is read as points
only, from its ``points`` array or its single array.

Files are never unpickled (``allow_pickle=False``): object arrays are refused with an
error. The file's contents, not its suffix, tell ``.npy`` from ``.npz`` on reading.
"""

from __future__ import annotations

import ast
import dataclasses
import json
import math
import zipfile
from collections.abc import Mapping
from os import PathLike
from pathlib import Path
from typing import IO, Any

import numpy as np
from numpy.typing import NDArray
from shapely.errors import ShapelyError  # type: ignore[import-untyped]

from lidarfuzz.errors import DataFormatError
from lidarfuzz.io.atomic import atomic_path
from lidarfuzz.io.common import NonFinitePolicy, cloud_from_columns, finish_cloud, map_field_names
from lidarfuzz.io.guards import describe, file_size, reading, require_bytes
from lidarfuzz.scene.boxes import Boxes3D
from lidarfuzz.scene.calib import CALIB_KEYS, KittiCalibration
from lidarfuzz.scene.points import STANDARD_CHANNELS, PointCloud, frozen
from lidarfuzz.scene.roi import RoiMap
from lidarfuzz.scene.scene import Scene

SUFFIXES = (".npy", ".npz")
#: Key marking lidarfuzz's scene archive; its value is the archive layout's version.
ARCHIVE_KEY = "lidarfuzz_scene_version"
ARCHIVE_VERSION = 1
BOX_FIELDS = tuple(f.name for f in dataclasses.fields(Boxes3D))
NPY_MAGIC = b"\x93NUMPY"
ZIP_MAGIC = b"PK"
_NUMERIC_KINDS = "biuf"
_EXPECTED = (
    "expected a structured array with named numeric fields (x, y, z, ...) or an N×C numeric array "
    "with C ≥ 3 (x, y, z, intensity, then extra columns)"
)


def _sniff(path: Path) -> bytes:
    try:
        with open(path, "rb") as handle:
            return handle.read(len(NPY_MAGIC))
    except FileNotFoundError:
        raise DataFormatError(path, "file not found") from None
    except OSError as exc:
        raise DataFormatError(path, f"cannot read: {exc.strerror}") from None


def _load_failure(path: Path, exc: Exception, key: str | None = None) -> DataFormatError:
    text = str(exc)
    if "allow_pickle" in text or "pickled" in text:
        return DataFormatError(
            path,
            "holds Python objects (an object array); lidarfuzz never unpickles files",
            field=key,
            hint="save a numeric or structured array instead",
        )
    return DataFormatError(path, f"cannot load: {exc}", field=key)


def _columns_from_array(array: NDArray[Any], path: Path, key: str | None = None) -> dict[str, NDArray[Any]]:
    """Channel columns of a structured or N×C array (see the module docstring)."""
    dtype = array.dtype
    if dtype.names is not None:
        if array.ndim == 0:
            raise DataFormatError(path, f"found a 0-d structured array; {_EXPECTED}", field=key)
        records = array.reshape(-1)
        sources: dict[str, NDArray[Any]] = {}
        for name in dtype.names:
            sub = dtype.fields[name][0]  # type: ignore[index]
            if sub.base.kind not in _NUMERIC_KINDS:
                raise DataFormatError(
                    path,
                    f"has dtype {sub}; only numeric fields can become channels ({_EXPECTED})",
                    field=name,
                )
            values = records[name].reshape(len(records), int(np.prod(sub.shape)))
            if sub.shape:
                for k in range(values.shape[1]):
                    sources[f"{name}_{k}"] = values[:, k]
            else:
                sources[name] = values[:, 0]
        mapping = map_field_names(list(sources))
        return {mapping[name]: values for name, values in sources.items()}
    if array.ndim != 2 or array.shape[1] < 3 or dtype.kind not in _NUMERIC_KINDS:
        raise DataFormatError(path, f"found an array of shape {array.shape} and dtype {dtype}; {_EXPECTED}", field=key)
    names = [*STANDARD_CHANNELS[: min(4, array.shape[1])], *(f"c{i}" for i in range(4, array.shape[1]))]
    return {name: array[:, i] for i, name in enumerate(names)}


# -- headers, checked before numpy allocates ------------------------------------------------
#: Longest .npy header read (numpy's own default refusal is at 10,000 bytes).
_MAX_HEADER = 10_000
#: Deepest nesting of brackets in a header's dict (a structured dtype nests one level per field level).
_MAX_NESTING = 16
#: DEFLATE's densest packing is about 1,032:1; a member declaring more than this is refused.
_MAX_DEFLATE_RATIO = 1100


def _nesting(text: str) -> int:
    depth = deepest = 0
    for char in text:
        if char in "([{":
            depth += 1
            deepest = max(deepest, depth)
        elif char in ")]}":
            depth -= 1
    return deepest


def _check_npy_header(handle: IO[bytes], path: Path, available: int, key: str | None = None) -> None:
    """Parse a ``.npy`` header ourselves (bounded length and nesting, :func:`ast.literal_eval` only)
    and check the array it declares against the ``available`` bytes, before numpy reads it.

    Raises:
        DataFormatError: naming the file, the archive member (``key``) and the header field.
    """
    magic = handle.read(len(NPY_MAGIC) + 2)
    if len(magic) < len(NPY_MAGIC) + 2 or magic[: len(NPY_MAGIC)] != NPY_MAGIC:
        raise DataFormatError(path, "cannot load: not a .npy array (no NumPy magic)", field=key)
    major = magic[-2]
    if major not in (1, 2, 3):
        raise DataFormatError(path, f"cannot load: unknown .npy format version {major}.{magic[-1]}", field=key)
    width = 2 if major == 1 else 4
    field = handle.read(width)
    if len(field) < width:
        raise DataFormatError(path, "cannot load: the .npy header is truncated", field=key)
    length = int.from_bytes(field, "little")
    if length > _MAX_HEADER:
        raise DataFormatError(path, f"cannot load: the .npy header claims {length:,} bytes; at most "
                              f"{_MAX_HEADER:,} are read", field=key or "header_len")
    raw = handle.read(length)
    if len(raw) < length:
        raise DataFormatError(path, f"cannot load: the .npy header is truncated ({len(raw)} of {length} bytes)",
                              field=key)
    try:
        text = raw.decode("utf-8" if major == 3 else "latin1")
    except UnicodeDecodeError:
        raise DataFormatError(path, "cannot load: the .npy header is not text", field=key) from None
    if _nesting(text) > _MAX_NESTING:
        raise DataFormatError(path, f"cannot load: the .npy header nests deeper than {_MAX_NESTING} levels", field=key)
    try:
        header = ast.literal_eval(text.strip())
    except (ValueError, SyntaxError, TypeError, MemoryError, RecursionError) as exc:
        raise DataFormatError(path, f"cannot load: the .npy header is not a Python literal ({type(exc).__name__})",
                              field=key) from None
    if not isinstance(header, dict) or set(header) != {"descr", "fortran_order", "shape"}:
        raise DataFormatError(path, "cannot load: the .npy header must be a dict with keys descr, fortran_order "
                              "and shape", field=key)
    shape = header["shape"]
    if not isinstance(shape, tuple) or not all(isinstance(n, int) and n >= 0 for n in shape):
        raise DataFormatError(path, f"cannot load: shape must be a tuple of non-negative integers, got {shape!r:.80}",
                              field=f"{key}.shape" if key else "shape")
    try:
        dtype = np.lib.format.descr_to_dtype(header["descr"])
    except Exception as exc:  # numpy raises ValueError, TypeError, KeyError... for a bad descr
        raise DataFormatError(path, f"cannot load: not a NumPy dtype: {describe(exc)}",
                              field=f"{key}.descr" if key else "descr") from None
    needed, holds = math.prod(shape) * max(dtype.itemsize, 1), max(available - handle.tell(), 0)
    if needed > holds:
        raise DataFormatError(path, f"cannot load: the header declares a {dtype} array of shape {shape} "
                              f"({needed:,} bytes) but {holds:,} bytes follow it",
                              field=f"{key}.shape" if key else "shape",
                              hint="the file is truncated or its header is damaged")


def _check_npz(path: Path, archive: zipfile.ZipFile) -> None:
    """Every member's declared size against its compressed size, then its .npy header."""
    size = file_size(path)
    for info in archive.infolist():
        if info.compress_size > size:
            raise DataFormatError(path, f"member claims {info.compress_size:,} compressed bytes but the archive "
                                  f"holds {size:,}", field=info.filename)
        ratio = 1 if info.compress_type == zipfile.ZIP_STORED else _MAX_DEFLATE_RATIO
        require_bytes(path, info.file_size, ratio * info.compress_size + 64, field=info.filename,
                      what="decompressed data (more than DEFLATE can pack)")
        if info.filename.endswith(".npy"):
            with archive.open(info) as member:
                _check_npy_header(member, path, info.file_size, key=info.filename.removesuffix(".npy"))


# -- .npy -------------------------------------------------------------------------------
def _read_npy(path: Path, nonfinite: NonFinitePolicy) -> tuple[Scene, int]:
    with open(path, "rb") as handle:
        _check_npy_header(handle, path, file_size(path))
    try:
        array = np.load(path, allow_pickle=False)
    except (ValueError, OSError, EOFError) as exc:
        raise _load_failure(path, exc) from exc
    cloud, dropped = cloud_from_columns(_columns_from_array(array, path), path, nonfinite=nonfinite)
    meta: dict[str, object] = {"source": str(path), "format": "npy"}
    if dropped:
        meta["dropped_nonfinite"] = dropped
    return Scene(cloud, frame_id=path.stem, metadata=meta), dropped


def _write_npy(tmp: Path, cloud: PointCloud) -> None:
    records = np.empty(len(cloud), dtype=[(name, "<f4") for name in cloud.channels])
    for i, name in enumerate(cloud.channels):
        records[name] = cloud.data[:, i]
    with open(tmp, "wb") as handle:
        np.save(handle, records, allow_pickle=False)


# -- .npz -------------------------------------------------------------------------------
def scene_arrays(scene: Scene) -> dict[str, NDArray[Any]]:
    """The arrays of lidarfuzz's scene archive (what :func:`write` stores in a ``.npz``)."""
    try:
        metadata_json = json.dumps(dict(scene.metadata))
    except (TypeError, ValueError) as exc:
        raise ValueError(f"scene metadata must be JSON-able to be archived: {exc}") from exc
    arrays: dict[str, NDArray[Any]] = {
        ARCHIVE_KEY: np.array(ARCHIVE_VERSION, dtype=np.int64),
        "points": np.ascontiguousarray(scene.points.data, dtype="<f4"),
        "channels": np.array(scene.points.channels, dtype=np.str_),
        # JSON text, because numpy's unicode arrays drop trailing NUL characters.
        "frame_id_json": np.array(json.dumps(scene.frame_id), dtype=np.str_),
        "metadata_json": np.array(metadata_json, dtype=np.str_),
    }
    for name in BOX_FIELDS:
        arrays[f"boxes_{name}"] = np.asarray(getattr(scene.boxes, name))
    if scene.calib is not None:
        for key, _, _ in CALIB_KEYS:
            matrix = getattr(scene.calib, key)
            if matrix is not None:
                arrays[f"calib_{key}"] = np.asarray(matrix, dtype=np.float64)
        arrays["calib_image_shape"] = np.asarray(scene.calib.image_shape, dtype=np.int64)
    if scene.roi is not None:
        arrays["roi_geojson"] = np.array(json.dumps(scene.roi.to_geojson()), dtype=np.str_)
    if scene.pose is not None:
        arrays["pose"] = np.asarray(scene.pose, dtype=np.float64)
    if scene.timestamp is not None:
        arrays["timestamp"] = np.array(scene.timestamp, dtype=np.float64)
    return arrays


def _text(arrays: Mapping[str, NDArray[Any]], key: str) -> str:
    value = arrays[key]
    if value.shape != () or value.dtype.kind != "U":
        raise ValueError(f"'{key}' must be a text scalar, got shape {value.shape} and dtype {value.dtype}")
    return str(value[()])


def _scene_from_arrays(arrays: Mapping[str, NDArray[Any]], path: Path, nonfinite: NonFinitePolicy) -> tuple[Scene, int]:
    """Rebuild a scene from the arrays of lidarfuzz's archive (inverse of :func:`scene_arrays`)."""
    try:
        version = int(arrays[ARCHIVE_KEY])
        if version > ARCHIVE_VERSION:
            raise DataFormatError(
                path,
                f"scene archive version {version} is newer than this lidarfuzz reads ({ARCHIVE_VERSION})",
                hint="upgrade lidarfuzz",
            )
        channels = [str(c) for c in arrays["channels"].reshape(-1)]
        cloud, dropped = finish_cloud(
            np.asarray(arrays["points"], dtype=np.float32), channels, path, nonfinite=nonfinite
        )
        box_values = {name: arrays[f"boxes_{name}"] for name in BOX_FIELDS}
        boxes = Boxes3D.create(
            box_values.pop("centers"),
            box_values.pop("sizes"),
            box_values.pop("yaw"),
            box_values.pop("labels"),
            **box_values,
        )
        # create() wraps yaw again, which is not the identity on every value (1e-20 becomes
        # 0.0); keep the stored values.
        boxes = dataclasses.replace(boxes, yaw=frozen(np.asarray(arrays["boxes_yaw"], dtype=np.float64)))
        calib = None
        if "calib_P2" in arrays:
            matrices = {key: arrays[f"calib_{key}"] for key, _, _ in CALIB_KEYS if f"calib_{key}" in arrays}
            shape = tuple(int(v) for v in arrays["calib_image_shape"])
            if len(shape) != 2:
                raise ValueError(f"calib_image_shape must hold 2 values, got {len(shape)}")
            calib = KittiCalibration(**matrices, image_shape=(shape[0], shape[1]))
        roi = RoiMap.from_geojson(_text(arrays, "roi_geojson")) if "roi_geojson" in arrays else None
        metadata = json.loads(_text(arrays, "metadata_json"))
        if not isinstance(metadata, dict):
            raise ValueError("'metadata_json' must hold a JSON object")
        frame_id = json.loads(_text(arrays, "frame_id_json"))
        if not isinstance(frame_id, str):
            raise ValueError("'frame_id_json' must hold a JSON string")
        if dropped:
            metadata["dropped_nonfinite"] = dropped
        scene = Scene(
            cloud,
            boxes=boxes,
            calib=calib,
            frame_id=frame_id,
            timestamp=float(arrays["timestamp"]) if "timestamp" in arrays else None,
            pose=arrays.get("pose"),
            roi=roi,
            metadata=metadata,
        )
    except DataFormatError:
        raise
    except KeyError as exc:
        raise DataFormatError(path, f"scene archive lacks the {exc} array") from None
    except (ValueError, TypeError, AttributeError, ShapelyError) as exc:
        raise DataFormatError(path, f"malformed scene archive: {exc}") from exc
    return scene, dropped


def _read_npz(path: Path, nonfinite: NonFinitePolicy) -> tuple[Scene, int]:
    try:
        archive = np.load(path, allow_pickle=False)
    except (ValueError, OSError, EOFError, zipfile.BadZipFile) as exc:
        raise DataFormatError(path, f"not a readable .npz archive: {exc}") from exc
    with archive:
        _check_npz(path, archive.zip)
        keys = list(archive.files)
        if ARCHIVE_KEY in keys:
            wanted = keys
        elif "points" in keys:
            wanted = ["points"]
        elif len(keys) == 1:
            wanted = keys
        else:
            raise DataFormatError(
                path,
                f"no 'points' array among {sorted(keys)}",
                hint="expected lidarfuzz's scene archive, or one with a 'points' array or a single array",
            )
        arrays: dict[str, NDArray[Any]] = {}
        for key in wanted:
            try:
                arrays[key] = archive[key]
            except (ValueError, OSError, EOFError, zipfile.BadZipFile) as exc:
                raise _load_failure(path, exc, key) from exc
    if ARCHIVE_KEY in arrays:
        return _scene_from_arrays(arrays, path, nonfinite)
    (key,) = wanted
    columns = _columns_from_array(arrays[key], path, key)
    cloud, dropped = cloud_from_columns(columns, path, nonfinite=nonfinite)
    meta: dict[str, object] = {"source": str(path), "format": "npz", "array": key}
    if dropped:
        meta["dropped_nonfinite"] = dropped
    return Scene(cloud, frame_id=path.stem, metadata=meta), dropped


# -- public -------------------------------------------------------------------------------
def _read(path: Path, nonfinite: NonFinitePolicy) -> tuple[Scene, int]:
    with reading(path, "read the NumPy file"):
        return _read_checked(path, nonfinite)


def _read_checked(path: Path, nonfinite: NonFinitePolicy) -> tuple[Scene, int]:
    magic = _sniff(path)
    if magic.startswith(ZIP_MAGIC):
        return _read_npz(path, nonfinite)
    if magic == NPY_MAGIC:
        return _read_npy(path, nonfinite)
    raise DataFormatError(path, "not a NumPy file (it starts with neither the .npy magic nor a zip signature)")


def read(path: str | PathLike[str], *, nonfinite: NonFinitePolicy = "drop") -> Scene:
    """Read a ``.npy`` point array or a ``.npz`` archive (a whole scene when lidarfuzz wrote it)."""
    scene, _ = _read(Path(path), nonfinite)
    return scene


def read_points(path: str | PathLike[str], *, nonfinite: NonFinitePolicy = "drop") -> tuple[PointCloud, int]:
    """Read the cloud; returns it and the number of points dropped for NaN/Inf coordinates."""
    scene, dropped = _read(Path(path), nonfinite)
    return scene.points, dropped


def write(path: str | PathLike[str], scene: Scene, *, overwrite: bool = False) -> Path:
    """Write ``.npy`` (the points, one float32 field per channel) or ``.npz`` (the whole scene).

    Raises:
        ValueError: The suffix is neither ``.npy`` nor ``.npz``, or (``.npz``) the
            metadata is not JSON-able.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in SUFFIXES:
        raise ValueError(f"{path}: suffix must be .npy or .npz, got {path.suffix!r}")
    arrays = scene_arrays(scene) if suffix == ".npz" else None
    with atomic_path(path, overwrite=overwrite) as tmp:
        if arrays is None:
            _write_npy(tmp, scene.points)
        else:
            with open(tmp, "wb") as handle:  # a file object: np.savez appends '.npz' to bare names
                np.savez(handle, allow_pickle=False, **arrays)
    return path
