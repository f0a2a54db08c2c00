"""clholo: wave-optics holograms from multiplane images, on any OpenCL device."""

from .scene import MPI, Optics  # noqa: F401
from . import io  # noqa: F401  (readers import OpenImageIO lazily)
from .propagation import propagate  # noqa: F401
from .hologram import (  # noqa: F401
    HologramRenderer,
    focal_stack,
    hologram_padded_shape,
    iter_hologram_frames,
    render_hologram,
)

__version__ = "0.1.0"
