"""PLY (Stanford polygon format) point clouds, read and written with :mod:`plyfile`.

Only the ``vertex`` element is read; other elements (faces of a mesh) are ignored.
Each scalar vertex property becomes a float32 channel, named through the shared
aliases (``reflectance`` → ``intensity``, ``t`` → ``time``, ...); list properties
cannot be channels and are skipped (their names are kept in
``metadata["skipped_properties"]``). ``double`` and integer properties wider than 24
bits are rounded to float32.

Writing stores one little-endian ``float`` property per channel, named after it
(``text=True`` writes an ASCII PLY with plyfile's 18 significant digits), so
lidarfuzz's own files round-trip bit-exactly. A channel whose name is an alias of an
absent standard channel (e.g. ``beam`` without ``ring``) reads back as that channel,
and names are lower-cased on reading. Text PLY is read and written row by row by
plyfile: fine for small files, slow for full scans.
"""

from __future__ import annotations

from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np
import plyfile  # type: ignore[import-untyped]
from numpy.typing import NDArray

from lidarfuzz.errors import DataFormatError, LidarfuzzError
from lidarfuzz.io.atomic import atomic_path
from lidarfuzz.io.common import NonFinitePolicy, cloud_from_columns, map_field_names
from lidarfuzz.io.guards import describe, file_size, reading
from lidarfuzz.scene.points import PointCloud
from lidarfuzz.scene.scene import Scene

SUFFIXES = (".ply",)
VERTEX = "vertex"


#: Bytes of each PLY scalar type (both spellings).
_TYPE_SIZES = {"char": 1, "uchar": 1, "int8": 1, "uint8": 1, "short": 2, "ushort": 2, "int16": 2, "uint16": 2,
               "int": 4, "uint": 4, "int32": 4, "uint32": 4, "float": 4, "float32": 4, "double": 8, "float64": 8}
_MAX_HEADER = 1 << 16


def _check_counts(path: Path) -> None:
    """Each element's row count against the bytes after the header, before plyfile allocates for
    it: a binary row takes at least its scalar properties' sizes (a list at least its count's),
    a text row at least two characters per property."""
    with open(path, "rb") as handle:
        head = handle.read(_MAX_HEADER)
    end = head.find(b"end_header")
    if end < 0 and len(head) == _MAX_HEADER:  # plyfile would parse a megabyte-long line byte by byte
        raise DataFormatError(path, f"bad PLY header: no end_header within its first {_MAX_HEADER:,} bytes")
    if end < 0:
        return  # plyfile names what is wrong with the header
    remaining = file_size(path) - head.find(b"\n", end) - 1
    text = True
    elements: list[list[Any]] = []  # [name, rows, bytes per row at least]
    for raw in head[:end].decode("ascii", "replace").splitlines():
        words = raw.split()
        if len(words) >= 2 and words[0] == "format":
            text = words[1] == "ascii"
        elif len(words) == 3 and words[0] == "element" and words[2].isdigit():
            elements.append([words[1], int(words[2]), 0])
        elif len(words) >= 3 and words[0] == "property" and elements:
            kind = words[2] if words[1] == "list" else words[1]
            if kind not in _TYPE_SIZES:
                return  # plyfile names the unknown type
            elements[-1][2] += 2 if text else _TYPE_SIZES[kind]
    for name, rows, row in elements:
        row = max(row, 1)
        if rows * row > remaining:
            complete = max(remaining, 0) // row
            raise DataFormatError(path, f"header claims {rows} '{name}' rows but the data holds only "
                                  f"{'at most ' if text else ''}{complete} complete rows", field=f"element {name}",
                                  hint="the file is truncated or corrupt")
        remaining -= rows * row


