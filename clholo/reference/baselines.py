"""NumPy reference of the baselines (:mod:`clholo.baselines`).

The RGB-D layer sum is written as HOLOGRAPHY.md section 7 states it, each layer propagated by
its own depth straight to the hologram plane and the fields summed. The device does the same
(``HologramRenderer(occlusion=False)``: each layer's emission through ``kernels/composite.cl``
with ``-D CLHOLO_NO_OCCLUSION``, then one propagation by its depth, added into the hologram).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

__all__ = ["rgbd_hologram"]


def rgbd_hologram(color: np.ndarray, masks: np.ndarray, depths: Sequence[float], *,
                  wavelengths: Sequence[float], pitch: float, frames: int = 1, seed: int = 0,
                  pad="auto", band_limit: bool = True) -> np.ndarray:
    """RGB-D layer-sum holograms ``[T, C, H, W]`` complex128:
    ``sum_i ASM(sqrt(c_i m_i) exp(1j phi_i), d_i)``.

    Parameters
    ----------
    color : array (L, H, W, C), linear intensity in [0, 1]
    masks : array (L, H, W), the layers' masks (0/1; any alpha gives emission sqrt(c a))
    depths : array (L,), metres behind the hologram plane, nearest first
    wavelengths, pitch : metres
    frames, seed : the MPI method's phase stream (layer i, frame t, colour c)
    pad : per propagation (:func:`clholo.reference.padded_shape`)
    """
    from clholo.reference import core as reference

    color = np.asarray(color, np.float64)
    masks = np.asarray(masks, np.float64)
    L, H, W, C = color.shape
    out = np.zeros((frames, C, H, W), np.complex128)
    for t in range(frames):
        for c, lam in enumerate(wavelengths):
            for i in range(L):
                phi = reference.random_phase((H, W), seed=seed, frame=t, colour=c, layer=i)
                v = np.sqrt(color[i, :, :, c] * masks[i]) * np.exp(1j * phi.astype(np.float64))
                out[t, c] += reference.propagate(v, float(depths[i]), wavelength=lam,
                                                 pitch=pitch, pad=pad, band_limit=band_limit)
    return out
