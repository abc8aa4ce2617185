"""Object-level operators: ground-truth objects removed, corrupted, moved or inserted.

Every operator here acts on labelled objects (boxes with a geometry; ``DontCare``
regions, whose geometry is NaN, are never chosen). An object's points are the points
inside its box (grown by :data:`BOX_MARGIN`) that lie above the local ground band
(:data:`GROUND_BAND` over the lower of the fitted ground and the box's bottom), plus,
when the cloud has an ``instance`` channel, the box's points labelled with the box's
track id: the ground under a box belongs to the road, not to the object. Params record
the chosen boxes by index *and* track id, and replaying them on another frame is an error.

Occlusion after a move or an insertion is recomputed with a spherical range image
(z-buffer) at the sensor's own angular resolution, estimated from the data around the
object: one row per beam (from the ``ring`` channel, or elevation clusters when there is
none) and the azimuth step between neighbouring returns of a beam. Only the wedge of
azimuth around the object is rasterised. Every neighbourhood (a box, a ground ring, a wedge)
is found through a per-frame index (points bucketed by a square grid and by azimuth, built once
per point cloud and cached while it lives, with the ground fits and object points found on it,
so ``sample`` and ``apply`` share them); the results are exactly those of a scan of all points.
A moved object is judged against where the frame observed it: a grid estimated from a real
scan (no ring channel, per-laser offsets) is coarser than the scan, so only what the move
changes — points it packs into one beam and firing, returns it newly hides or is newly hidden
by — is removed; a zero move changes nothing. The ground under a box is a plane fitted to
the lowest return of each 0.5 m cell in a ring around it, obstacles (cars, walls, the
pavement beyond a kerb) rejected pass by pass. Vacated space (a removed or moved
object's footprint and shadow) can be filled with ground: the object's own rays are
re-cast onto that plane, which gives the density of the real scan pattern without any
tuning.

Intensity: inserted and infilled points take intensities from the frame itself or
from a library normalised to [0, 1] and rescaled to the frame's scale (0–255 when the
frame's maximum exceeds 1), so both conventions work.
"""

from lidarfuzz.operators.lidar.objects.corruptions import (
    ObjectCutout,
    ObjectCutoutConfig,
    ObjectCutoutParams,
    ObjectDensityConfig,
    ObjectDensityLoss,
    ObjectDensityParams,
    ObjectJitter,
    ObjectJitterConfig,
    ObjectJitterParams,
    ObjectRemoval,
    ObjectRemovalConfig,
    ObjectRemovalParams,
)
from lidarfuzz.operators.lidar.objects.insertion import (
    Insertion,
    ObjectInsertion,
    ObjectInsertionConfig,
    ObjectInsertionParams,
    ObjectLibrary,
)
from lidarfuzz.operators.lidar.objects.moves import (
    ObjectMoveParams,
    ObjectRotate,
    ObjectRotateConfig,
    ObjectRotateParams,
    ObjectScale,
    ObjectScaleConfig,
    ObjectScaleParams,
    ObjectTranslate,
    ObjectTranslateConfig,
    ObjectTranslateParams,
)
from lidarfuzz.operators.lidar.objects.support import BOX_MARGIN, DEPTH_MARGIN, GROUND_BAND

__all__ = [
    "BOX_MARGIN",
    "DEPTH_MARGIN",
    "GROUND_BAND",
    "Insertion",
    "ObjectCutout",
    "ObjectCutoutConfig",
    "ObjectCutoutParams",
    "ObjectDensityConfig",
    "ObjectDensityLoss",
    "ObjectDensityParams",
    "ObjectInsertion",
    "ObjectInsertionConfig",
    "ObjectInsertionParams",
    "ObjectJitter",
    "ObjectJitterConfig",
    "ObjectJitterParams",
    "ObjectLibrary",
    "ObjectMoveParams",
    "ObjectRemoval",
    "ObjectRemovalConfig",
    "ObjectRemovalParams",
    "ObjectRotate",
    "ObjectRotateConfig",
    "ObjectRotateParams",
    "ObjectScale",
    "ObjectScaleConfig",
    "ObjectScaleParams",
    "ObjectTranslate",
    "ObjectTranslateConfig",
    "ObjectTranslateParams",
]
