"""Host/device array plumbing shared by the public wrappers.

A wrapper accepts ``np.ndarray`` or ``pyopencl.array.Array``; NumPy in gives NumPy out, a device
array in stays on the device. These helpers do the conversion and validation once.
"""

from __future__ import annotations

from typing import Optional, Tuple

import numpy as np
import pyopencl as cl
import pyopencl.array as cla

from clholo.host import runtime

COMPLEX_TYPES = (np.dtype(np.complex64), np.dtype(np.complex128))


def resolve_queue(queue: Optional["cl.CommandQueue"], *arrays) -> "cl.CommandQueue":
    """The queue to use: the given one, else a device array's, else clholo's default."""
    if queue is not None:
        return queue
    for a in arrays:
        if isinstance(a, cla.Array) and a.queue is not None:
            return a.queue
    return runtime.get_queue()


def real_dtype(dtype) -> np.dtype:
    """float32 for complex64, float64 for complex128."""
    return np.dtype(np.finfo(np.dtype(dtype)).dtype)


def check_complex(name: str, a, *, dtype=None) -> np.dtype:
    """Validate that ``a`` is a complex64/complex128 array (of ``dtype`` when given)."""
    dt = np.dtype(a.dtype)
    if dt not in COMPLEX_TYPES:
        raise TypeError(f"{name} must be complex64 or complex128, got {dt}; "
                        f"convert with .astype(np.complex64)")
    if dtype is not None and dt != np.dtype(dtype):
        raise TypeError(f"{name} has dtype {dt} but {np.dtype(dtype)} is required here")
    return dt


def check_precision(queue: "cl.CommandQueue", dtype, what: str) -> None:
    """complex128/float64 need fp64 on the device: a clear error otherwise."""
    if np.dtype(dtype) in (np.dtype(np.complex128), np.dtype(np.float64)):
        runtime.require_fp64(queue.device, what)


def to_device(queue: "cl.CommandQueue", a, *, name: str, dtype=None) -> Tuple["cla.Array", bool]:
    """``(device_array, was_numpy)``; NumPy input is copied (contiguous) to the device."""
    if isinstance(a, cla.Array):
        if not a.flags.c_contiguous:
            raise ValueError(f"{name} must be a C-contiguous device array")
        if dtype is not None and a.dtype != np.dtype(dtype):
            raise TypeError(f"{name} has dtype {a.dtype}, expected {np.dtype(dtype)}")
        return a, False
    arr = np.asarray(a)
    if dtype is not None:
        arr = arr.astype(dtype, copy=False)
    return cla.to_device(queue, np.ascontiguousarray(arr)), True


def program_defines(dtype) -> dict:
    """Preprocessor macros selecting the precision of a kernel built from clholo_complex.h."""
    if real_dtype(dtype) == np.dtype(np.float64):
        return {"REAL": "double", "CLHOLO_FP64": True}
    return {"REAL": "float"}
