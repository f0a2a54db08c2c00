"""Random phase maps on the device (``kernels/random_phase.cl``), the stream of
``clholo.reference.random_phase`` bit for bit."""

from __future__ import annotations

from typing import Optional, Tuple

import numpy as np
import pyopencl as cl
import pyopencl.array as cla

from clholo._arrays import resolve_queue
from clholo.errors import InputError
from clholo.host import runtime
from clholo.reference import seed_key

__all__ = ["random_phases", "philox4x32_10", "MAX_PIXELS"]


#: The most pixels a plane may have: the kernel counts pixels in 32-bit ``uint``, and its last
#: block of four, ``p0 = 4 * ceil(npix / 4) - 4``, tests ``p0 + 4u <= npix``: from
#: ``npix = 2**32 - 3`` on, ``p0 + 4u`` wraps to 0 and the block's four floats are written
#: past the plane (into the next frame's or beyond the buffer)
MAX_PIXELS = 2 ** 32 - 4


def random_phases(shape: Tuple[int, int], *, seed: int, layer: int, frames=1, colours=1,
                  frame0: int = 0, colour0: int = 0, out=None,
                  queue: Optional["cl.CommandQueue"] = None):
    """Uniform phases in [0, 2 pi], float32 ``[frames, colours, H, W]``, for one layer.

    Frame ``frame0 + f`` and colour ``colour0 + c`` of the stream keyed by ``seed``, bit for
    bit :func:`clholo.reference.random_phase`'s.

    Parameters
    ----------
    shape : (int, int)
        ``(H, W)`` pixels of a plane, at most ``2**32 - 4`` (:data:`MAX_PIXELS`) in all.
    seed : int
        Key of the phase stream, in ``[0, 2**64)``.
    layer : int
        Layer index, in ``[0, 2**32)``.
    frames, colours : int
        Frames and colours to make (>= 1).
    frame0, colour0 : int
        First frame and colour: ``frame0 + frames`` and ``colour0 + colours`` at most
        ``2**32`` (each is a 32-bit counter word of the stream).
    out : pyopencl.array.Array, optional
        float32 ``[frames, colours, H, W]`` to write into; default a new one.
    queue : pyopencl.CommandQueue, optional
        Queue to run on (default: ``out``'s, or clholo's default device).

    Returns
    -------
    pyopencl.array.Array
        float32 ``[frames, colours, H, W]`` radians (``out`` if given), enqueued.

    Raises
    ------
    clholo.errors.InputTypeError
        An index or count that is not a whole number (2.7 would be frame 2's phases), or a
        bool.
    clholo.errors.InputError
        An index outside the stream, a shape below 1 x 1 or above :data:`MAX_PIXELS` pixels
        (refused before anything is allocated), or an ``out`` of another shape or dtype.
    """
    from clholo import validate

    queue = resolve_queue(queue, out)
    H, W = validate.shape2d(shape, name="shape")
    npix = H * W
    if npix > MAX_PIXELS:
        raise InputError(f"shape {H} x {W} has {npix} pixels; at most 2**32 - 4 "
                         f"(= {MAX_PIXELS}) fit the kernel's 32-bit pixel counter: make the "
                         f"phases of a larger plane in tiles of fewer pixels")
    key_lo, key_hi = seed_key(seed)
    layer = validate.stream_index(layer, name="layer")
    frames = validate.count(frames, name="frames")  # 2.5 frames is refused, not truncated
    colours = validate.count(colours, name="colours")
    # each checked alone first: a NumPy -1 would pass a check of frame0 + frames - 1 alone, and
    # np.uint32 would wrap it to frame 2**32 - 1
    frame0 = validate.stream_index(frame0, name="frame0")
    colour0 = validate.stream_index(colour0, name="colour0")
    validate.frame_range(frame0, frames, start_name="frame0")
    if colour0 + colours > validate.STREAM_INDICES:
        raise InputError(f"colours must lie in [0, 2**32), got {colour0}..{colour0 + colours}: "
                         f"give colour0 + colours <= 2**32")
    full = (frames, colours, H, W)
    if out is None:
        out = cla.empty(queue, full, np.float32)
    elif out.shape != full or out.dtype != np.float32:
        raise ValueError(f"out must be float32 {full}, got {out.dtype} {out.shape}")
    runtime.launch(runtime.get_kernel(queue.context, "random_phase.cl", "random_phase"), queue, ((npix + 3) // 4, colours, frames), None, out.data,
                     np.uint32(npix), np.uint32(layer), np.uint32(frame0), np.uint32(colour0),
                     key_lo, key_hi)
    return out


def philox4x32_10(counters: np.ndarray, keys: np.ndarray, *,
                  queue: Optional["cl.CommandQueue"] = None) -> np.ndarray:
    """Raw Philox4x32-10 on the device: uint32 ``counters [N, 4]`` and ``keys [N, 2]`` ->
    ``[N, 4]`` output words (for known-answer checks against Random123)."""
    queue = resolve_queue(queue)
    counters = np.ascontiguousarray(counters, dtype=np.uint32)
    keys = np.ascontiguousarray(keys, dtype=np.uint32)
    if counters.ndim != 2 or counters.shape[1] != 4:
        raise ValueError(f"counters must have shape (N, 4), got {counters.shape}")
    if keys.shape != (counters.shape[0], 2):
        raise ValueError(f"keys must have shape ({counters.shape[0]}, 2), got {keys.shape}")
    dc = cla.to_device(queue, counters)
    dk = cla.to_device(queue, keys)
    out = cla.empty(queue, counters.shape, np.uint32)
    runtime.launch(runtime.get_kernel(queue.context, "random_phase.cl", "philox_raw"), queue, (counters.shape[0],), None, dc.data, dk.data, out.data)
    return out.get()
