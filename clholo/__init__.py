"""clholo: wave-optics holograms from multiplane images, on any OpenCL device."""

from .scene import MPI, Optics  # noqa: F401

__version__ = "0.1.0"
