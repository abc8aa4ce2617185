"""Single-frame point-cloud file formats (one module per format)."""
