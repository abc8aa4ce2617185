"""Data-set options: what a user tells lidarfuzz about data it cannot see for itself.

A :class:`DatasetOptions` travels with a data set — given on the command line, stored with a
registered data set (the store's ``datasets.options`` column) and honoured by
:func:`~lidarfuzz.io.open.open_dataset` wherever the data set is opened again (campaign workers,
reports, the web app):

* ``layout``: the point layout of headerless scans (:mod:`lidarfuzz.io.layouts`);
* ``allow_unlabelled``: a campaign may run on a labelled data set some of whose frames have no
  labels; AP is then scored on the labelled frames only;
* ``intensity_scale``: the intensity reading of the strongest return (1.0 or 255.0), when the
  layout's is wrong for this data;
* ``modality``: ``lidar`` (the default) reads point clouds, ``camera`` the images of the same
  source (a KITTI folder's ``image_2/``) or of a camera data set (:mod:`lidarfuzz.io.images`), and
  ``camera`` which of its cameras (``image_3``; Udacity's ``left``);
* ``roi_map``: a GeoJSON drivable-area map for the whole data set, used for every frame that has
  no map of its own (``roi/<id>.json``). Its polygons are in the LiDAR frame (the same for every
  frame), or — with ``"frame": "world"`` at the top level or in its ``properties`` — in the
  world frame of a log with poses, moved into each frame's LiDAR frame by the frame's pose. Or the
  word ``estimate``: every frame without a map gets the drivable region estimated from its own
  points (:func:`lidarfuzz.scene.drivable.with_estimated_roi`, ``roi_source: estimated``), so the
  system under test and every mutant of the frame see the same region, as Apollo's ROI filter sees
  the same HD map — what Zhou & Sun's MR1 (``outside_roi_scatter``) needs on data without a map.

Example:
    >>> DatasetOptions(layout="nuscenes").stored()
    {'layout': 'nuscenes'}
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass
from os import PathLike
from pathlib import Path
from typing import Any, Literal

import numpy as np
import shapely
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator
from shapely.errors import ShapelyError  # type: ignore[import-untyped]
from shapely.geometry import MultiPolygon, Polygon, shape

from lidarfuzz.errors import DataFormatError, LidarfuzzError
from lidarfuzz.io.guards import describe, reading
from lidarfuzz.io.layouts import LayoutError, PointLayout, parse_layout
from lidarfuzz.io.textfiles import check_json_depth, read_text
from lidarfuzz.scene.roi import RoiMap
from lidarfuzz.scene.scene import Scene

MapFrame = Literal["lidar", "world"]
#: ``roi_map`` value asking for the drivable region estimated from each frame's points.
ESTIMATE_MAP = "estimate"


class DatasetOptions(BaseModel):
    """How to read a data set (see the module docstring)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    layout: str | None = Field(default=None, description="point layout: a name (kitti, nuscenes, …) or a "
                                                          "column spec such as x,y,z,intensity,ring:f4")
    allow_unlabelled: bool = Field(default=False, description="campaigns may run on frames without labels "
                                                              "(AP from the labelled frames only)")
    intensity_scale: float | None = Field(default=None, gt=0, description="intensity of the strongest return "
                                                                           "(1 or 255), overriding the layout's")
    roi_map: str | None = Field(default=None, description="GeoJSON drivable-area map for every frame without "
                                                          "its own, or 'estimate' for the region estimated from "
                                                          "each frame's points")
    modality: Literal["lidar", "camera"] = Field(
        default="lidar", description="which sensor's frames to read: point clouds, or the camera's images "
                                     "(lidarfuzz.io.images: a KITTI folder's image_2/, Udacity, images + CSV, bags)")
    camera: str | None = Field(default=None, description="camera modality: which camera of the source (image_2 or "
                                                         "image_3 of a KITTI folder; center, left or right of a "
                                                         "Udacity one); the source's default when not given")

    @field_validator("layout")
    @classmethod
    def _layout(cls, value: str | None) -> str | None:
        if value is None or not value.strip():
            return None
        parse_layout(value)  # a LayoutError (a ValueError) names the bad part
        return value.strip()

    def point_layout(self) -> PointLayout | None:
        """The parsed layout, or ``None`` to decide from the data's structure."""
        return parse_layout(self.layout) if self.layout else None

    def resolved(self) -> DatasetOptions:
        """The same options with ``roi_map`` an absolute path (what the store keeps)."""
        if self.roi_map is None or self.estimates_map:
            return self
        return self.model_copy(update={"roi_map": str(Path(self.roi_map).expanduser().resolve())})

    def stored(self) -> dict[str, Any]:
        """The JSON the store keeps: only what differs from the defaults."""
        return self.model_dump(exclude_defaults=True)

    @classmethod
    def from_stored(cls, data: Mapping[str, Any] | None) -> DatasetOptions:
        """Options from the store's JSON (``None`` or ``{}``: the defaults)."""
        try:
            return cls.model_validate(dict(data or {}))
        except (ValidationError, LayoutError) as exc:
            raise LidarfuzzError(f"the stored data-set options {dict(data or {})} are not valid: {exc}") from None

    @property
    def estimates_map(self) -> bool:
        """Whether frames without a map get the region estimated from their points."""
        return self.roi_map == ESTIMATE_MAP

    def dataset_map(self) -> DatasetMap | None:
        """The data-set ROI map, read and checked (``None`` when there is none or it is estimated)."""
        return load_dataset_map(self.roi_map) if self.roi_map and not self.estimates_map else None


