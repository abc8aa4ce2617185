"""PCD, the Point Cloud Library's format: a text header, then ascii, binary or binary_compressed data.

The header (plain text lines up to ``DATA``) is parsed and validated here, so that a
malformed or lying header is reported with the file, line and field instead of a
traceback; the binary encodings are then decoded by :mod:`pypcd4`. ASCII data is
parsed with numpy, which (unlike pypcd4) accepts any run of spaces or tabs between
values.

Reading:

* every field becomes a float32 channel, named through the shared aliases
  (``reflectance`` → ``intensity``, ``t`` → ``time``, ...); integer fields wider than
  24 bits and ``F8`` fields are rounded to float32;
* a field with ``COUNT`` k > 1 becomes channels ``name_0`` … ``name_{k-1}``;
  padding fields named ``_`` are skipped; a header may claim at most 65,536 values per
  point in all, and binary_compressed data at most LZF's 88:1 of its compressed size;
* PCL's packed colour (a 4-byte ``rgb``/``rgba`` field) becomes ``red, green, blue``
  (and ``alpha`` for ``rgba``) channels of 0…255 — as a float it is often NaN;
* an organised cloud (``HEIGHT`` > 1) is flattened row by row;
* a non-identity ``VIEWPOINT`` is kept in ``metadata["viewpoint"]``.

Writing stores every channel as an ``F4`` field named after the channel, so
lidarfuzz's own files round-trip bit-exactly in all three encodings (ASCII values are
written with 9 significant digits, which identify a float32 exactly). A channel whose
name is an alias of an absent standard channel (e.g. ``beam`` without ``ring``) reads
back as that channel, and names are lower-cased on reading.
"""

from __future__ import annotations

import io
import struct
from dataclasses import dataclass
from os import PathLike
from pathlib import Path
from typing import Any, Literal

import lzf  # type: ignore[import-not-found]  # pypcd4's own LZF binding (a dependency of pypcd4)
import numpy as np
import pypcd4
from numpy.typing import NDArray

from lidarfuzz.errors import DataFormatError
from lidarfuzz.io.atomic import atomic_path
from lidarfuzz.io.common import NonFinitePolicy, cloud_from_columns, finish_cloud, map_field_names
from lidarfuzz.io.guards import reading, require_bytes
from lidarfuzz.scene.points import STANDARD_CHANNELS, PointCloud
from lidarfuzz.scene.scene import Scene

SUFFIXES = (".pcd",)

PcdEncoding = Literal["ascii", "binary", "binary_compressed"]
ENCODINGS: tuple[str, ...] = ("ascii", "binary", "binary_compressed")

HEADER_KEYS = ("VERSION", "FIELDS", "SIZE", "TYPE", "COUNT", "WIDTH", "HEIGHT", "VIEWPOINT", "POINTS", "DATA")
REQUIRED_KEYS = ("FIELDS", "SIZE", "TYPE", "WIDTH", "HEIGHT", "POINTS", "DATA")
#: (TYPE, SIZE) pairs a PCD field may have.
FIELD_TYPES: dict[tuple[str, int], type[np.generic]] = {
    ("F", 4): np.float32,
    ("F", 8): np.float64,
    ("I", 1): np.int8,
    ("I", 2): np.int16,
    ("I", 4): np.int32,
    ("I", 8): np.int64,
    ("U", 1): np.uint8,
    ("U", 2): np.uint16,
    ("U", 4): np.uint32,
    ("U", 8): np.uint64,
}
DEFAULT_VIEWPOINT: tuple[float, ...] = (0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0)
PADDING_FIELD = "_"
#: Fields holding PCL's packed 0xAARRGGBB colour, read as ``red, green, blue`` (and ``alpha``).
PACKED_COLOUR = ("rgb", "rgba")
_MAX_HEADER_LINE = 65536
#: Values per point (the sum of COUNT) a header may claim: PCL's widest descriptor (SHOT colour)
#: has 1,344; a claim of 10⁶ took minutes to lay out and 10¹² exhausted memory.
MAX_VALUES_PER_POINT = 65536
#: LZF's densest packing: a 3-byte back-reference copies at most 264 bytes (88:1).
_MAX_LZF_RATIO = 88


