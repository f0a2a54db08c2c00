"""NumPy reference of ``kernels/encode.cl``: SGD phase retrieval and double-phase coding.

complex128/float64 throughout. The SGD model (HOLOGRAPHY.md section 8): the SLM shows
``x = exp(1j P)``; it reaches the hologram plane as ``y = A x = ASM(x, +z)``; the loss of field
``b`` is

    L_b = sum w |s_b y_b - t_b|^2 / sum w |t_b|^2

with ``w`` the region-of-interest weights (ones without; each weight multiplies its pixel's
squared error, so 0.5 halves a pixel's say), ``t`` the target and ``s_b`` the weighted
least-squares complex scale ``sum w conj(y) t / sum w |y|^2`` fitted in closed form each
iteration.
Because ``s_b`` minimises ``L_b`` its own dependence on ``P`` drops out of the gradient:

    dL_b / dP_b = 2 Im(g conj(x)),   g = A^H (conj(s_b) w (s_b y - t)) / sum w |t|^2

and ``A^H`` is ASM by ``-z`` with the same band limit and padded grid.
"""

from __future__ import annotations

from typing import Optional, Sequence, Tuple

import numpy as np

from .core import apply_transfer_function, transfer_function

__all__ = ["phase_to_field", "asm_operator", "sgd_loss", "sgd_loss_and_gradient", "adam_step",
           "sgd_fit", "sgd_iteration", "dpac_phase", "dpac_filter_mask"]


def phase_to_field(phase: np.ndarray) -> np.ndarray:
    """``exp(1j P)``, complex128."""
    return np.exp(1j * np.asarray(phase, np.float64))


def asm_operator(shape: Tuple[int, int], z: float, *, wavelengths: Sequence[float],
                 pitch: float, padded: Tuple[int, int], band_limit: bool = True):
    """``(A, A_adjoint)``: functions ``[B, H, W] -> [B, H, W]`` (field ``b`` uses wavelength
    ``b % C``) propagating by ``+z`` and by ``-z`` on the same padded grid."""
    tf_fwd = np.stack([transfer_function(padded, z, wavelength=w, pitch=pitch,
                                         band_limit=band_limit) for w in wavelengths])
    tf_adj = np.stack([transfer_function(padded, -z, wavelength=w, pitch=pitch,
                                         band_limit=band_limit) for w in wavelengths])
    C = len(wavelengths)

    def apply(tf, u):
        u = np.asarray(u, np.complex128)
        B = u.shape[0]
        return apply_transfer_function(u, tf[np.arange(B) % C], padded)

    return (lambda u: apply(tf_fwd, u)), (lambda u: apply(tf_adj, u))


def _mask2(mask, shape):
    if mask is None:
        return np.ones(shape, np.float64)
    return np.asarray(mask, np.float64)  # a weight per pixel on the squared error


def _fit_scale(y, t, m2):
    """Per-field ``sum w conj(y) t``, ``sum w |y|^2``, ``sum w |t|^2`` and the least-squares
    scale (``m2`` holds the weights ``w``)."""
    c = np.sum(m2 * np.conj(y) * t, axis=(-2, -1))
    yy = np.sum(m2 * np.abs(y) ** 2, axis=(-2, -1))
    tt = np.sum(m2 * np.abs(t) ** 2, axis=(-2, -1))
    return c, yy, tt, c / yy


def sgd_fit(y: np.ndarray, t: np.ndarray, *, mask: Optional[np.ndarray] = None
            ) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What ``field_sums`` then ``fit_scale`` make of fields ``y`` and targets ``t``.

    Parameters
    ----------
    y, t : complex ``[B, H, W]`` (or ``[B, 1, n]``)
    mask : float ``[H, W]``, optional
        Weights ``w`` of each pixel's squared error (all ones without).

    Returns
    -------
    (scale [B] complex128, weight [B] float64, loss [B] float64)
        ``s_b = sum w conj(y) t / sum w |y|^2``, ``1 / sum w |t|^2`` and
        ``L_b = 1 - |sum w conj(y) t|^2 / (sum w |y|^2 sum w |t|^2)`` (module docstring).
    """
    y = np.asarray(y, np.complex128)
    t = np.asarray(t, np.complex128)
    c, yy, tt, s = _fit_scale(y, t, _mask2(mask, y.shape[-2:]))
    return s, 1.0 / tt, 1.0 - np.abs(c) ** 2 / (yy * tt)


def sgd_loss(phase: np.ndarray, target: np.ndarray, A, *, mask: Optional[np.ndarray] = None
             ) -> np.ndarray:
    """Per-field loss ``L_b`` ``[B]`` at the fitted scale (module docstring)."""
    y = A(phase_to_field(phase))
    t = np.asarray(target, np.complex128)
    m2 = _mask2(mask, y.shape[-2:])
    _, _, tt, s = _fit_scale(y, t, m2)
    r = s[:, None, None] * y - t
    return np.sum(m2 * np.abs(r) ** 2, axis=(-2, -1)) / tt


def sgd_loss_and_gradient(phase: np.ndarray, target: np.ndarray, A, A_adjoint, *,
                          mask: Optional[np.ndarray] = None
                          ) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(loss [B], gradient [B, H, W], scale [B])`` of the SGD loss (module docstring)."""
    x = phase_to_field(phase)
    y = A(x)
    t = np.asarray(target, np.complex128)
    m2 = _mask2(mask, y.shape[-2:])
    c, yy, tt, s = _fit_scale(y, t, m2)
    loss = 1.0 - np.abs(c) ** 2 / (yy * tt)
    r = (np.conj(s) / tt)[:, None, None] * m2 * (s[:, None, None] * y - t)
    g = A_adjoint(r)
    grad = 2.0 * np.imag(g * np.conj(x))
    return loss, grad, s


