r"""Double-phase amplitude coding (DPAC): direct, real-time-friendly phase-only patterns.

HOLOGRAPHY.md section 8. The complex hologram (target at the hologram plane) is propagated back
by ``z_slm`` to the SLM plane, optionally low-passed there, normalised and split:

.. math::

    a = \min(|u| / a_\mathrm{max}, 1), \qquad
    u / a_\mathrm{max} \approx a e^{i\phi} = \tfrac{1}{2}\left(e^{i(\phi + \arccos a)}
    + e^{i(\phi - \arccos a)}\right)

and the two phases interleave on a checkerboard (``phi + acos a`` where ``x + y`` is even).

* Amplitude normalisation: ``a_max`` is the largest ``|u|`` of each field (frame and colour)
  after the low-pass, or one value given by the caller (amplitudes above it clip to 1).
* Fourier-plane filter: the checkerboard puts the copy term ``i sqrt(1 - a^2) exp(1j phi)`` at
  the spectrum's corner ``(1/(2p), 1/(2p))``. A square low-pass ``|fx|, |fy| < cutoff / (2p)``
  (default ``cutoff = 0.5``: ``1/(4p)``, half the Nyquist frequency, 31 lines/mm at 8 um) keeps
  the signal and removes the copy. The same filter low-passes the target before coding
  (``prefilter``), so that the signal fits inside it; in simulation
  (:func:`clholo.encode.simulate.simulate_slm` with ``fourier_filter``) it stands for the 4f
  system's aperture. It halves the bandwidth (and the viewing angle) of the hologram.
"""

from __future__ import annotations

from typing import Optional

import numpy as np
import pyopencl as cl
import pyopencl.array as cla

from clholo import validate
from clholo._arrays import resolve_queue, to_device
from clholo.scene import Optics

__all__ = ["dpac_encode", "dpac_encode_device", "fourier_filter_transfer"]


def check_cutoff(cutoff) -> float:
    """The DPAC low-pass's half-width ``cutoff``, a fraction of the Nyquist frequency in
    (0, 1], as a float; anything else is refused by name."""
    cutoff = validate.real_scalar("cutoff", cutoff,
                                  fix="a fraction of the Nyquist frequency in (0, 1], e.g. 0.5")
    if not 0 < cutoff <= 1:
        raise ValueError(f"cutoff is a fraction of the Nyquist frequency in (0, 1], got {cutoff}")
    return cutoff


def fourier_filter_transfer(queue, padded, dz: float, optics: Optics, *, cutoff: float = 0.5,
                            band_limit: bool = True) -> "cla.Array":
    """Transfer functions ``[C, Hp, Wp]`` of ASM by ``dz`` times the DPAC low-pass
    (:func:`clholo.reference.dpac_filter_mask`), built once per context and kept in its
    transfer-function cache (:func:`clholo.propagation.transfer_function_cache`): a display
    loop encodes every batch with the same one. Shared: do not write to the result.

    Parameters
    ----------
    queue : pyopencl.CommandQueue
        Queue the transfer functions are built on.
    padded : (int, int)
        The padded grid ``(Hp, Wp)``.
    dz : float
        Propagation distance, metres.
    optics : Optics
        Pitch and the ``C`` wavelengths, metres.
    cutoff : float
        Filter half-width as a fraction of the Nyquist frequency ``1/(2 p)``, in (0, 1].
    band_limit : bool
        Apply the Matsushima-Shimobaba band limit too (default).
    """
    from clholo import reference
    from clholo.elementwise import complex_multiply
    from clholo.propagation import transfer_function_cache

    cutoff = check_cutoff(cutoff)
    cache = transfer_function_cache(queue.context)

    def build():
        tf = cache.get(queue, padded, dz, wavelengths=optics.wavelengths, pitch=optics.pitch,
                       band_limit=band_limit)
        mask = cla.to_device(queue, reference.dpac_filter_mask(padded, cutoff=cutoff)
                             .astype(np.complex64))
        return complex_multiply(tf, mask, queue=queue)

    key = ("dpac_filter", cutoff) + cache.key(padded, dz, wavelengths=optics.wavelengths,
                                               pitch=optics.pitch, band_limit=band_limit)
    return cache.get_or_build(key, build)


def dpac_encode(holograms, optics: Optics, *, z_slm: float = 0.04,
                amax: Optional[float] = None, prefilter: bool = True, cutoff: float = 0.5,
                pad="auto", queue: Optional["cl.CommandQueue"] = None) -> np.ndarray:
    """Double-phase patterns ``[T, C, H, W]`` float32 (radians, not wrapped) for complex
    holograms ``[T, C, H, W]`` complex64 at ``z_slm`` metres in front of the SLM.
    :func:`dpac_encode_device` is the same with the phases left on the device.

    Parameters
    ----------
    holograms : array complex64 ``[T, C, H, W]`` (NumPy or device)
        Complex targets at the hologram plane.
    optics : Optics
        Pitch and one wavelength per channel (metres).
    z_slm : float
        SLM -> hologram plane distance, metres (paper: 0.04).
    amax : float, optional
        Amplitude that maps to 1 (in the units of ``|ASM(hologram, -z_slm)|``); default: the
        largest amplitude of each frame and colour.
    prefilter : bool
        Low-pass the SLM-plane field with the Fourier filter before coding (default).
    cutoff : float
        Filter half-width as a fraction of the Nyquist frequency ``1/(2 p)``.
    pad : "auto", float or (int, int)
        Padding of the back-propagation (:func:`clholo.propagation.device_padded_shape`).
    queue : pyopencl.CommandQueue, optional
        Queue to run on (default: clholo's default device, ``CLHOLO_DEVICE``).

    Returns
    -------
    numpy.ndarray, float32 ``[T, C, H, W]``
        Phases in radians, not wrapped.
    """
    return dpac_encode_device(holograms, optics, z_slm=z_slm, amax=amax, prefilter=prefilter,
                              cutoff=cutoff, pad=pad, queue=queue).get()


