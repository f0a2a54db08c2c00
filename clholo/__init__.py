"""clholo: wave-optics holograms from multiplane images, on any OpenCL device."""

import importlib as _importlib

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

from clholo._version import __version__  # noqa: F401 (re-exported)


def __getattr__(name: str):
    # Public submodules (clholo.fft, clholo.reference, clholo.views, ...) are reachable after a
    # plain ``import clholo`` without importing every one of them (and their optional
    # dependencies) at start-up.
    if name.startswith("_"):
        raise AttributeError(f"module 'clholo' has no attribute {name!r}")
    try:
        return _importlib.import_module(f"{__name__}.{name}")
    except ModuleNotFoundError as exc:
        if exc.name != f"{__name__}.{name}":
            raise  # the submodule exists but one of its own imports is missing: say which
        raise AttributeError(f"module 'clholo' has no attribute {name!r}") from None