@dataclass(frozen=True)
class PcdHeader:
    """A validated PCD header.

    Attributes:
        fields: Field names in file order (padding fields are ``_``).
        sizes: Bytes per value of each field.
        types: ``F``, ``I`` or ``U`` for each field.
        counts: Values per point of each field.
        width: ``WIDTH`` (points per row).
        height: ``HEIGHT`` (rows; 1 for unorganised clouds).
        points: ``POINTS``, always ``width * height``.
        encoding: ``ascii``, ``binary`` or ``binary_compressed``.
        viewpoint: Sensor pose ``tx ty tz qw qx qy qz``.
        data_offset: Byte offset of the data section.
        header_lines: Number of lines up to and including ``DATA``.
    """

    fields: tuple[str, ...]
    sizes: tuple[int, ...]
    types: tuple[str, ...]
    counts: tuple[int, ...]
    width: int
    height: int
    points: int
    encoding: str
    viewpoint: tuple[float, ...]
    data_offset: int
    header_lines: int

    @property
    def point_size(self) -> int:
        """Bytes per point in the binary encodings."""
        return sum(size * count for size, count in zip(self.sizes, self.counts, strict=True))


def parse_header(data: bytes, path: str | PathLike[str] = "<pcd>") -> PcdHeader:
    """Parse and validate the header at the start of a PCD file's bytes.

    Raises:
        DataFormatError: A key is missing, repeated, unknown or malformed, a field type
            is not one PCD allows, or ``POINTS`` differs from ``WIDTH × HEIGHT``.
    """
    found: dict[str, tuple[int, list[str]]] = {}
    pos = 0
    lineno = 0
    while "DATA" not in found:
        if pos >= len(data):
            if not found:
                raise DataFormatError(path, "empty file; expected a PCD header")
            raise DataFormatError(path, "header ends without a DATA line", line=lineno)
        end = data.find(b"\n", pos, pos + _MAX_HEADER_LINE)
        if end < 0:
            end = len(data) if len(data) - pos <= _MAX_HEADER_LINE else -1
        if end < 0:
            raise DataFormatError(path, "header line too long; not a PCD file", line=lineno + 1)
        raw = data[pos:end]
        pos = end + 1
        lineno += 1
        try:
            line = raw.decode("ascii").strip()
        except UnicodeDecodeError:
            raise DataFormatError(path, "header line is not text; not a PCD file", line=lineno) from None
        if not line or line.startswith("#"):
            continue
        key, *tokens = line.split()
        upper = key.upper()
        if upper not in HEADER_KEYS:
            raise DataFormatError(
                path,
                f"unknown header key {key!r}; a PCD header has lines {', '.join(HEADER_KEYS)}",
                line=lineno,
            )
        if upper in found:
            raise DataFormatError(path, f"header key {upper} appears twice", line=lineno)
        found[upper] = (lineno, tokens)

    missing = [key for key in REQUIRED_KEYS if key not in found]
    if missing:
        raise DataFormatError(
            path, f"header lacks {', '.join(missing)}", hint=f"a PCD header needs {', '.join(REQUIRED_KEYS)}"
        )

    def integers(key: str, minimum: int) -> tuple[int, ...]:
        line, tokens = found[key]
        try:
            values = tuple(int(token) for token in tokens)
        except ValueError:
            raise DataFormatError(path, f"{key} values must be integers, got {' '.join(tokens)!r}", line=line) from None
        if any(v < minimum for v in values):
            raise DataFormatError(path, f"{key} values must be ≥ {minimum}, got {' '.join(tokens)!r}", line=line)
        return values

    def scalar(key: str) -> int:
        values = integers(key, 0)
        if len(values) != 1:
            raise DataFormatError(path, f"{key} needs exactly one value, got {len(values)}", line=found[key][0])
        return values[0]

    fields = tuple(found["FIELDS"][1])
    if not fields:
        raise DataFormatError(path, "FIELDS names no field", line=found["FIELDS"][0])
    sizes = integers("SIZE", 1)
    types = tuple(t.upper() for t in found["TYPE"][1])
    counts = integers("COUNT", 1) if "COUNT" in found else (1,) * len(fields)
    for key, values in (("SIZE", sizes), ("TYPE", types), ("COUNT", counts)):
        if len(values) != len(fields):
            raise DataFormatError(
                path,
                f"{key} lists {len(values)} values but FIELDS names {len(fields)} fields",
                line=found[key][0],
            )
    if sum(counts) > MAX_VALUES_PER_POINT:
        raise DataFormatError(path, f"COUNT claims {sum(counts):,} values per point; lidarfuzz reads at most "
                              f"{MAX_VALUES_PER_POINT:,}", line=found["COUNT"][0], field="COUNT")
    named = [f for f in fields if f != PADDING_FIELD]
    for name in named:
        if named.count(name) > 1:
            raise DataFormatError(path, "field name appears twice in FIELDS", line=found["FIELDS"][0], field=name)
    for name, kind, size in zip(fields, types, sizes, strict=True):
        if (kind, size) not in FIELD_TYPES:
            raise DataFormatError(
                path,
                f"unsupported field type {kind}{size} for field {name!r}; "
                "PCD allows F4, F8, I1, I2, I4, I8, U1, U2, U4, U8",
                line=found["TYPE"][0],
                field=name,
            )

    width, height, points = scalar("WIDTH"), scalar("HEIGHT"), scalar("POINTS")
    if points != width * height:
        raise DataFormatError(
            path,
            f"header claims {points} points (POINTS) but WIDTH×HEIGHT is {width}×{height} = {width * height}",
            line=found["POINTS"][0],
        )

    viewpoint: tuple[float, ...] = DEFAULT_VIEWPOINT
    if "VIEWPOINT" in found:
        key_line, tokens = found["VIEWPOINT"]
        try:
            viewpoint = tuple(float(t) for t in tokens)
        except ValueError:
            viewpoint = ()
        if len(viewpoint) != 7:
            raise DataFormatError(
                path, f"VIEWPOINT needs 7 numbers (tx ty tz qw qx qy qz), got {' '.join(tokens)!r}", line=key_line
            )

    key_line, tokens = found["DATA"]
    encoding = tokens[0].lower() if len(tokens) == 1 else " ".join(tokens)
    if encoding not in ENCODINGS:
        raise DataFormatError(
            path,
            f"unknown DATA encoding {encoding!r}; expected ascii, binary or binary_compressed",
            line=key_line,
        )
    return PcdHeader(
        fields=fields,
        sizes=sizes,
        types=types,
        counts=counts,
        width=width,
        height=height,
        points=points,
        encoding=encoding,
        viewpoint=viewpoint,
        data_offset=min(pos, len(data)),
        header_lines=lineno,
    )


