"""lidarfuzz: mutation-based and metamorphic testing of LiDAR perception software."""

from typing import Any


def __getattr__(name: str) -> Any:
    # __version__ is looked up on first use: importlib.metadata and the scan of the installed
    # distributions cost about 0.07 s of CPU, a quarter of `lidarfuzz --help`, which needs no version.
    if name == "__version__":
        from importlib.metadata import PackageNotFoundError, version

        try:
            found = version("lidarfuzz")
        except PackageNotFoundError:  # running from a source tree that is not installed
            found = "0.0.0+unknown"
        globals()["__version__"] = found
        return found
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["__version__"]
