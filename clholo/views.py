"""Operators on holograms: what a viewer sees through a pupil, and the STFT light field.

HOLOGRAPHY.md section 5. Every operator takes a batch of frames ``[T, C, H, W]`` complex64
(NumPy or device) and returns the frame-averaged intensity (time multiplexing), computed on the
OpenCL device in chunks of frames under a memory budget (``clholo.host.views``). The focal
slice is :func:`clholo.hologram.focal_stack`.

* :func:`pupil_view`: refocus by ``-focus_depth`` and keep a disc or square of the spectrum
  centred at spatial frequency ``sin(theta) / lambda`` (the lab's pupil on a stage at the
  Fourier plane), in one spectrum pass: ``crop(IFFT2(FFT2(pad(u)) * H(-d) * A))``.
* :func:`light_field`: STFT with ``w x w`` windows at hop ``s``, ``|FFT2|^2`` averaged over
  frames, bins fftshifted; bin ``k`` is the ray direction ``sin(theta) = lambda k / (w p)``.
"""

from __future__ import annotations

import math
from typing import NamedTuple, Optional, Tuple

import numpy as np
import pyopencl as cl

from clholo import validate
from clholo._arrays import check_context, check_finite_result, resolve_queue
from clholo.fft import is_fft_size, nearest_fft_sizes
from clholo.scene import Optics

__all__ = ["pupil_view", "pupil_geometry", "light_field", "LightField", "DEFAULT_PUPIL_ANGLE_RAD"]

#: Default pupil half-angle (angular radius, as in :mod:`clholo.rayoptics`): 0.005 rad
#: (0.29 deg), a sixth of the +-1.86 deg green light leaves an 8 um SLM with.
DEFAULT_PUPIL_ANGLE_RAD = 0.005


def _check_holograms(holograms, optics: Optics):
    from clholo._arrays import check_holograms

    return check_holograms(holograms, optics)


def _memory_budget(value) -> Optional[int]:
    if value is None:
        return None
    return validate.count(value, name="memory_budget", minimum=1)