def options_from_flags(layout: str | None = None, allow_unlabelled: bool = False,
                       intensity_scale: float | None = None, roi_map: str | PathLike[str] | None = None
                       ) -> DatasetOptions:
    """Options from command-line flags, a bad value named as its flag in one line."""
    try:
        return DatasetOptions(layout=layout, allow_unlabelled=allow_unlabelled, intensity_scale=intensity_scale,
                              roi_map=str(roi_map) if roi_map is not None else None).resolved()
    except ValidationError as exc:
        first = exc.errors()[0]
        flag = "--" + str(first["loc"][0]).replace("_", "-") if first["loc"] else "options"
        message = str(first.get("ctx", {}).get("error", first["msg"]))
        raise LidarfuzzError(message if message.startswith(flag) else f"{flag}: {message}") from None


@dataclass(frozen=True)
class DatasetMap:
    """A drivable-area map given for a whole data set."""

    path: Path
    roi: RoiMap
    frame: MapFrame = "lidar"

    def for_scene(self, scene: Scene) -> RoiMap:
        """The map in ``scene``'s LiDAR frame (moved by the inverse of its pose for a world map)."""
        if self.frame == "lidar":
            return self.roi
        if scene.pose is None:
            raise DataFormatError(self.path, f"the map is in the world frame but frame {scene.frame_id!r} has no "
                                  "pose (poses.txt)", field="frame",
                                  hint="give the polygons in the LiDAR frame, or a log with poses")
        return self.roi.transformed(np.linalg.inv(np.asarray(scene.pose, dtype=np.float64)))


def _polygons(obj: Any, where: str, path: Path) -> list[Polygon]:
    if not isinstance(obj, dict):
        raise DataFormatError(path, "expected a GeoJSON object", field=where or "<root>")
    kind = obj.get("type")
    prefix = f"{where}." if where else ""
    if kind == "FeatureCollection":
        features = obj.get("features")
        if not isinstance(features, list):
            raise DataFormatError(path, "a FeatureCollection needs a list of features", field=f"{prefix}features")
        return [p for i, f in enumerate(features) for p in _polygons(f, f"{prefix}features.{i}", path)]
    if kind == "Feature":
        return _polygons(obj.get("geometry"), f"{prefix}geometry", path)
    if kind not in ("Polygon", "MultiPolygon"):
        raise DataFormatError(path, f"type {kind!r} is not a Polygon, MultiPolygon, Feature or FeatureCollection",
                              field=f"{prefix}type")
    try:
        geometry = shape(obj)
    except (ShapelyError, ValueError, TypeError, IndexError, KeyError, AttributeError, OverflowError) as exc:
        # OverflowError: an integer too large for a float (300 digits of JSON)
        raise DataFormatError(path, f"not a valid {kind}: {describe(exc)}", field=f"{prefix}coordinates") from None
    if not np.all(np.isfinite(np.asarray(shapely.get_coordinates(geometry)))):
        raise DataFormatError(path, "coordinates must be finite numbers", field=f"{prefix}coordinates")
    return [geometry] if isinstance(geometry, Polygon) else list(geometry.geoms)


def load_dataset_map(path: str | PathLike[str]) -> DatasetMap:
    """Read a data-set ROI map (see the module docstring).

    Raises:
        DataFormatError: An unreadable file, invalid JSON (with its line), or a field that is not
            what a drivable-area map needs — one line naming the file and the field.
    """
    path = Path(path)
    text = read_text(path, "a GeoJSON drivable-area map")
    check_json_depth(text, path)
    with reading(path, "read the ROI map"):  # numbers Python cannot convert (over 4,300 digits)
        try:
            obj = json.loads(text)
        except json.JSONDecodeError as exc:
            raise DataFormatError(path, f"not valid JSON: {exc.msg}", line=exc.lineno) from None
    if not isinstance(obj, dict):
        raise DataFormatError(path, "expected a GeoJSON object", field="<root>")
    given = obj.get("properties")
    properties = given if isinstance(given, dict) else {}
    frame = obj.get("frame", properties.get("frame", "lidar"))
    if frame not in ("lidar", "world"):
        raise DataFormatError(path, f"{frame!r} is not 'lidar' or 'world'",
                              field="frame" if "frame" in obj else "properties.frame")
    polygons = _polygons(obj, "", path)
    if not polygons:
        raise DataFormatError(path, "no polygons: a drivable-area map needs at least one", field="features")
    with reading(path, "join the map's polygons", hint="check that the polygons' rings do not cross themselves"):
        union = shapely.union_all(polygons)
    parts = list(union.geoms) if hasattr(union, "geoms") else [union]
    geometry = MultiPolygon([g for g in parts if isinstance(g, Polygon) and not g.is_empty])
    return DatasetMap(path, RoiMap(geometry), frame)


__all__ = ["DatasetMap", "DatasetOptions", "load_dataset_map", "options_from_flags"]