def adam_step(phase: np.ndarray, grad: np.ndarray, m: np.ndarray, v: np.ndarray, step: int, *,
              lr: float, beta1: float = 0.9, beta2: float = 0.999, eps: float = 1e-8
              ) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One Adam step (Kingma & Ba; PyTorch's form, ``eps`` outside the root); ``step`` counts
    from 1. Returns ``(phase, m, v)``."""
    m = beta1 * m + (1 - beta1) * grad
    v = beta2 * v + (1 - beta2) * grad * grad
    bc1 = 1 - beta1 ** step
    bc2 = 1 - beta2 ** step
    phase = phase - lr * (m / bc1) / (np.sqrt(v / bc2) + eps)
    return phase, m, v


def sgd_iteration(phase, m, v, step, target, A, A_adjoint, *, lr, mask=None, beta1=0.9,
                  beta2=0.999, eps=1e-8):
    """One whole SGD iteration: forward, loss, gradient, Adam step.

    Returns ``(phase, m, v, loss, grad, scale)``; ``loss``/``grad``/``scale`` belong to the
    phase before the step."""
    loss, grad, s = sgd_loss_and_gradient(phase, target, A, A_adjoint, mask=mask)
    phase, m, v = adam_step(phase, grad, m, v, step, lr=lr, beta1=beta1, beta2=beta2, eps=eps)
    return phase, m, v, loss, grad, s


def dpac_phase(field: np.ndarray, amax: np.ndarray) -> np.ndarray:
    """Double-phase coding of ``field [B, H, W]`` with per-field normalisation ``amax [B]``:
    ``a = min(|u| / amax, 1)``, ``P = arg u + acos a`` where ``x + y`` is even, ``- acos a``
    where odd. float64 ``[B, H, W]`` (not wrapped)."""
    u = np.asarray(field, np.complex128)
    amax = np.asarray(amax, np.float64).reshape(-1, 1, 1)
    with np.errstate(divide="ignore", invalid="ignore"):
        a = np.where(amax > 0, np.minimum(np.abs(u) / amax, 1.0), 0.0)
    d = np.arccos(a)
    H, W = u.shape[-2:]
    odd = (np.add.outer(np.arange(H), np.arange(W)) & 1).astype(bool)
    return np.angle(u) + np.where(odd, -d, d)


def dpac_filter_mask(padded: Tuple[int, int], *, cutoff: float = 0.5) -> np.ndarray:
    """Fourier-plane low-pass of DPAC on grid ``padded`` (unshifted order), float64 0/1: 1 where
    ``|fx| < cutoff / (2 p)`` and ``|fy| < cutoff / (2 p)``, ``cutoff`` a fraction of the
    Nyquist frequency ``1 / (2 p)`` (``p`` the pitch).

    The checkerboard ``(-1)^(x+y)`` moves the copy term ``i sqrt(1-a^2) exp(i phi)`` to the
    corner ``(1/(2p), 1/(2p))`` of the spectrum; a square of half-width ``1/(4p)`` (the default
    ``cutoff = 0.5``) keeps a signal band-limited to it and removes the copy."""
    # compare integer frequency indices k (f = k / (N p)) so that a cut-off on a bin is exact
    Hp, Wp = padded
    ky = np.abs(np.rint(np.fft.fftfreq(Hp) * Hp))[:, None]
    kx = np.abs(np.rint(np.fft.fftfreq(Wp) * Wp))[None, :]
    return ((ky < cutoff * Hp / 2) & (kx < cutoff * Wp / 2)).astype(np.float64)