def _column_names(header: PcdHeader) -> list[tuple[int, int, str]]:
    """``(field index, element, channel source name)`` for every non-padding value of a point."""
    out = []
    for index, (name, count) in enumerate(zip(header.fields, header.counts, strict=True)):
        if name == PADDING_FIELD:
            continue
        if count == 1:
            out.append((index, 0, name))
        else:
            out.extend((index, k, f"{name}_{k}") for k in range(count))
    return out


def _record_dtype(header: PcdHeader) -> np.dtype[np.void]:
    """Little-endian record layout of one point, fields named as pypcd4 names them by position."""
    names, formats, offsets = [], [], []
    offset = 0
    for index, (kind, size, count) in enumerate(zip(header.types, header.sizes, header.counts, strict=True)):
        code = "<" + {"F": "f", "I": "i", "U": "u"}[kind] + str(size)
        for element in range(count):
            names.append(f"f{index}" if count == 1 else f"f{index}__{element:04d}")
            formats.append(code)
            offsets.append(offset)
            offset += size
    return np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": header.point_size})


def _decode_binary(data: bytes, header: PcdHeader, path: Path) -> NDArray[np.void]:
    """Check the data section's length against the header, then decode it (binary_compressed by pypcd4)."""
    body = memoryview(data)[header.data_offset :]
    need = header.points * header.point_size
    if header.encoding == "binary":
        if len(body) < need:
            raise DataFormatError(
                path,
                f"header claims {header.points} points ({need} bytes at {header.point_size} bytes per point) "
                f"but the binary data section holds {len(body)} bytes "
                f"({len(body) // header.point_size} points)",
                hint="the file is truncated or its POINTS/WIDTH/HEIGHT are wrong",
            )
        # Uncompressed binary is a packed array of records: view it in place (no decode, no copy).
        return np.frombuffer(body, dtype=_record_dtype(header), count=header.points)
    else:
        if len(body) < 8:
            raise DataFormatError(
                path,
                f"header claims {header.points} points but the binary_compressed data section holds "
                f"{len(body)} bytes (it must start with two 4-byte sizes)",
                hint="the file is truncated",
            )
        compressed_size, uncompressed_size = struct.unpack("<II", body[:8])
        if uncompressed_size != need:
            raise DataFormatError(
                path,
                f"header claims {header.points} points ({need} bytes at {header.point_size} bytes per point) "
                f"but the compressed data holds {uncompressed_size} bytes "
                f"({uncompressed_size / header.point_size:g} points)",
            )
        if compressed_size > len(body) - 8:
            raise DataFormatError(
                path,
                f"compressed data block claims {compressed_size} bytes but only {len(body) - 8} follow the header",
                hint="the file is truncated",
            )
        # checked before pypcd4 allocates the decompressed block
        require_bytes(path, uncompressed_size, _MAX_LZF_RATIO * compressed_size + 8, field="POINTS",
                      what="decompressed data (LZF packs at most 88:1)")
    # pypcd4 gets a canonical header: it reads at most 10 header lines, needs COUNT and
    # randomises padding names, none of which matters once fields are named by position.
    canonical = (
        "VERSION 0.7\n"
        f"FIELDS {' '.join(f'f{i}' for i in range(len(header.fields)))}\n"
        f"SIZE {' '.join(map(str, header.sizes))}\n"
        f"TYPE {' '.join(header.types)}\n"
        f"COUNT {' '.join(map(str, header.counts))}\n"
        f"WIDTH {header.points}\nHEIGHT 1\nPOINTS {header.points}\nDATA {header.encoding}\n"
    ).encode("ascii")
    try:
        cloud = pypcd4.PointCloud.from_fileobj(io.BytesIO(b"".join((canonical, body))))  # type: ignore[arg-type]
    except Exception as exc:  # pypcd4/lzf raise ValueError, RuntimeError, struct.error...
        raise DataFormatError(path, f"cannot decode the {header.encoding} data: {exc}") from exc
    records: NDArray[np.void] = cloud.pc_data
    if records.shape != (header.points,):
        raise DataFormatError(path, f"header claims {header.points} points but the data holds {records.shape[0]}")
    return records


