"""NumPy reference of ``kernels/views.cl`` and of the operators of :mod:`clholo.views`.

HOLOGRAPHY.md section 5, written out plainly in complex128/float64:

* pupil view: ``I = mean_t |crop(IFFT2(FFT2(pad(u_t)) * H(-d_focus) * A))|^2`` with ``A`` a disc
  or square pupil centred at spatial frequency ``sin(theta) / lambda``;
* STFT light field: ``L[wy, wx, ky, kx] = mean_t |FFT2(window * u_t)|^2`` over ``w x w``
  windows at hop ``s``, bins fftshifted (bin ``w/2`` is angle zero), bin ``k`` seen at
  ``sin(theta) = lambda k / (w p)``.
"""

from __future__ import annotations

import math
from typing import Sequence, Tuple

import numpy as np

__all__ = ["pupil_mask", "pupil_transfer_function", "pupil_view", "stft_taper",
           "stft_windows", "stft_accumulate", "light_field", "stft_bin_angles"]


def pupil_mask(padded: Tuple[int, int], *, pitch: float, centre: Tuple[float, float],
               radius: float, square: bool = False) -> np.ndarray:
    """Pupil ``A`` on the padded grid ``(Hp, Wp)`` in unshifted ``fftfreq`` order; bool.

    Parameters
    ----------
    centre : (float, float)
        ``(fx, fy)`` of the pupil's centre, cycles/metre.
    radius : float
        Disc radius, or half the side of the square, cycles/metre.
    square : bool
        Square pupil ``|fx - cx| <= r and |fy - cy| <= r`` instead of the disc.
    """
    Hp, Wp = padded
    fy = np.fft.fftfreq(Hp, d=pitch)[:, None]
    fx = np.fft.fftfreq(Wp, d=pitch)[None, :]
    dx = (fx - centre[0]) / radius
    dy = (fy - centre[1]) / radius
    if square:
        return (np.abs(dx) <= 1.0) & (np.abs(dy) <= 1.0)
    return dx ** 2 + dy ** 2 <= 1.0


def pupil_transfer_function(tf: np.ndarray, *, pitch: float,
                            centres: Sequence[Tuple[float, float]], radii: Sequence[float],
                            square: bool = False) -> np.ndarray:
    """``tf[c] * A_c``: transfer functions ``[C, Hp, Wp]`` times each channel's pupil."""
    tf = np.asarray(tf, np.complex128)
    out = np.empty_like(tf)
    for c in range(tf.shape[0]):
        out[c] = tf[c] * pupil_mask(tf.shape[1:], pitch=pitch, centre=centres[c],
                                    radius=radii[c], square=square)
    return out


def pupil_view(holograms: np.ndarray, focus_depth: float, *, wavelengths: Sequence[float],
               pitch: float, angles_rad: Sequence[Tuple[float, float]],
               pupil_angle_rad: float, square: bool = False, pad=(None, None),
               band_limit: bool = True) -> np.ndarray:
    """Frame-averaged pupil views ``[A, C, H, W]`` float64.

    The pupil of channel ``c`` is centred at ``(sin(theta_x), sin(theta_y)) / lambda_c`` with
    radius ``sin(pupil_angle_rad) / lambda_c`` (``pupil_angle_rad``: the half-angle). ``pad`` is the padded grid ``(Hp, Wp)``
    (default 2x per axis).
    """
    from clholo.reference import core as reference

    holograms = np.asarray(holograms)
    T, C, H, W = holograms.shape
    padded = (pad[0] or 2 * H, pad[1] or 2 * W)
    out = np.zeros((len(angles_rad), C, H, W))
    for a, (tx, ty) in enumerate(angles_rad):
        for c, lam in enumerate(wavelengths):
            tf = reference.transfer_function(padded, -focus_depth, wavelength=lam, pitch=pitch,
                                             band_limit=band_limit)
            mask = pupil_mask(padded, pitch=pitch,
                              centre=(math.sin(tx) / lam, math.sin(ty) / lam),
                              radius=math.sin(pupil_angle_rad) / lam, square=square)
            u = reference.apply_transfer_function(holograms[:, c], tf * mask, padded)
            out[a, c] = np.mean(np.abs(u) ** 2, axis=0)
    return out


def stft_taper(window: int, taper: str = "rect") -> np.ndarray:
    """1-D taper of the STFT: ones, or the periodic Hann ``0.5 - 0.5 cos(2 pi i / w)``."""
    if taper == "rect":
        return np.ones(window)
    i = np.arange(window)
    return 0.5 - 0.5 * np.cos(2 * np.pi * i / window)


def stft_windows(u: np.ndarray, *, window: int, hop: int, taper: str = "rect") -> np.ndarray:
    """Tapered windows ``[..., Ny, Nx, w, w]`` of fields ``u [..., H, W]`` (complex128);
    window ``(wy, wx)`` starts at pixel ``(wy hop, wx hop)``."""
    u = np.asarray(u, np.complex128)
    H, W = u.shape[-2:]
    Ny, Nx = (H - window) // hop + 1, (W - window) // hop + 1
    t = stft_taper(window, taper)
    t2 = t[:, None] * t[None, :]
    out = np.empty(u.shape[:-2] + (Ny, Nx, window, window), np.complex128)
    for wy in range(Ny):
        for wx in range(Nx):
            y0, x0 = wy * hop, wx * hop
            out[..., wy, wx, :, :] = u[..., y0:y0 + window, x0:x0 + window] * t2
    return out


def stft_accumulate(spectra: np.ndarray) -> np.ndarray:
    """Frame mean of ``|spectra|^2`` fftshifted over the last two axes: ``spectra [T, ...,
    w, w]`` -> ``[..., w, w]`` float64 (the kernel accumulates the sum times a weight)."""
    p = np.abs(np.asarray(spectra, np.complex128)) ** 2
    return np.fft.fftshift(p.mean(axis=0), axes=(-2, -1))


def light_field(holograms: np.ndarray, *, window: int, hop: int,
                taper: str = "rect") -> np.ndarray:
    """STFT light field ``[C, Ny, Nx, w, w]`` float64 of holograms ``[T, C, H, W]``."""
    windows = stft_windows(holograms, window=window, hop=hop, taper=taper)
    return stft_accumulate(np.fft.fft2(windows))


def stft_bin_angles(window: int, *, wavelength: float, pitch: float) -> np.ndarray:
    """Angle (radians) of each fftshifted bin ``j``: ``asin(lambda (j - w/2) / (w p))``."""
    k = np.arange(window) - window // 2
    return np.arcsin(np.clip(wavelength * k / (window * pitch), -1.0, 1.0))
