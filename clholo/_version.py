"""clholo's version, in a module of its own so that any module can read it without importing
the package (no import cycle through ``clholo/__init__.py``)."""

__version__ = "0.1.0"
