"""Random phase maps on the device (``kernels/random_phase.cl``), the stream of
``clholo.reference.random_phase`` bit for bit."""

from __future__ import annotations

from typing import Optional, Tuple

import numpy as np
import pyopencl as cl
import pyopencl.array as cla

from clholo._arrays import resolve_queue
from clholo.host import runtime
from clholo.reference import seed_key

__all__ = ["random_phases", "philox4x32_10"]


def _check_index(name: str, value: int) -> int:
    value = int(value)
    if not 0 <= value < 2 ** 32:
        raise ValueError(f"{name} must be an integer in [0, 2**32), got {value}")
    return value


def random_phases(shape: Tuple[int, int], *, seed: int, layer: int, frames=1, colours=1,
                  frame0: int = 0, colour0: int = 0, out=None,
                  queue: Optional["cl.CommandQueue"] = None):
    """Uniform phases in [0, 2 pi], float32 ``[frames, colours, H, W]``, for one layer.

    Frame ``frame0 + f`` and colour ``colour0 + c`` of the stream keyed by ``seed``.
    Returns a pyopencl array (``out`` if given).
    """
    queue = resolve_queue(queue, out)
    H, W = (int(s) for s in shape)
    if H < 1 or W < 1:
        raise ValueError(f"shape must be (H, W) with H, W >= 1, got {shape}")
    npix = H * W
    if npix >= 2 ** 34:
        raise ValueError(f"shape {shape} has too many pixels for the 32-bit Philox block counter")
    key_lo, key_hi = seed_key(seed)
    layer = _check_index("layer", layer)
    from clholo import validate

    frames = validate.count(frames, name="frames")  # 2.5 frames is refused, not truncated
    colours = validate.count(colours, name="colours")
    _check_index("frame0 + frames", frame0 + frames - 1)
    _check_index("colour0 + colours", colour0 + colours - 1)
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
