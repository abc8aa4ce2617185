"""Built-in camera operators: DeepTest's nine image transformations on :class:`~lidarfuzz.scene.image.ImageSample`
(registered through the ``lidarfuzz.operators`` entry points, ``modality = "camera"``).

* :mod:`~lidarfuzz.operators.camera.photometric` — brightness, contrast;
* :mod:`~lidarfuzz.operators.camera.affine` — translation, scale, shear, rotation (Table 2's matrices);
* :mod:`~lidarfuzz.operators.camera.convolutional` — blur (averaging, Gaussian, median, bilateral);
* :mod:`~lidarfuzz.operators.camera.weather` — fog (Koschmieder's law) and rain (streaks).

Severities 1–5 follow DeepTest's Table 4: each transformation has ten parameter values there, and
severity ``s`` covers the (2s−1)-th and 2s-th of them, ordered from mildest to strongest.
"""
