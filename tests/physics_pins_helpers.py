"""Helpers of the physics pins (tests/test_physics_pins.py): small, independent models of the
physics written from the textbook formulas, not from clholo's code or its NumPy reference.

Only the physics-pin tests import this module.
"""

import numpy as np


def asm(field, z, wavelength, pitch, padded):
    """Angular-spectrum propagation by ``z`` metres (textbook form, complex128).

    ``field [..., h, w]`` is zero padded to ``padded`` (top-left), multiplied in frequency by
    ``exp(2 pi i z sqrt(1/lambda^2 - fx^2 - fy^2))`` (0 for evanescent waves) with
    ``f = k / (N p)`` and cropped back. No band limit: callers choose ``z`` and grids where the
    Matsushima limit lies beyond the Nyquist frequency.
    """
    u = np.asarray(field, np.complex128)
    h, w = u.shape[-2:]
    Hp, Wp = padded
    big = np.zeros(u.shape[:-2] + (Hp, Wp), np.complex128)
    big[..., :h, :w] = u
    fy = np.fft.fftfreq(Hp, d=pitch)[:, None]
    fx = np.fft.fftfreq(Wp, d=pitch)[None, :]
    arg = 1.0 / wavelength ** 2 - fx ** 2 - fy ** 2
    kz = np.sqrt(np.maximum(arg, 0.0))
    tf = np.where(arg > 0, np.exp(2j * np.pi * z * kz), 0.0)
    return np.fft.ifft2(np.fft.fft2(big) * tf)[..., :h, :w]


def matsushima_inactive(z, wavelength, pitch, padded):
    """True when the Matsushima-Shimobaba band limit of ASM by ``z`` on ``padded`` lies beyond
    the grid's Nyquist frequency (so a propagation without it is the same operator)."""
    for n in padded:
        df = 1.0 / (n * pitch)
        limit = 1.0 / (wavelength * np.sqrt((2 * df * z) ** 2 + 1))
        if limit < 1.0 / (2 * pitch):
            return False
    return True


def plane_wave(shape, kx, ky, amplitude=1.0, phase=0.0):
    """``a exp(i (2 pi (kx x / W + ky y / H) + phase))`` on ``shape = (H, W)``: a plane wave on
    frequency bin ``(ky, kx)`` of the grid (complex128)."""
    H, W = shape
    y, x = np.mgrid[0:H, 0:W]
    return amplitude * np.exp(1j * (2 * np.pi * (kx * x / W + ky * y / H) + phase))


def rotation_from_quaternion(q_wxyz):
    """Rotation matrix of the unit quaternion ``(w, x, y, z)`` via SciPy (scalar-last input)."""
    from scipy.spatial.transform import Rotation

    w, x, y, z = q_wxyz
    return Rotation.from_quat([x, y, z, w]).as_matrix()


def pinhole(points_world, R, t, fx, fy, cx, cy):
    """Pixel ``(u, v)`` of world points ``[N, 3]`` through the pinhole camera
    ``p_cam = R p + t``, ``u = fx X / Z + cx``, ``v = fy Y / Z + cy``."""
    p = np.asarray(points_world, np.float64) @ np.asarray(R).T + np.asarray(t)
    return np.stack([fx * p[:, 0] / p[:, 2] + cx, fy * p[:, 1] / p[:, 2] + cy], 1)


def monte_carlo_projection(mean, scales, q_wxyz, R, t, fx, fy, cx, cy, n, rng):
    """Mean ``(2,)`` and covariance ``(2, 2)`` in pixels of the pinhole images of ``n`` samples
    of the 3-D Gaussian ``N(mean, Rq diag(scales^2) Rq^T)``."""
    Rq = rotation_from_quaternion(q_wxyz)
    local = rng.standard_normal((n, 3)) * np.asarray(scales)[None, :]
    pts = np.asarray(mean)[None, :] + local @ Rq.T
    uv = pinhole(pts, R, t, fx, fy, cx, cy)
    return uv.mean(0), np.cov(uv.T)


def gaussian_alpha(xs, ys, mean_uv, cov, opacity):
    """``o exp(-1/2 d^T cov^-1 d)`` at pixel centres ``(xs, ys)``, ``d = (x, y) - mean``."""
    inv = np.linalg.inv(cov)
    dx = xs - mean_uv[0]
    dy = ys - mean_uv[1]
    q = inv[0, 0] * dx * dx + 2 * inv[0, 1] * dx * dy + inv[1, 1] * dy * dy
    return opacity * np.exp(-0.5 * q)


def complex_fit_error(got, want):
    """Relative L2 error of ``s got`` against ``want`` at the least-squares complex ``s``."""
    g = np.asarray(got, np.complex128).ravel()
    w = np.asarray(want, np.complex128).ravel()
    s = np.vdot(g, w) / np.vdot(g, g)
    return float(np.linalg.norm(s * g - w) / np.linalg.norm(w))


def wrap(phase):
    """Phase wrapped to (-pi, pi]."""
    return np.angle(np.exp(1j * np.asarray(phase, np.float64)))