def dpac_encode_device(holograms, optics: Optics, *, z_slm: float = 0.04,
                       amax: Optional[float] = None, prefilter: bool = True,
                       cutoff: float = 0.5, pad="auto",
                       queue: Optional["cl.CommandQueue"] = None,
                       allocator=None) -> "cla.Array":
    """:func:`dpac_encode` with the phases left on the device: a pyopencl float32 array
    ``[T, C, H, W]`` (radians, within ``[-3 pi/2, 3 pi/2]``: ``atan2 +- acos``), enqueued on
    ``queue`` (default: the holograms' queue when they are a device array); nothing is read
    back. ``holograms`` may be NumPy (uploaded) or a pyopencl array (used where it lies).

    Parameters
    ----------
    holograms : array complex64 ``[T, C, H, W]`` (NumPy or device)
        Complex targets at the hologram plane.
    optics : Optics
        Pitch and one wavelength per channel (metres).
    z_slm : float
        SLM -> hologram plane distance, metres.
    amax, prefilter, cutoff, pad
        As for :func:`dpac_encode`.
    queue : pyopencl.CommandQueue, optional
        Queue to enqueue on (default: the holograms', else clholo's default device).
    allocator : callable, optional
        Where the device arrays it makes come from (the back-propagated fields, the phases,
        the per-field maxima), e.g. a ``pyopencl.tools.MemoryPool``: a caller that codes batch
        after batch (the display loop's :class:`~clholo.host.display_loop.DeviceEncoder`)
        reuses the same buffers instead of allocating and freeing them every batch, which some
        drivers do only once the device is idle. Default: new buffers.
    """
    from clholo.encode.sgd import (_amplitude_exponent, _check_holograms, _check_z,
                                   slm_padded_shape)
    from clholo.host.phase_retrieval import encode_kernel, field_max_abs, runtime
    from clholo.propagation import _propagator, transfer_function_cache

    queue = resolve_queue(queue, holograms)
    T, C, H, W = _check_holograms(holograms, optics)
    z_slm = _check_z(z_slm)
    prefilter = validate.flag(prefilter, name="prefilter")
    cutoff = check_cutoff(cutoff)
    if amax is not None:
        amax = validate.real_scalar("amax", amax, fix="a positive amplitude, or None for each "
                                    "field's largest |u|")
        if not 0 < amax <= float(np.finfo(np.float32).max):
            raise ValueError(f"amax must be a positive amplitude within float32's range, got "
                             f"{amax!r}")
    padded = slm_padded_shape((H, W), optics, z_slm, pad=pad)
    B = T * C
    dholo, _ = to_device(queue, holograms, name="holograms")
    if isinstance(holograms, np.ndarray):
        # the largest |u| comes from |u|^2 in float32: far from unit amplitude (1e20, 1e-25)
        # it overflows or vanishes and the patterns are flat checkerboards. The phases do not
        # depend on the scale, and a power of two divides exactly: the same bits as the
        # scaled target's (ordinary amplitudes are not touched; device input, from clholo's
        # own renders, is taken as it is: no host round trip in the display loop)
        exponent = _amplitude_exponent(holograms, dholo)
        if exponent:
            dholo = dholo * np.float32(2.0 ** -exponent)
            amax = None if amax is None else amax * 2.0 ** -exponent
    if prefilter:
        tf = fourier_filter_transfer(queue, padded, -z_slm, optics, cutoff=cutoff)
    else:
        tf = transfer_function_cache(queue.context).get(
            queue, padded, -z_slm, wavelengths=optics.wavelengths, pitch=optics.pitch)
    field = _propagator(queue, B, (H, W), padded, np.complex64).apply(
        dholo.reshape((B, H, W)), tf, tf_even=not prefilter,
        out=cla.empty(queue, (B, H, W), np.complex64, allocator=allocator))
    if amax is None:
        # the largest |u| per field, split over the device like SGD's sums (sum_plan)
        damax = field_max_abs(field.reshape((B, H * W)), queue=queue, allocator=allocator)
    else:
        damax = cla.to_device(queue, np.full(B, amax, np.float32), allocator=allocator)
    phase = cla.empty(queue, (T, C, H, W), np.float32, allocator=allocator)
    runtime.launch(encode_kernel(queue.context, "dpac_encode"), queue, (W, H, B), None,
                   field.data, damax.data, phase.data)
    return phase
