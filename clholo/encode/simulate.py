"""What the SLM shows: quantised patterns back to fields at the hologram plane.

``gray -> phase`` through the inverse lookup table (:func:`clholo.encode.quantize.dequantize`),
``x = exp(1j P)`` on the device, then ASM by ``+z_slm`` to the hologram plane (optionally
through the DPAC Fourier-plane filter). The result is a hologram ``[T, C, H, W]`` that
:func:`clholo.focal_stack` (and every other operator on holograms) scores like the complex
one.
"""

from __future__ import annotations

from typing import Optional, Sequence, Union

import numpy as np
import pyopencl as cl
import pyopencl.array as cla

from clholo._arrays import resolve_queue
from clholo.scene import Optics

__all__ = ["simulate_slm", "phase_to_hologram"]


def phase_to_hologram(phase, optics: Optics, *, z_slm: float = 0.04,
                      fourier_filter: Optional[float] = None, pad="auto",
                      queue: Optional["cl.CommandQueue"] = None) -> np.ndarray:
    """Fields ``[T, C, H, W]`` complex64 at the hologram plane from SLM phases
    ``[T, C, H, W]`` (radians): ``ASM(exp(1j P), +z_slm)``.

    ``fourier_filter``: the DPAC low-pass cut-off (fraction of Nyquist, e.g. 0.5) applied in
    the same propagation, or None for none.

    Parameters
    ----------
    phase : array ``[T, C, H, W]``
        SLM phases, radians.
    optics : Optics
        Pitch and one wavelength per channel, metres.
    z_slm : float
        SLM -> hologram plane distance, metres.
    fourier_filter : float, optional
        The DPAC low-pass cut-off (above), or None.
    pad : "auto", float or (int, int)
        Padding of the propagation by ``z_slm`` (:func:`clholo.encode.sgd.slm_padded_shape`).
    queue : pyopencl.CommandQueue, optional
        Queue to run on (default: clholo's default device, ``CLHOLO_DEVICE``).
    """
    from clholo.encode.dpac import fourier_filter_transfer
    from clholo.encode.quantize import real_phases
    from clholo.encode.sgd import _check_z, slm_padded_shape
    from clholo.host.phase_retrieval import encode_kernel, quads, runtime
    from clholo.propagation import _propagator, transfer_function_cache

    if not isinstance(optics, Optics):
        raise TypeError(f"optics must be a clholo.Optics, got {type(optics).__name__}")
    queue = resolve_queue(queue, phase)
    phase = real_phases(phase).astype(np.float32, copy=False)
    if phase.ndim != 4 or phase.shape[1] != optics.channels:
        raise ValueError(f"phase must be [T, C, H, W] with C = {optics.channels} channels, got "
                         f"{phase.shape}")
    if not np.all(np.isfinite(phase)):
        raise ValueError("phase contains NaN/inf values")
    z_slm = _check_z(z_slm)
    T, C, H, W = phase.shape
    padded = slm_padded_shape((H, W), optics, z_slm, pad=pad)
    if fourier_filter is None:
        tf = transfer_function_cache(queue.context).get(
            queue, padded, z_slm, wavelengths=optics.wavelengths, pitch=optics.pitch)
    else:
        tf = fourier_filter_transfer(queue, padded, z_slm, optics, cutoff=fourier_filter)
    dphase = cla.to_device(queue, np.ascontiguousarray(phase))
    x = cla.empty(queue, (T * C, H, W), np.complex64)
    runtime.launch(encode_kernel(queue.context, "phase_to_field"), queue, (quads(x.size),), None,
                   dphase.data, x.data, np.uint32(x.size))
    out = _propagator(queue, T * C, (H, W), padded, np.complex64).apply(
        x, tf, tf_even=fourier_filter is None)
    return out.get().reshape(T, C, H, W)


def simulate_slm(gray, optics: Optics, luts: Union[str, Sequence] = "linear", *,
                 z_slm: float = 0.04, fourier_filter: Optional[float] = None, pad="auto",
                 queue: Optional["cl.CommandQueue"] = None) -> np.ndarray:
    """Holograms ``[T, C, H, W]`` complex64 that uint8 patterns ``gray [T, C, H, W]`` produce
    at the hologram plane (inverse LUT, then :func:`phase_to_hologram`).

    Parameters
    ----------
    gray : uint8 array ``[T, C, H, W]``
        The patterns' gray levels.
    optics : Optics
        Pitch and one wavelength per channel, metres.
    luts : PhaseLUT, str or sequence of them
        One lookup table for every colour or one per colour (``"linear"``, ``"linear:N"``, a file
        path; :func:`parse_lut`).
    z_slm : float
        SLM -> hologram plane distance, metres.
    fourier_filter : float, optional
        The DPAC low-pass cut-off (fraction of Nyquist), or None for none.
    pad : "auto", float or (int, int)
        Padding of the propagation by ``z_slm`` (:func:`clholo.encode.sgd.slm_padded_shape`).
    queue : pyopencl.CommandQueue, optional
        Queue to run on (default: clholo's default device, ``CLHOLO_DEVICE``).
    """
    from clholo.encode.quantize import dequantize

    return phase_to_hologram(dequantize(gray, luts), optics, z_slm=z_slm,
                             fourier_filter=fourier_filter, pad=pad, queue=queue)
