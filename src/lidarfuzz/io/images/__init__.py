"""Camera data sets: readers that give :class:`~lidarfuzz.scene.image.ImageSample` frames.

========================= ================================================================
layout                    what is read
========================= ================================================================
``udacity``               Udacity challenge 2: ``interpolated.csv`` + ``center/`` ``left/``
                          ``right/``; steering-wheel angle, radians, left positive
``driving_log``           behavioural-cloning recordings: ``driving_log.csv`` (center, left,
                          right, steering, throttle, brake, speed) + ``IMG/``
``csv``                   any CSV with an image column and a steering column
``kitti``                 ``image_2/`` beside ``velodyne/``: ``calib/`` P2 → intrinsics,
                          ``depth_2/`` (uint16, metres × 256), ``steering.csv``
``log``                   ``sensor_msgs/Image`` / ``CompressedImage`` topics of ROS 1 bags,
                          ROS 2 bags and MCAP files; steering from a companion topic
                          (:mod:`~lidarfuzz.io.images.steering`)
========================= ================================================================

Entry point: :func:`open_image_dataset` (also reached through
:func:`lidarfuzz.io.open.open_dataset` with ``modality="camera"``). Images are PNG or JPEG,
decoded by OpenCV after their container is checked complete (:mod:`~lidarfuzz.io.images.decode`).
"""

from lidarfuzz.io.images.decode import MAX_PIXELS, decode_depth, decode_image, decode_raw, image_header
from lidarfuzz.io.images.kitti import KittiImageLog, KittiImages, open_kitti_images
from lidarfuzz.io.images.logs import ImageLog
from lidarfuzz.io.images.open import IMAGE_LAYOUTS, detect_layout, is_image_source, open_image_dataset
from lidarfuzz.io.images.tabular import TableImageLog, TableImages, open_table

__all__ = [
    "IMAGE_LAYOUTS",
    "MAX_PIXELS",
    "ImageLog",
    "KittiImageLog",
    "KittiImages",
    "TableImageLog",
    "TableImages",
    "decode_depth",
    "decode_image",
    "decode_raw",
    "detect_layout",
    "image_header",
    "is_image_source",
    "open_image_dataset",
    "open_kitti_images",
    "open_table",
]
