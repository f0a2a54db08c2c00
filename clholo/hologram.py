"""MPI -> hologram (the paper's method) and what a viewer sees of it.

:func:`render_hologram` runs the recursion of HOLOGRAPHY.md section 4 on the OpenCL device
through :class:`clholo.host.scheduler.HologramRenderer`; :func:`iter_hologram_frames` yields
frames as they finish (for a display loop); :func:`focal_stack` returns the frame-averaged
intensity focused at given depths.
"""

from __future__ import annotations

from typing import Iterator, Optional, Sequence, Tuple

import numpy as np
import pyopencl as cl
import pyopencl.array as cla

from clholo._arrays import check_complex, resolve_queue, to_device
from clholo.host.scheduler import HologramRenderer
from clholo.scene import MPI, Optics

__all__ = ["render_hologram", "iter_hologram_frames", "hologram_padded_shape", "focal_stack",
           "HologramRenderer"]


def render_hologram(mpi: MPI, optics: Optics, *, frames: int = 24, seed: int = 0, pad="auto",
                    band_limit: bool = True, out: Optional["cla.Array"] = None,
                    queue: Optional["cl.CommandQueue"] = None):
    """Random-phase MPI holograms at the hologram plane, ``[T, C, H, W]`` complex64.

    Parameters
    ----------
    mpi : MPI
        ``L`` layers ``(H, W)`` with ``C`` channels, depths in metres behind the hologram.
    optics : Optics
        Pitch (metres) and ``C`` wavelengths (metres).
    frames : int
        ``T`` time-multiplexed frames, each with fresh phases (paper: 24).
    seed : int
        Key of the phase stream; the same seed gives the same holograms bit for bit on the
        same device (and the same phases on every device).
    pad : "auto", float or (int, int)
        Padding of each propagation (power-of-two grid; see :mod:`clholo.propagation`).
        :func:`hologram_padded_shape` tells the grid it resolves to.
    out : pyopencl.array.Array, optional
        Device array ``[T, C, H, W]`` complex64 to render into (and return). Without it the
        holograms come back as a NumPy array.

    Returns
    -------
    numpy.ndarray or pyopencl.array.Array (``out``), complex64 ``[T, C, H, W]``
    """
    renderer = HologramRenderer(mpi, optics, seed=seed, pad=pad, band_limit=band_limit,
                                queue=queue)
    result = renderer.render(frames, out=out)
    return result if out is not None else result.get()


def iter_hologram_frames(mpi: MPI, optics: Optics, *, frames: int = 24, seed: int = 0,
                         pad="auto", band_limit: bool = True,
                         frames_per_batch: Optional[int] = None,
                         queue: Optional["cl.CommandQueue"] = None
                         ) -> Iterator[Tuple[int, np.ndarray]]:
    """Yield ``(t0, holograms[n, C, H, W])`` as each batch of frames finishes.

    The device already computes the next batch while the caller handles this one. Frames are
    identical to :func:`render_hologram`'s with the same seed.
    """
    renderer = HologramRenderer(mpi, optics, seed=seed, pad=pad, band_limit=band_limit,
                                queue=queue)
    yield from renderer.iter_frames(frames, frames_per_batch=frames_per_batch)


def hologram_padded_shape(mpi: MPI, optics: Optics, *, pad="auto") -> Tuple[int, int]:
    """The power-of-two grid ``(Hp, Wp)`` every propagation of ``render_hologram`` uses
    (give it to ``clholo.reference`` as ``pad=(Hp, Wp)`` to compare)."""
    from clholo import reference
    from clholo.propagation import device_padded_shape

    return device_padded_shape(mpi.shape, reference.layer_steps(mpi.depths),
                               wavelength=optics.wavelengths, pitch=optics.pitch, pad=pad)


def focal_stack(holograms, optics: Optics, depths: Sequence[float], *, pad="auto",
                band_limit: bool = True, queue: Optional["cl.CommandQueue"] = None
                ) -> np.ndarray:
    """Frame-averaged intensity focused at each depth: ``[D, C, H, W]`` float32.

    ``I_d = mean_t |ASM(u_t, -d)|^2`` per colour (HOLOGRAPHY.md section 5), computed on the
    device.

    Parameters
    ----------
    holograms : array ``[T, C, H, W]`` complex64 (NumPy or device)
    optics : Optics
        One wavelength per channel ``C``.
    depths : sequence of float
        Metres behind the hologram plane (> 0 looks into the scene).
    pad : "auto", float or (int, int)
        One power-of-two grid for every depth (the largest any needs).
    """
    from clholo.elementwise import accumulate_intensity
    from clholo.propagation import (_propagator, device_padded_shape,
                                    transfer_function_cache)

    queue = resolve_queue(queue, holograms)
    check_complex("holograms", holograms, dtype=np.complex64)
    if holograms.ndim != 4:
        raise ValueError(f"holograms must have shape [T, C, H, W], got {holograms.shape}")
    T, C, H, W = holograms.shape
    if C != optics.channels:
        raise ValueError(f"holograms have {C} channel(s) but optics has {optics.channels} "
                         f"wavelength(s)")
    d = np.atleast_1d(np.asarray(depths, dtype=np.float64))
    if d.ndim != 1 or d.size == 0 or not np.all(np.isfinite(d)):
        raise ValueError(f"depths must be a non-empty 1-D sequence of finite metres, got {depths!r}")
    if isinstance(holograms, np.ndarray) and not np.all(np.isfinite(holograms)):
        raise ValueError("holograms contain NaN/inf values")
    padded = device_padded_shape((H, W), -d, wavelength=optics.wavelengths, pitch=optics.pitch,
                                 pad=pad)
    dholo, _ = to_device(queue, holograms, name="holograms")
    prop = _propagator(queue, T * C, (H, W), padded, np.complex64)
    cache = transfer_function_cache(queue.context)
    field = cla.empty(queue, (T * C, H, W), np.complex64)
    out = np.empty((d.size, C, H, W), np.float32)
    acc = cla.empty(queue, (C, H, W), np.float32)
    for k, depth in enumerate(d):
        tf = cache.get(queue, padded, -float(depth), wavelengths=optics.wavelengths,
                       pitch=optics.pitch, band_limit=band_limit, dtype=np.complex64)
        prop.apply(dholo.reshape((T * C, H, W)), tf, out=field)
        acc.fill(0)
        accumulate_intensity(field.reshape((T, C, H, W)), acc, weight=1.0 / T, queue=queue)
        acc.get(ary=out[k])
    return out
