"""The ``lidarfuzz`` command line (Typer). Commands are thin: they call the library."""
