"""Stereo Magnification output folders (Zhou et al. 2018, google/stereo-magnification).

``mpi_from_images.py`` writes ``mpi_rgb_NN.png`` (straight sRGB colour) and
``mpi_alpha_NN.png`` (linear alpha) for ``NN = 00 .. L-1``, ``00`` the farthest plane. It stores no
depths: the planes are uniform in inverse depth between ``min_depth`` and ``max_depth`` (the
script's defaults: 1 and 100 scene units), and its renderer takes the farthest alpha as 1.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Optional

import numpy as np

from ..scene import MPI, stored_or_placed_depths
from .images import PathLike, grey_channel, read_image
from .mpi_folder import _decode_layers

__all__ = ["read_stereo_mag", "is_stereo_mag_folder", "stereo_mag_depths"]

_RGB = re.compile(r"^mpi_rgb_(\d+)\.png$", re.IGNORECASE)
_ALPHA = re.compile(r"^mpi_alpha_(\d+)\.png$", re.IGNORECASE)


def is_stereo_mag_folder(path: PathLike) -> bool:
    """True when ``path`` is a folder holding at least one ``mpi_rgb_NN.png``."""
    path = Path(path)
    return path.is_dir() and any(_RGB.match(p.name) for p in path.iterdir())


def stereo_mag_depths(layers: int, *, min_depth: float = 1.0,
                      max_depth: float = 100.0) -> np.ndarray:
    """Depths of Stereo Magnification's planes, farthest first: uniform in inverse depth.

    Returns
    -------
    ndarray, shape (layers,)
        ``1 / linspace(1/max_depth, 1/min_depth, layers)`` in scene units.
    """
    from .. import validate

    # a number first: an infinite max_depth gave 1/inf = 0 and a NaN depth that named no
    # argument, and a string compared as no number does
    min_depth = validate.real_scalar("min_depth", min_depth,
                                     fix="the nearest plane in scene units (--min-depth)")
    max_depth = validate.real_scalar("max_depth", max_depth,
                                     fix="the farthest plane in scene units (--max-depth)")
    if not (0 < min_depth < max_depth):
        raise ValueError(f"min_depth must be > 0 and smaller than max_depth (--min-depth, "
                         f"--max-depth: the folder's scene units), got {min_depth:g} and "
                         f"{max_depth:g}")
    return 1.0 / np.linspace(1.0 / max_depth, 1.0 / min_depth, layers)


def read_stereo_mag(path: PathLike, *, min_depth: float = 1.0, max_depth: float = 100.0,
                    near: Optional[float] = None, far: Optional[float] = None,
                    spacing: str = "index") -> MPI:
    """Read a Stereo Magnification folder of ``mpi_rgb_NN.png`` + ``mpi_alpha_NN.png``.

    Parameters
    ----------
    path : path-like
        The folder.
    min_depth, max_depth : float
        The network's plane range in scene units (its defaults 1 and 100).
    near, far : float, optional
        Metres behind the hologram plane; when given the planes are placed there with
        :meth:`MPI.placed` (``spacing``), otherwise depths stay in scene units.
    spacing : {"index", "depth", "inverse"}

    Returns
    -------
    MPI
        Linear colour (sRGB decoded), straight alpha, the farthest alpha set to 1, nearest first.

    Raises
    ------
    FileNotFoundError
        When the folder has no ``mpi_rgb_NN.png``.
    ValueError
        Colour without alpha (or alpha without colour), gaps in the numbering, layers of
        different sizes, an alpha file whose channels differ (one saved as RGB is read when its
        channels are equal); the message names the files.
    """
    path = Path(path)
    if not path.is_dir():
        raise FileNotFoundError(f"Stereo Magnification folder {path} does not exist")
    rgb, alpha = {}, {}
    for p in path.iterdir():
        m = _RGB.match(p.name)
        if m:
            rgb[int(m.group(1))] = p
        m = _ALPHA.match(p.name)
        if m:
            alpha[int(m.group(1))] = p
    if not rgb:
        raise FileNotFoundError(f"{path} holds no mpi_rgb_NN.png files (Stereo Magnification "
                                f"output is mpi_rgb_NN.png + mpi_alpha_NN.png)")
    only_rgb = sorted(set(rgb) - set(alpha))
    only_alpha = sorted(set(alpha) - set(rgb))
    if only_rgb or only_alpha:
        parts = []
        if only_rgb:
            parts.append("no alpha file for " + ", ".join(rgb[i].name for i in only_rgb))
        if only_alpha:
            parts.append("no colour file for " + ", ".join(alpha[i].name for i in only_alpha))
        raise ValueError(f"{path}: {'; '.join(parts)}; every mpi_rgb_NN.png needs its "
                         f"mpi_alpha_NN.png")
    indices = sorted(rgb)
    if indices != list(range(len(indices))):
        missing = sorted(set(range(indices[-1] + 1)) - set(indices))
        raise ValueError(f"{path}: layer numbers must run 00..{len(indices) - 1} without gaps; "
                         f"missing {', '.join(f'{i:02d}' for i in missing)}")
    # placed (or refused) before any layer is read: scene units need near/far to be
    # metres, and a range that cannot be used is said at once, not after the reading
    depths = stereo_mag_depths(len(indices), min_depth=min_depth, max_depth=max_depth)
    placed = stored_or_placed_depths(depths, near, far, spacing=spacing,
                                     source=f"{path} (min_depth {min_depth:g}, max_depth "
                                            f"{max_depth:g})", units="scene units")
    colors, alphas, names, ccodes, acodes = [], [], [], [], []
    for i in indices:
        c, cinfo = read_image(rgb[i], normalise=False)
        a, ainfo = read_image(alpha[i], normalise=False)
        ccodes.append(cinfo["max_code"])
        acodes.append(ainfo["max_code"])
        if c.shape[2] not in (1, 3):
            raise ValueError(f"{rgb[i]} has {c.shape[2]} channels; expected RGB")
        if c.shape[:2] != a.shape[:2]:
            raise ValueError(f"{rgb[i]} is {c.shape[1]}x{c.shape[0]} but {alpha[i]} is "
                             f"{a.shape[1]}x{a.shape[0]}")
        colors.append(c)
        alphas.append(grey_channel(a, alpha[i], "alpha map",
                                   fix="save alpha as a one-channel (grey) PNG"))
        names.append(str(rgb[i]))
    color, alpha_arr = _decode_layers(colors, alphas, names, encoding="srgb",
                                      alpha_mode="straight", color_codes=ccodes,
                                      alpha_codes=acodes)
    alpha_arr[0] = 1.0  # the farthest plane (index 00) is opaque in the source's renderer
    return MPI(color, alpha_arr, placed)