def _load(path: Path) -> plyfile.PlyData:
    try:
        _check_counts(path)
        with np.errstate(over="ignore", invalid="ignore"):  # 1e308 in a float property becomes inf, silently
            return plyfile.PlyData.read(str(path))
    except FileNotFoundError:
        raise DataFormatError(path, "file not found") from None
    except plyfile.PlyHeaderParseError as exc:
        raise DataFormatError(path, f"bad PLY header: {exc.message}", line=exc.line) from None
    except plyfile.PlyElementParseError as exc:
        element = exc.element.name if exc.element is not None else "?"
        count = exc.element.count if exc.element is not None else "?"
        if exc.message == "early end-of-file":
            message = f"header claims {count} '{element}' rows but the data holds only {exc.row} complete rows"
        else:
            where = f"'{element}' row {exc.row}" + (f", property '{exc.prop.name}'" if exc.prop else "")
            message = f"cannot read {where}: {exc.message}"
        raise DataFormatError(path, message, hint="the file is truncated or corrupt") from None
    except LidarfuzzError:
        raise
    except (MemoryError, RecursionError):
        raise DataFormatError(path, "not a readable PLY file: it claims more memory than this machine has") from None
    except Exception as exc:  # plyfile lets struct/numpy/unicode errors through
        raise DataFormatError(path, f"not a readable PLY file: {describe(exc)}") from exc


def _read(path: Path, nonfinite: NonFinitePolicy) -> tuple[PointCloud, int, list[str], bool]:
    with reading(path, "read the PLY file"):
        return _read_loaded(path, _load(path), nonfinite)


def _read_loaded(path: Path, ply: plyfile.PlyData, nonfinite: NonFinitePolicy) -> tuple[PointCloud, int, list[str],
                                                                                         bool]:
    if VERTEX not in ply:
        elements = [element.name for element in ply.elements]
        raise DataFormatError(path, f"no 'vertex' element; found elements {elements}")
    vertex = ply[VERTEX]
    scalar = [p.name for p in vertex.properties if not isinstance(p, plyfile.PlyListProperty)]
    skipped = [p.name for p in vertex.properties if isinstance(p, plyfile.PlyListProperty)]
    mapping = map_field_names(scalar)
    data = vertex.data
    columns: dict[str, NDArray[np.generic]] = {mapping[name]: data[name] for name in scalar}
    for axis in ("x", "y", "z"):
        if axis not in columns:
            raise DataFormatError(
                path, f"the 'vertex' element has no '{axis}' property; found properties {scalar + skipped}"
            )
    cloud, dropped = cloud_from_columns(columns, path, nonfinite=nonfinite)
    return cloud, dropped, skipped, bool(ply.text)


def read_points(path: str | PathLike[str], *, nonfinite: NonFinitePolicy = "drop") -> tuple[PointCloud, int]:
    """Read the cloud; returns it and the number of points dropped for NaN/Inf coordinates."""
    cloud, dropped, _, _ = _read(Path(path), nonfinite)
    return cloud, dropped


def read(path: str | PathLike[str], *, nonfinite: NonFinitePolicy = "drop") -> Scene:
    """Read a PLY file's vertices as a scene (points only)."""
    cloud, dropped, skipped, text = _read(Path(path), nonfinite)
    meta: dict[str, object] = {
        "source": str(path),
        "format": "ply",
        "encoding": "ascii" if text else "binary",
    }
    if skipped:
        meta["skipped_properties"] = skipped
    if dropped:
        meta["dropped_nonfinite"] = dropped
    return Scene(cloud, frame_id=Path(path).stem, metadata=meta)


def write_points(path: str | PathLike[str], cloud: PointCloud, *, overwrite: bool = False, text: bool = False) -> Path:
    """Write a ``vertex`` element with one float32 property per channel.

    Args:
        path: Destination file.
        cloud: The points.
        overwrite: Replace an existing file.
        text: Write ASCII PLY instead of binary little-endian.
    """
    records = np.empty(len(cloud), dtype=[(name, "<f4") for name in cloud.channels])
    for i, name in enumerate(cloud.channels):
        records[name] = cloud.data[:, i]
    element = plyfile.PlyElement.describe(records, VERTEX)
    ply = plyfile.PlyData([element], text=text, byte_order="<", comments=["written by lidarfuzz"])
    with atomic_path(path, overwrite=overwrite) as tmp, open(tmp, "wb") as handle:
        ply.write(handle)
    return Path(path)


def write(path: str | PathLike[str], scene: Scene, *, overwrite: bool = False, text: bool = False) -> Path:
    """Write the scene's points (boxes, calibration and the rest cannot be stored in PLY)."""
    return write_points(path, scene.points, overwrite=overwrite, text=text)
