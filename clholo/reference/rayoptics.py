"""NumPy reference of ``kernels/rayoptics.cl``: warp every MPI layer, "over", mean of views.

Float64, plain loops over views and layers, vectorised over pixels. Pixel centres sit at integer
coordinates; a homography maps an output pixel ``(x, y, 1)`` to the source position
``(x', y', w) / w`` in the layer; bilinear taps outside the layer are transparent (colour 0,
alpha 0).
"""

from __future__ import annotations

import numpy as np

__all__ = ["bilinear_sample", "warp_over_mean"]


def bilinear_sample(image: np.ndarray, sx: np.ndarray, sy: np.ndarray) -> np.ndarray:
    """Sample ``image[H, W, ...]`` at positions ``(sx, sy)`` (arrays of one shape), zero outside.

    Returns an array of shape ``sx.shape + image.shape[2:]``.
    """
    image = np.asarray(image, np.float64)
    H, W = image.shape[:2]
    x0 = np.floor(sx)
    y0 = np.floor(sy)
    tx = sx - x0
    ty = sy - y0
    out = np.zeros(sx.shape + image.shape[2:])
    for dy in (0, 1):
        for dx in (0, 1):
            xi = x0 + dx
            yi = y0 + dy
            ok = (xi >= 0) & (xi < W) & (yi >= 0) & (yi < H)
            wt = (tx if dx else 1 - tx) * (ty if dy else 1 - ty)
            xc = np.where(ok, xi, 0).astype(np.int64)
            yc = np.where(ok, yi, 0).astype(np.int64)
            tap = image[yc, xc]
            wt = np.where(ok, wt, 0.0)
            out += wt.reshape(wt.shape + (1,) * (tap.ndim - wt.ndim)) * tap
    return out


def warp_over_mean(color: np.ndarray, alpha: np.ndarray, homographies: np.ndarray, *,
                   premultiplied: bool = True) -> np.ndarray:
    """Mean over views of the "over" composite of homography-warped layers.

    Parameters
    ----------
    color : ndarray, shape (L, H, W, C)
        Straight colour, layer 0 the nearest.
    alpha : ndarray, shape (L, H, W)
    homographies : ndarray, shape (C, V, L, 3, 3)
        Per channel, view and layer: output pixel ``(x, y, 1)`` -> source ``(x', y', w)``.
    premultiplied : bool
        Interpolate ``c * a`` and ``a`` (True) or ``c`` and ``a`` (False, then multiply).

    Returns
    -------
    ndarray, shape (H, W, C), float64
    """
    color = np.asarray(color, np.float64)
    alpha = np.asarray(alpha, np.float64)
    hom = np.asarray(homographies, np.float64)
    L, H, W, C = color.shape
    _, V = hom.shape[:2]
    ys, xs = np.mgrid[0:H, 0:W].astype(np.float64)
    pts = np.stack([xs, ys, np.ones_like(xs)], axis=-1)  # [H, W, 3]
    out = np.zeros((H, W, C))
    for c in range(C):
        for v in range(V):
            acc = np.zeros((H, W))
            for layer in range(L - 1, -1, -1):  # back to front
                src = pts @ hom[c, v, layer].T
                sx = src[..., 0] / src[..., 2]
                sy = src[..., 1] / src[..., 2]
                a = bilinear_sample(alpha[layer], sx, sy)
                if premultiplied:
                    ca = bilinear_sample(color[layer, ..., c] * alpha[layer], sx, sy)
                else:
                    ca = bilinear_sample(color[layer, ..., c], sx, sy) * a
                acc = acc * (1 - a) + ca
            out[..., c] += acc
    return out / V