def _decode_ascii(data: bytes, header: PcdHeader, path: Path) -> NDArray[np.float64]:
    """Parse the ASCII data section into a points × values float64 array."""
    width = sum(header.counts)
    raw_lines = data[header.data_offset :].split(b"\n")
    lines = [(i, line) for i, line in enumerate(raw_lines) if line.strip()]
    if len(lines) != header.points:
        raise DataFormatError(
            path,
            f"header claims {header.points} points but the ascii data holds {len(lines)} lines",
            hint="the file is truncated or its POINTS/WIDTH/HEIGHT are wrong",
        )
    if not lines:
        return np.zeros((0, width), np.float64)
    for i, line in lines:
        if len(line.split()) != width:
            raise DataFormatError(
                path,
                f"expected {width} values (one per field element), found {len(line.split())}",
                line=header.header_lines + i + 1,
            )
    try:
        text = [line.decode("ascii") for _, line in lines]
        values = np.loadtxt(text, dtype=np.float64, ndmin=2, comments=None)
    except (UnicodeDecodeError, ValueError) as exc:
        raise DataFormatError(path, f"cannot parse the ascii data: {exc}") from exc
    return values


def _unpack_colour(values: NDArray[np.generic], with_alpha: bool) -> dict[str, NDArray[np.generic]]:
    """Split PCL's packed ``0xAARRGGBB`` colour into channels.

    Binary ``F4`` colours are reinterpreted bit for bit (opaque colours are NaN as
    floats). PCL writes them in ASCII as the unsigned integer, so integral ASCII values
    are taken as that integer and others as the float's text.
    """
    array: NDArray[Any] = np.asarray(values)
    bits: NDArray[np.uint32]
    if array.dtype == np.float64:  # ASCII
        integral = np.isfinite(array) & (array == np.round(array)) & (array >= 0) & (array < 2**32)
        bits = array.astype(np.uint32) if integral.all() else array.astype(np.float32).view(np.uint32)
    elif array.dtype == np.float32:
        bits = np.ascontiguousarray(array).view(np.uint32)
    else:
        bits = array.astype(np.uint32)
    parts: dict[str, NDArray[np.generic]] = {
        "red": (bits >> 16) & 0xFF,
        "green": (bits >> 8) & 0xFF,
        "blue": bits & 0xFF,
    }
    if with_alpha:
        parts["alpha"] = bits >> 24
    return parts


