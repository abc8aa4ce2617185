"""Built-in LiDAR operators (registered through the ``lidarfuzz.operators`` entry points)."""
