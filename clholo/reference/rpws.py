"""NumPy reference of random-phase wave splatting (``kernels/rpws.cl``, ``host/rpws.py``).

The whole recursion of docs/rpws.md for small scenes: K screen-parallel 2-D Gaussians sorted
nearest first at depths ``d_0 <= d_1 <= ... <= d_{K-1}`` (metres behind the hologram plane),
per frame and colour, back to front::

    u = 0
    for k = K-1 ... 0:
        u <- sqrt(1 - alpha_k) u + sqrt(c_k alpha_k) exp(i phi_k)    (inside k's box only)
        u <- ASM(u, d_k - d_{k-1})        (d_{-1} = 0; a zero step is the identity, skipped)

``phi_k`` is the MPI phase stream (:func:`clholo.reference.random_phase`) with layer = k.
"""

from __future__ import annotations

from typing import Sequence, Tuple

import numpy as np

__all__ = ["rpws_boxes", "rpws_footprint", "rpws_hologram"]


def rpws_boxes(xy: np.ndarray, radius: np.ndarray, shape: Tuple[int, int]) -> np.ndarray:
    """Bounding boxes ``(K, 4)`` int64 ``(x0, y0, x1, y1)`` (end exclusive) on the image.

    The pixels ``x`` (columns, centres at integers) with ``|x - m_x| <= r`` and likewise for
    rows, clipped to ``[0, W) x [0, H)``; an empty box has ``x1 <= x0`` or ``y1 <= y0``.
    """
    H, W = shape
    xy = np.asarray(xy, np.float64).reshape(-1, 2)
    r = np.asarray(radius, np.float64).reshape(-1)
    x0 = np.clip(np.ceil(xy[:, 0] - r), 0, W)
    x1 = np.clip(np.floor(xy[:, 0] + r) + 1, 0, W)
    y0 = np.clip(np.ceil(xy[:, 1] - r), 0, H)
    y1 = np.clip(np.floor(xy[:, 1] + r) + 1, 0, H)
    return np.stack([x0, y0, np.maximum(x1, x0), np.maximum(y1, y0)], 1).astype(np.int64)


def rpws_footprint(xy: Sequence[float], conic: Sequence[float], opacity: float,
                   box: Sequence[int], *, alpha_max: float = 0.99,
                   alpha_min: float = 1.0 / 255.0) -> np.ndarray:
    """Opacity of one Gaussian over its box, float32 ``(y1 - y0, x1 - x0)``.

    ``alpha = min(alpha_max, o exp(-1/2 (a dx^2 + c dy^2) - b dx dy))`` with
    ``(dx, dy) = (m_x - x, m_y - y)``, set to 0 where below ``alpha_min``; float32 arithmetic
    in the kernel's order.
    """
    f32 = np.float32
    x0, y0, x1, y1 = (int(v) for v in box)
    ys, xs = np.mgrid[y0:y1, x0:x1]
    dx = f32(xy[0]) - xs.astype(f32)
    dy = f32(xy[1]) - ys.astype(f32)
    a, b, c = (f32(v) for v in conic)
    power = f32(-0.5) * (a * dx * dx + c * dy * dy) - b * dx * dy
    alpha = np.minimum(f32(alpha_max), f32(opacity) * np.exp(power.astype(f32)))
    return np.where(alpha >= f32(alpha_min), alpha, f32(0)).astype(f32)


def rpws_hologram(xy: np.ndarray, conic: np.ndarray, opacity: np.ndarray, color: np.ndarray,
                  depths: np.ndarray, boxes: np.ndarray, shape: Tuple[int, int], *,
                  wavelengths: Sequence[float], pitch: float, frames: int = 1, seed: int = 0,
                  pad="auto", band_limit: bool = True, alpha_max: float = 0.99,
                  alpha_min: float = 1.0 / 255.0) -> np.ndarray:
    """RPWS holograms ``[T, C, H, W]`` complex128 at the hologram plane (z = 0).

    Parameters
    ----------
    xy : array (K, 2)
        Gaussian centres in pixels ``(x, y)``, nearest primitive first.
    conic : array (K, 3)
        Inverse 2-D covariances ``(a, b, c)`` in px^-2.
    opacity : array (K,)
    color : array (K, C)
        Linear intensity in [0, 1].
    depths : array (K,)
        Metres behind the hologram plane, nondecreasing (nearest first).
    boxes : array (K, 4)
        From :func:`rpws_boxes`.
    shape : (H, W)
    wavelengths : C floats, metres
    pitch : float, metres
    frames, seed : int
    pad : see :func:`clholo.reference.padded_shape`; give the device's ``(Hp, Wp)`` to compare.
    """
    from clholo.reference import core as reference

    H, W = shape
    color = np.asarray(color, np.float64)
    K, C = color.shape
    if len(wavelengths) != C:
        raise ValueError(f"wavelengths has {len(wavelengths)} entries for {C} colour channels")
    steps = reference.layer_steps(depths)
    alphas = [rpws_footprint(xy[k], conic[k], opacity[k], boxes[k], alpha_max=alpha_max,
                             alpha_min=alpha_min).astype(np.float64) for k in range(K)]
    out = np.zeros((frames, C, H, W), np.complex128)
    for t in range(frames):
        for c, lam in enumerate(wavelengths):
            u = np.zeros((H, W), np.complex128)
            for k in range(K - 1, -1, -1):  # back to front
                x0, y0, x1, y1 = (int(v) for v in boxes[k])
                if x1 > x0 and y1 > y0:
                    phi = reference.random_phase((H, W), seed=seed, frame=t, colour=c,
                                                 layer=k)[y0:y1, x0:x1]
                    u[y0:y1, x0:x1] = reference.composite_layer(
                        u[y0:y1, x0:x1], np.float32(color[k, c]), alphas[k], phi)
                if steps[k] != 0.0:
                    u = reference.propagate(u, steps[k], wavelength=lam, pitch=pitch, pad=pad,
                                            band_limit=band_limit)
            out[t, c] = u
    return out
