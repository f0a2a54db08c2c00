"""The bundled demo scene: scikit-image's Middlebury "motorcycle" RGB-D pair as an MPI.

``clholo demo`` renders it (:mod:`clholo.commands.render`); the render folder it writes is
:mod:`clholo.render_folder`'s.
"""

from __future__ import annotations

import numpy as np

from clholo.io.load import MIN_SCENE_PIXELS
from clholo.scene import MPI

__all__ = ["DEMO_NEAR", "DEMO_FAR", "MIN_SCENE_PIXELS", "motorcycle_mpi"]

DEMO_NEAR = 2e-3   # metres behind the hologram plane: "a few millimetres"
DEMO_FAR = 6e-3


def motorcycle_mpi(*, layers: int = 8, near: float = DEMO_NEAR, far: float = DEMO_FAR,
                   scale: float = 1.0) -> MPI:
    """The Middlebury "motorcycle" RGB-D pair of scikit-image as an ``layers``-plane MPI.

    Invalid disparities are filled from their nearest valid neighbours (``rgbd_to_mpi``'s
    documented policy); disparity becomes depth, binned uniformly (hard assignment) over
    ``[near, far]`` metres behind the hologram plane.
    """
    from skimage import data
    from skimage.transform import rescale

    from clholo.io import rgbd_to_mpi, srgb_to_linear

    from clholo import validate

    scale = validate.real_scalar("scale", scale)
    left, _right, disparity = data.stereo_motorcycle()
    smallest = min(left.shape[:2])
    if not scale > 0 or round(smallest * scale) < MIN_SCENE_PIXELS:
        raise ValueError(
            f"scale={scale:g} shrinks the {left.shape[1]}x{left.shape[0]} scene to "
            f"{max(0, round(left.shape[1] * scale))}x{max(0, round(left.shape[0] * scale))} pixels; "
            f"use a scale of at least {MIN_SCENE_PIXELS / smallest:.3g}")
    image = srgb_to_linear(left.astype(np.float32) / 255.0)
    if scale != 1.0:
        image = np.clip(rescale(image, scale, channel_axis=-1, anti_aliasing=True), 0, 1)
        # nearest neighbour keeps invalid (inf) disparities from smearing into valid ones
        disparity = rescale(disparity, scale, order=0, anti_aliasing=False)
    return rgbd_to_mpi(image.astype(np.float32), disparity, layers=layers, near=near, far=far,
                       mode="hard", depth_kind="disparity", invalid="fill", srgb=False)