def _angles(angles_rad) -> np.ndarray:
    try:
        arr = np.asarray(angles_rad, dtype=np.float64)
    except (TypeError, ValueError):
        raise TypeError(f"angles_rad must be (theta_x, theta_y) pairs in radians, got "
                        f"{angles_rad!r}") from None
    if arr.ndim == 1 and arr.size == 2:
        arr = arr[None]
    if arr.ndim != 2 or arr.shape[1] != 2 or arr.shape[0] == 0:
        raise ValueError(f"angles_rad must be a sequence of (theta_x, theta_y) pairs in radians, "
                         f"shape (A, 2), got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"angles_rad must be finite, got {arr.tolist()}")
    return arr


def pupil_geometry(optics: Optics, angles_rad, *, pupil_angle_rad: Optional[float] = None,
                   pupil_diameter_m: Optional[float] = None,
                   fourier_focal_length_m: Optional[float] = None) -> Tuple[np.ndarray, np.ndarray]:
    """Pupil centres and radii in spatial frequency: ``(centres [A, C, 2], radii [C])``,
    cycles/metre, ``centres[..., 0]`` horizontal.

    Centre ``(sin(theta_x), sin(theta_y)) / lambda_c``; radius ``sin(beta) / lambda_c`` with
    ``beta`` the pupil's half-angle (angular radius): ``pupil_angle_rad``, or for a pupil of
    diameter ``pupil_diameter_m`` at the Fourier plane of a lens of focal length
    ``fourier_focal_length_m`` (the lab's 4f relay), ``sin(beta) = D / (2 f)``.

    Parameters
    ----------
    optics : Optics
        Pitch (metres) and ``C`` wavelengths (metres).
    angles_rad : array ``(A, 2)``
        Viewing angles ``(theta_x, theta_y)`` in radians.
    pupil_angle_rad : float, optional
        The pupil's half-angle in radians.
    pupil_diameter_m, fourier_focal_length_m : float, optional
        Or the pupil's diameter at the Fourier plane and the lens's focal length, metres.

    Raises
    ------
    ValueError
        An angle whose pupil centre lies beyond what the SLM sends, ``|sin(theta)| >
        lambda / (2 p)`` on either axis for any channel (the message gives the limit
        ``asin(lambda / 2p)`` in degrees), or a pupil wider than the SLM's whole band.
    """
    angles = _angles(angles_rad)
    if pupil_diameter_m is not None:
        if pupil_angle_rad is not None:
            raise ValueError("give pupil_angle_rad or pupil_diameter_m, not both")
        D = validate.real_scalar("pupil_diameter_m", pupil_diameter_m)
        if fourier_focal_length_m is None:
            raise ValueError("pupil_diameter_m needs fourier_focal_length_m, the focal length "
                             "(metres) of the lens whose Fourier plane holds the pupil")
        f = validate.real_scalar("fourier_focal_length_m", fourier_focal_length_m)
        # lengths of a bench lens and its pupil: millimetres given as metres would warn
        validate.distance(D, name="pupil_diameter_m")
        validate.distance(f, name="fourier_focal_length_m")
        if D <= 0 or f <= 0:
            raise ValueError(f"pupil_diameter_m and fourier_focal_length_m must be > 0 metres, "
                             f"got {D!r} and {f!r}")
        sin_half = D / (2 * f)
        if sin_half >= 1:
            raise ValueError(f"pupil_diameter_m={D!r} is not smaller than twice "
                             f"fourier_focal_length_m={f!r}")
    else:
        if fourier_focal_length_m is not None:
            raise ValueError("fourier_focal_length_m sizes a pupil given by pupil_diameter_m: "
                             "give pupil_diameter_m too (metres), or drop it")
        beta = DEFAULT_PUPIL_ANGLE_RAD if pupil_angle_rad is None else \
            validate.real_scalar("pupil_angle_rad", pupil_angle_rad)
        if not 0 < beta < math.pi / 2:
            raise ValueError(f"pupil_angle_rad is the pupil's half-angle (angular radius) in "
                             f"radians, in (0, pi/2); got {beta!r}")
        sin_half = math.sin(beta)
    lams = np.asarray(optics.wavelengths)
    limits = lams / (2 * optics.pitch)  # largest sin(theta) the grid carries, per channel
    sines = np.sin(angles)
    for a, (sx, sy) in enumerate(sines):
        optics.check_direction_sent(
            sx, sy, f"angles_rad[{a}] = ({angles[a, 0]:.5g}, {angles[a, 1]:.5g}) rad = "
                    f"({math.degrees(angles[a, 0]):.3f}, {math.degrees(angles[a, 1]):.3f}) deg")
    if sin_half > limits.max():
        smaller = ("a smaller pupil_diameter_m (at most "
                   f"{2 * limits.max() * f:.4g} m at this focal length)"
                   if pupil_diameter_m is not None else "a smaller pupil_angle_rad")
        raise ValueError(
            f"the pupil (half-angle sine {sin_half:.4g}) is wider than the whole band the SLM "
            f"sends (sine {limits.max():.4g}); use {smaller}")
    centres = sines[:, None, :] / lams[None, :, None]
    radii = sin_half / lams
    return centres, radii


#: ``pupil_view``'s automatic padding covers this many widths ``1 / r_c`` of the pupil's
#: point-spread (``r_c`` its radius in cycles/metre; an Airy disc's first zero lies at 0.61 of
#: one): light that wraps round from the far edge is then below about 1 % of the edge's.
PUPIL_PSF_WIDTHS = 8


def _pupil_padded_shape(shape, padded, radii, pitch) -> Tuple[int, int]:
    """``padded`` (the refocus's automatic grid) grown by the pupil's point-spread: the pupil
    multiplies the spectrum, so it convolves the view with its point-spread, circularly on the
    padded grid; at most twice the field per axis (where the convolution is linear)."""
    from clholo.fft import next_fft_size

    margin = math.ceil(PUPIL_PSF_WIDTHS / (float(np.min(radii)) * pitch))
    return tuple(next_fft_size(max(n_p, min(n_p + margin, 2 * n)))
                 for n, n_p in zip(shape, padded))


def _check_pupil_resolved(radii, padded, optics: Optics, physical: bool) -> None:
    """A pupil narrower than one frequency bin ``1 / (N p)`` of the padded grid holds no bin
    (the kernel keeps the bins whose centres lie inside it): an all-black view, or one
    without the colours whose pupils are smallest in bins."""
    Hp, Wp = padded
    p = optics.pitch
    bins = np.asarray(radii) * min(Hp, Wp) * p  # the pupil's radius in bins, per colour
    if bins.min() >= 1:
        return
    c = int(np.argmin(bins))
    lam = optics.wavelengths[c]
    smallest = math.asin(min(1.0, lam / (min(Hp, Wp) * p)))
    given = ("pupil_diameter_m / (2 fourier_focal_length_m)" if physical
             else "sin(pupil_angle_rad)")
    raise ValueError(
        f"the pupil's radius is {bins[c]:.3g} frequency bins of the {Hp}x{Wp} padded grid at "
        f"{lam * 1e9:.0f} nm ({given} = {np.asarray(radii)[c] * lam:.3g}): narrower than one "
        f"bin 1 / (N p), it passes nothing (or only some colours); use a pupil half-angle of "
        f"at least {smallest:.3g} rad ({math.degrees(smallest):.3g} deg), or a larger pad "
        f"(finer bins)")


def pupil_view(holograms, optics: Optics, *, focus_depth: float, angles_rad,
               pupil_angle_rad: Optional[float] = None,
               pupil_diameter_m: Optional[float] = None,
               fourier_focal_length_m: Optional[float] = None, pupil: str = "disc",
               pad="auto", band_limit: bool = True, memory_budget: Optional[int] = None,
               queue: Optional["cl.CommandQueue"] = None) -> np.ndarray:
    """What a camera behind a pupil at the Fourier plane sees: ``[A, C, H, W]`` float32.

    ``I_a = mean_t |crop(IFFT2(FFT2(pad(u_t)) * H(-focus_depth) * A_a))|^2`` per colour
    (HOLOGRAPHY.md section 5), the refocus and the pupil multiplied into one spectrum pass.

    Pupil size in the Fourier plane: a disc of frequency radius ``r_c = sin(beta) / lambda_c``
    cycles/metre (a square of half-side ``r_c``), ``beta`` the half-angle (angular radius,
    ``pupil_angle_rad``, default :data:`DEFAULT_PUPIL_ANGLE_RAD` = 0.005 rad; or
    ``asin(D / 2f)`` for a pupil of diameter ``D = pupil_diameter_m`` at the Fourier plane
    of a lens of focal length ``f = fourier_focal_length_m``). Centred at
    ``(sin(theta_x), sin(theta_y)) / lambda_c``: the same angular pupil in every colour. For
    example at 520 nm and 8 um the SLM's band is ``|f| < 1/(2p) = 62.5`` cycles/mm (1.86 deg);
    the default pupil is a disc of radius 9.6 cycles/mm (0.29 deg half-angle).

    Parameters
    ----------
    holograms : array ``[T, C, H, W]`` complex64 (NumPy or device)
    optics : Optics
        Pitch and one wavelength per channel.
    focus_depth : float
        Metres behind the hologram plane to focus at (0 = the hologram plane).
    angles_rad : sequence of (theta_x, theta_y)
        ``A`` viewing angles in radians, ``theta_x`` horizontal (positive looks from +x).
        Each must satisfy ``|sin(theta)| <= lambda / (2p)`` for every channel.
    pupil_angle_rad : float, optional
        Half-angle (angular radius) of the pupil in radians, as in :mod:`clholo.rayoptics`.
    pupil_diameter_m, fourier_focal_length_m : float, optional
        Instead of ``pupil_angle_rad``: a pupil of that diameter at the Fourier plane of a
        lens of that focal length (metres).
    pupil : {"disc", "square"}
    pad : "auto", float or (int, int)
        Padding (sides ``2^a 3^b 5^c``, :mod:`clholo.propagation`). ``"auto"`` covers the
        refocus kernel's spread plus :data:`PUPIL_PSF_WIDTHS` widths ``1 / r_c`` of the
        pupil's point-spread (at most twice the field per axis), so that the pupil's blur does
        not wrap around from one edge of the view onto the other.
    memory_budget : int, optional
        Bytes of device memory to plan for (default half the device's); frames are processed
        in chunks that fit (``clholo.host.views``).
    band_limit : bool
        Apply the Matsushima-Shimobaba band limit to the refocus (default).
    queue : pyopencl.CommandQueue, optional
        Queue to run on (default: clholo's default device, ``CLHOLO_DEVICE``).

    Returns
    -------
    numpy.ndarray, float32 ``[A, C, H, W]``

    Raises
    ------
    ValueError
        Bad shapes, NaN, angles beyond the SLM's limit (the message states it in degrees), a
        pupil narrower than one frequency bin of the padded grid (it would pass nothing, or
        some colours only).
    MemoryError
        Not even one frame fits the budget (the message names the largest pad that fits,
        before any transfer function is built), or the device's allocation failed.
    """
    from clholo.host import views as host_views
    from clholo.propagation import device_padded_shape, transfer_function_cache

    T, C, H, W = _check_holograms(holograms, optics)
    if pupil not in ("disc", "square"):
        raise ValueError(f"pupil must be 'disc' or 'square', got {pupil!r}")
    d = validate.distance(focus_depth, name="focus_depth")
    band_limit = validate.flag(band_limit, name="band_limit")
    centres, radii = pupil_geometry(optics, angles_rad, pupil_angle_rad=pupil_angle_rad,
                                    pupil_diameter_m=pupil_diameter_m,
                                    fourier_focal_length_m=fourier_focal_length_m)
    budget = _memory_budget(memory_budget)
    queue = resolve_queue(queue, holograms)
    check_context(queue, holograms, name="holograms")  # before any work
    padded = device_padded_shape((H, W), -d, wavelength=optics.wavelengths, pitch=optics.pitch,
                                 pad=pad)
    if isinstance(pad, str):  # "auto" (device_padded_shape refused any other string)
        padded = _pupil_padded_shape((H, W), padded, radii, optics.pitch)
    Hp, Wp = padded
    _check_pupil_resolved(radii, padded, optics, pupil_angle_rad is None
                          and pupil_diameter_m is not None)
    # the memory plan before the transfer function is built: a pad beyond the budget is refused
    # at once, with the largest pad that fits
    host_views.plan_pupil_views(queue, holograms, angles=centres.shape[0], padded=padded,
                                memory_budget=budget)
    # the kernel works in frequency bins: f = k / (N p)
    p = optics.pitch
    pupils = np.empty((centres.shape[0], C, 4))
    pupils[..., 0] = centres[..., 0] * Wp * p
    pupils[..., 1] = centres[..., 1] * Hp * p
    pupils[..., 2] = (radii * Wp * p)[None]
    pupils[..., 3] = (radii * Hp * p)[None]
    tf = transfer_function_cache(queue.context).get(
        queue, padded, -d, wavelengths=optics.wavelengths, pitch=p, band_limit=band_limit,
        dtype=np.complex64)
    views = host_views.pupil_views(queue, holograms, pupils=pupils, refocus_tf=tf,
                                   padded=padded, square=pupil == "square",
                                   memory_budget=budget)
    return check_finite_result(views, holograms, what="pupil views")


class LightField(NamedTuple):
    """The STFT light field of a hologram (HOLOGRAPHY.md section 5).

    Attributes
    ----------
    intensity : numpy.ndarray, float32 ``[C, Ny, Nx, w, w]``
        ``mean_t |FFT2(window * u_t)|^2`` (unnormalised FFT) of window ``(wy, wx)``, bins
        fftshifted: ``intensity[c, wy, wx, j, i]`` is direction bin ``(ky, kx) = (j - w/2,
        i - w/2)``.
    bin_angles_rad : numpy.ndarray, float64 ``[C, w]``
        Angle of fftshifted bin ``j`` along either axis: ``asin(lambda_c (j - w/2) / (w p))``.
    window_y, window_x : numpy.ndarray, int ``[Ny]``, ``[Nx]``
        Top-left pixel row / column of each window (``k * hop``).
    window, hop : int
    taper : str
    """

    intensity: np.ndarray
    bin_angles_rad: np.ndarray
    window_y: np.ndarray
    window_x: np.ndarray
    window: int
    hop: int
    taper: str


def light_field(holograms, optics: Optics, *, window: int = 16, hop: Optional[int] = None,
                taper: str = "rect", memory_budget: Optional[int] = None,
                queue: Optional["cl.CommandQueue"] = None) -> LightField:
    """STFT light field of holograms ``[T, C, H, W]``: a :class:`LightField`.

    Windows of ``w x w`` pixels (``w = window`` >= 2, any FFT size ``2^a 3^b 5^c``) start every
    ``hop`` pixels (default ``hop = w``: tiles) and cover ``Ny = (H - w) // hop + 1`` by
    ``Nx = (W - w) // hop + 1`` positions (a ragged right/bottom margin is left out). Each is
    multiplied by the taper (``"rect"``, or ``"hann"``: the periodic ``0.5 - 0.5 cos(2 pi i /
    w)`` per axis), Fourier transformed, and ``|.|^2`` is averaged over frames. Bin ``k`` of a
    window sees the ray direction ``sin(theta) = lambda k / (w p)``, so a window resolves
    ``w`` directions across the SLM's ``+-asin(lambda / 2p)``.

    Parameters
    ----------
    holograms : array ``[T, C, H, W]`` complex64 (NumPy or device)
    optics : Optics
    window : int
        Power of two, 2 <= w <= min(H, W).
    hop : int, optional
        Step between windows in pixels, >= 1 (default ``window``).
    taper : {"rect", "hann"}
    memory_budget : int, optional
        Bytes of device memory to plan for (default half the device's).
    queue : pyopencl.CommandQueue, optional
        Queue to run on (default: clholo's default device, ``CLHOLO_DEVICE``).
    """
    from clholo.host import views as host_views

    T, C, H, W = _check_holograms(holograms, optics)
    w = validate.count(window, name="window", minimum=2)
    if not is_fft_size(w):
        lo, hi = nearest_fft_sizes(w)
        raise ValueError(f"window must be a size the FFT takes (2^a 3^b 5^c), got {w}; use {lo} "
                         f"or {hi}")
    if w > min(H, W):
        raise ValueError(f"window {w} is larger than the hologram ({H} x {W}); use a window "
                         f"<= {min(H, W)}")
    s = w if hop is None else validate.count(hop, name="hop", minimum=1)
    if taper not in ("rect", "hann"):
        raise ValueError(f"taper must be 'rect' or 'hann', got {taper!r}")
    budget = _memory_budget(memory_budget)
    queue = resolve_queue(queue, holograms)
    check_context(queue, holograms, name="holograms")  # before any work
    intensity = check_finite_result(
        host_views.light_field(queue, holograms, window=w, hop=s, hann=taper == "hann",
                               memory_budget=budget), holograms, what="light field")
    k = np.arange(w) - w // 2
    lams = np.asarray(optics.wavelengths)
    angles = np.arcsin(lams[:, None] * k[None, :] / (w * optics.pitch))
    Ny, Nx = intensity.shape[1:3]
    return LightField(intensity, angles, np.arange(Ny) * s, np.arange(Nx) * s, w, s, taper)