def _read_packed_float32(
    data: bytes, header: PcdHeader, path: Path, nonfinite: NonFinitePolicy
) -> tuple[PointCloud, int] | None:
    """Fast path for the common layout (binary, every field a named scalar F4): the data section
    is then an N×C float32 matrix, taken as a view and reordered into channel order in one copy."""
    if (
        header.encoding != "binary"
        or header.points == 0
        or any(t != "F" for t in header.types)
        or any(s != 4 for s in header.sizes)
        or any(c != 1 for c in header.counts)
        or any(f == PADDING_FIELD or f.lower() in PACKED_COLOUR for f in header.fields)
        or len(set(header.fields)) != len(header.fields)
    ):
        return None
    _decode_binary(data, header, path)  # validates the data length
    width = len(header.fields)
    matrix = np.frombuffer(data, dtype="<f4", count=header.points * width, offset=header.data_offset)
    matrix = matrix.reshape(header.points, width)
    mapping = map_field_names(list(header.fields))
    channels = [mapping[f] for f in header.fields]
    for axis in ("x", "y", "z"):
        if axis not in channels:
            raise DataFormatError(path, f"no '{axis}' field; found fields {list(header.fields)}")
    if "intensity" not in channels:
        return None  # the general path fills a zero intensity
    names = [*STANDARD_CHANNELS, *(c for c in channels if c not in STANDARD_CHANNELS)]
    order = [channels.index(c) for c in names]
    columns = matrix if order == list(range(width)) else matrix[:, order]
    return finish_cloud(np.ascontiguousarray(columns), names, path, nonfinite=nonfinite)


def _read(path: Path, nonfinite: NonFinitePolicy) -> tuple[PointCloud, int, PcdHeader]:
    with reading(path, "read the PCD file"):
        return _read_checked(path, nonfinite)


def _read_checked(path: Path, nonfinite: NonFinitePolicy) -> tuple[PointCloud, int, PcdHeader]:
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise DataFormatError(path, "file not found") from None
    except OSError as exc:
        raise DataFormatError(path, f"cannot read: {exc.strerror}") from None
    header = parse_header(data, path)
    fast = _read_packed_float32(data, header, path, nonfinite)
    if fast is not None:
        return (*fast, header)
    wanted = _column_names(header)
    names = [name for _, _, name in wanted]
    for name in names:
        if names.count(name) > 1:
            raise DataFormatError(path, "two fields give the same name (an element of an array field?)", field=name)
    raw: list[tuple[int, str, NDArray[np.generic]]] = []
    if header.points == 0:
        raw = [(index, name, np.zeros(0, np.float32)) for index, _, name in wanted]
    elif header.encoding == "ascii":
        values = _decode_ascii(data, header, path)
        starts = np.cumsum((0, *header.counts))
        raw = [(index, name, values[:, starts[index] + element]) for index, element, name in wanted]
    else:
        records = _decode_binary(data, header, path)
        for index, element, name in wanted:
            key = f"f{index}" if header.counts[index] == 1 else f"f{index}__{element:04d}"
            raw.append((index, name, records[key]))
    sources: dict[str, NDArray[np.generic]] = {}
    for index, name, column in raw:
        unpack = name.lower() in PACKED_COLOUR and header.sizes[index] == 4 and header.counts[index] == 1
        parts = _unpack_colour(column, name.lower() == "rgba") if unpack else {name: column}
        for part, part_values in parts.items():
            if part in sources:
                raise DataFormatError(path, f"two fields give the channel {part!r}", field=name)
            sources[part] = part_values
    mapping = map_field_names(list(sources))
    columns = {mapping[name]: column for name, column in sources.items()}
    cloud, dropped = cloud_from_columns(columns, path, nonfinite=nonfinite)
    return cloud, dropped, header


