"""Scene and hologram file input/output (see the module docstrings)."""
