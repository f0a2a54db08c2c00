"""Complex elementwise operations on the OpenCL device (``kernels/elementwise.cl``).

Each function takes NumPy or pyopencl arrays (NumPy in, NumPy out; device in, device out), in
complex64, or complex128 on devices with fp64. References: plain NumPy expressions, see
``clholo.reference`` and the tests.
"""

from __future__ import annotations

from typing import Optional

import numpy as np
import pyopencl as cl
import pyopencl.array as cla
from pyopencl import cltypes

from clholo._arrays import (check_complex, check_precision, program_defines, real_dtype,
                            resolve_queue, to_device)
from clholo.host import runtime

__all__ = ["complex_multiply", "complex_scale", "accumulate_intensity"]


def _kernel(queue, dtype, name):
    return runtime.get_kernel(queue.context, "elementwise.cl", name,
                              defines=program_defines(dtype))


def _prepare_out(queue, out, shape, dtype, name="out"):
    if out is None:
        return cla.empty(queue, shape, dtype)
    if not isinstance(out, cla.Array):
        raise TypeError(f"{name} must be a pyopencl.array.Array (NumPy outputs are returned)")
    if out.shape != tuple(shape) or out.dtype != np.dtype(dtype):
        raise ValueError(f"{name} must have shape {tuple(shape)} and dtype {np.dtype(dtype)}, "
                         f"got {out.shape} {out.dtype}")
    return out


def complex_multiply(a, b, *, out=None, queue: Optional["cl.CommandQueue"] = None):
    """``a * b`` with ``b`` broadcast over ``a``'s leading axes.

    Parameters
    ----------
    a : array, shape (..., *b.shape), complex64 or complex128
    b : array, same dtype; its shape must equal the trailing axes of ``a``.
    out : pyopencl.array.Array, optional
        Device output (may be ``a`` for in-place); only for device inputs.
    """
    queue = resolve_queue(queue, a, b)
    dt = check_complex("a", a)
    check_complex("b", b, dtype=dt)
    check_precision(queue, dt, "complex_multiply")
    if tuple(a.shape[a.ndim - b.ndim:]) != tuple(b.shape) or b.ndim > a.ndim:
        raise ValueError(f"b's shape {b.shape} must equal the trailing axes of a's {a.shape}")
    if b.size == 0 or a.size == 0:
        raise ValueError("a and b must not be empty")
    da, host = to_device(queue, a, name="a")
    db, _ = to_device(queue, b, name="b")
    dout = _prepare_out(queue, out, da.shape, dt)
    runtime.launch(_kernel(queue, dt, "complex_multiply"), queue, (da.size,), None, da.data, db.data, dout.data,
                                         np.uint64(db.size))
    return dout.get() if host else dout


def complex_scale(a, s: complex, *, out=None, queue: Optional["cl.CommandQueue"] = None):
    """``s * a`` for a complex scalar ``s``."""
    queue = resolve_queue(queue, a)
    dt = check_complex("a", a)
    check_precision(queue, dt, "complex_scale")
    if not np.isfinite(s):
        raise ValueError(f"s must be finite, got {s!r}")
    da, host = to_device(queue, a, name="a")
    dout = _prepare_out(queue, out, da.shape, dt)
    scalar = np.array(complex(s), dtype=dt).view(np.dtype((real_dtype(dt), 2)))
    vec = cltypes.make_double2(*scalar) if dt == np.complex128 else \
        cltypes.make_float2(*scalar)
    runtime.launch(_kernel(queue, dt, "complex_scale"), queue, (da.size,), None, da.data, vec, dout.data)
    return dout.get() if host else dout


def accumulate_intensity(u, acc, *, weight: float = 1.0,
                         queue: Optional["cl.CommandQueue"] = None):
    """``acc += weight * sum_batch |u|^2`` on the device; returns ``acc``.

    Parameters
    ----------
    u : array, shape (B..., *acc.shape), complex
        Fields; the leading axes not in ``acc`` are summed over (e.g. frames).
    acc : pyopencl.array.Array or np.ndarray, real of u's precision
        Accumulator. A NumPy accumulator is updated in place (copied back).
    weight : float
        E.g. ``1 / T`` for the frame mean of time multiplexing.
    """
    queue = resolve_queue(queue, u, acc)
    dt = check_complex("u", u)
    check_precision(queue, dt, "accumulate_intensity")
    rt = real_dtype(dt)
    if np.dtype(acc.dtype) != rt:
        raise TypeError(f"acc must be {rt} for {dt} fields, got {acc.dtype}")
    if acc.ndim > u.ndim or tuple(u.shape[u.ndim - acc.ndim:]) != tuple(acc.shape):
        raise ValueError(f"acc's shape {acc.shape} must equal the trailing axes of u's {u.shape}")
    if not np.isfinite(weight):
        raise ValueError(f"weight must be finite, got {weight!r}")
    du, _ = to_device(queue, u, name="u")
    dacc, host_acc = to_device(queue, acc, name="acc")
    n_batch = du.size // dacc.size
    runtime.launch(_kernel(queue, dt, "accumulate_intensity"), queue, (dacc.size,), None, du.data, dacc.data,
                                             rt.type(weight), np.uint64(dacc.size),
                                             np.uint32(n_batch))
    if host_acc:
        dacc.get(ary=acc)
        return acc
    return dacc