def read_points(path: str | PathLike[str], *, nonfinite: NonFinitePolicy = "drop") -> tuple[PointCloud, int]:
    """Read the cloud; returns it and the number of points dropped for NaN/Inf coordinates."""
    cloud, dropped, _ = _read(Path(path), nonfinite)
    return cloud, dropped


def read(path: str | PathLike[str], *, nonfinite: NonFinitePolicy = "drop") -> Scene:
    """Read a PCD file as a scene (points only; ``metadata["encoding"]`` tells the DATA encoding)."""
    cloud, dropped, header = _read(Path(path), nonfinite)
    meta: dict[str, object] = {"source": str(path), "format": "pcd", "encoding": header.encoding}
    if header.viewpoint != DEFAULT_VIEWPOINT:
        meta["viewpoint"] = list(header.viewpoint)
    if dropped:
        meta["dropped_nonfinite"] = dropped
    return Scene(cloud, frame_id=Path(path).stem, metadata=meta)


def write_points(
    path: str | PathLike[str],
    cloud: PointCloud,
    *,
    overwrite: bool = False,
    encoding: PcdEncoding = "binary",
) -> Path:
    """Write every channel as an ``F4`` field named after it.

    Args:
        path: Destination file.
        cloud: The points.
        overwrite: Replace an existing file.
        encoding: ``ascii``, ``binary`` (default) or ``binary_compressed`` (LZF).
    """
    if encoding not in ENCODINGS:
        raise ValueError(f"encoding must be one of {ENCODINGS}, got {encoding!r}")
    if PADDING_FIELD in cloud.channels:
        raise ValueError("a channel named '_' cannot be stored in PCD, where that name marks padding")
    data = np.ascontiguousarray(cloud.data, dtype="<f4")
    pcd = pypcd4.PointCloud.from_points(data, cloud.channels, [np.float32] * len(cloud.channels))
    with atomic_path(path, overwrite=overwrite) as tmp, open(tmp, "wb") as handle:
        if encoding == "binary":
            pcd.save(handle, encoding=pypcd4.Encoding.BINARY)
        elif encoding == "ascii":
            # pypcd4 writes '%.10f', which loses small values; 9 significant digits are exact.
            handle.write(pcd.metadata.compose_header(pypcd4.Encoding.ASCII).encode("ascii"))
            np.savetxt(handle, data, fmt="%.9g")
        else:
            handle.write(pcd.metadata.compose_header(pypcd4.Encoding.BINARY_COMPRESSED).encode("ascii"))
            if len(data):
                # Field-major layout, as PCL writes it. pypcd4 silently falls back to binary
                # when LZF cannot shrink the data; a large enough bound keeps the encoding asked for.
                raw = np.ascontiguousarray(data.T).tobytes()
                packed = lzf.compress(raw, len(raw) + len(raw) // 16 + 64)
                handle.write(struct.pack("<II", len(packed), len(raw)))
                handle.write(packed)
    return Path(path)


def write(
    path: str | PathLike[str],
    scene: Scene,
    *,
    overwrite: bool = False,
    encoding: PcdEncoding = "binary",
) -> Path:
    """Write the scene's points (boxes, calibration and the rest cannot be stored in PCD)."""
    return write_points(path, scene.points, overwrite=overwrite, encoding=encoding)
