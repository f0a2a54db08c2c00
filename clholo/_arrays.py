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
    """The queue to use: the given one, else a device array's, else clholo's default. A given
    ``queue`` that is not a ``pyopencl.CommandQueue`` is refused by name
    (:func:`clholo.validate.queue`)."""
    if queue is not None:
        from clholo import validate

        return validate.queue(queue)
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


def check_holograms(holograms, optics, *, name: str = "holograms") -> Tuple[int, int, int, int]:
    """The one check of a batch of holograms: a NumPy or pyopencl array, complex64
    ``[T, C, H, W]``, not empty, one channel per wavelength of ``optics``, finite (NumPy input),
    C-contiguous (device input). Returns ``(T, C, H, W)``."""
    from clholo.scene import Optics

    if not isinstance(optics, Optics):
        raise TypeError(f"optics must be a clholo.Optics, got {type(optics).__name__}")
    if not hasattr(holograms, "dtype") or not hasattr(holograms, "shape"):
        raise TypeError(f"{name} must be a NumPy or pyopencl array [T, C, H, W] complex64, "
                        f"got {type(holograms).__name__}")
    check_complex(name, holograms, dtype=np.complex64)
    if holograms.ndim != 4:
        raise ValueError(f"{name} must have shape [T, C, H, W], got {holograms.shape}")
    T, C, H, W = holograms.shape
    if min(T, C, H, W) < 1:
        raise ValueError(f"{name} must hold at least one frame, colour and pixel, got shape "
                         f"{holograms.shape}")
    if C != optics.channels:
        raise ValueError(f"{name} have {C} channel(s) but optics has {optics.channels} "
                         f"wavelength(s); give one wavelength per channel")
    if isinstance(holograms, np.ndarray) and not np.all(np.isfinite(holograms)):
        raise ValueError(f"{name} contain NaN/inf values; every value must be finite")
    if isinstance(holograms, cla.Array) and not holograms.flags.c_contiguous:
        raise ValueError(f"{name} must be a C-contiguous device array")
    return T, C, H, W


def check_finite_result(result: np.ndarray, holograms, *, what: str,
                        name: str = "holograms") -> np.ndarray:
    """``result`` (a host array computed from ``holograms``) if every value is finite, else a
    ValueError saying why it is not. A device array's holograms are not scanned for NaN/inf
    before the work (a pass over device memory per call), and intensities of amplitudes beyond
    about 1e15 overflow float32: either would leave NaN or inf in ``what`` without a word."""
    if result.size and not np.all(np.isfinite(result)):
        bad = int(np.count_nonzero(~np.isfinite(result)))
        if isinstance(holograms, cla.Array):
            cause = (f"the {name} (a device array, not scanned before the work) hold NaN/inf, "
                     f"or amplitudes whose intensities overflow float32 (beyond about 1e15); "
                     f"check them with numpy.isfinite({name}.get()), and divide them by their "
                     f"largest amplitude if it is huge")
        else:
            cause = (f"the {name}' amplitudes are so large that their intensities overflow "
                     f"float32; divide them by their largest amplitude first")
        raise ValueError(f"{bad} value(s) of the {what} are NaN or inf: {cause}")
    return result


def check_precision(queue: "cl.CommandQueue", dtype, what: str) -> None:
    """complex128/float64 need fp64 on the device: a clear error otherwise."""
    if np.dtype(dtype) in (np.dtype(np.complex128), np.dtype(np.float64)):
        runtime.require_fp64(queue.device, what)


def other_queue_markers(queue: "cl.CommandQueue", *arrays) -> list:
    """Events to wait for on ``queue`` before reading or writing ``arrays``: for each other
    queue among the device arrays' own (``None`` entries and NumPy arrays are skipped), a
    marker enqueued there now, complete once everything enqueued there so far is. Commands of
    two queues are not ordered otherwise: a kernel on ``queue`` could read an array before its
    own queue had written it. Empty when every array is ``queue``'s, the usual case."""
    others = None
    for a in arrays:
        q = getattr(a, "queue", None)
        # the usual case first, cheaply (FFT plans ask on every call)
        if q is None or q is queue or not isinstance(a, cla.Array) or q == queue:
            continue
        others = others or {}
        others[q.int_ptr] = q
    return [cl.enqueue_marker(q) for q in others.values()] if others else []


def check_context(queue: "cl.CommandQueue", a, *, name: str) -> None:
    """Refuse a device array ``a`` of another OpenCL context than ``queue``'s, by its name."""
    if isinstance(a, cla.Array) and a.context != queue.context:
        raise ValueError(f"{name} is a device array of another OpenCL context than the "
                         f"queue's: pass the queue it was made on (queue=...), or its "
                         f"values as NumPy ({name}.get())")


def to_device(queue: "cl.CommandQueue", a, *, name: str, dtype=None) -> Tuple["cla.Array", bool]:
    """``(device_array, was_numpy)``; NumPy input is copied (contiguous) to the device.

    A device array is used where it lies. It must belong to ``queue``'s context; if it was
    made on another queue of that context, ``queue`` waits from here on for everything enqueued
    on that one so far (a marker there, a barrier here): commands of two queues are not ordered
    otherwise, and a kernel here could read the array before the other queue has written it."""
    if isinstance(a, cla.Array):
        if not a.flags.c_contiguous:
            raise ValueError(f"{name} must be a C-contiguous device array")
        if dtype is not None and a.dtype != np.dtype(dtype):
            raise TypeError(f"{name} has dtype {a.dtype}, expected {np.dtype(dtype)}")
        check_context(queue, a, name=name)
        markers = other_queue_markers(queue, a)
        if markers:
            cl.enqueue_barrier(queue, wait_for=markers)
        return a, False
    arr = np.asarray(a)
    if dtype is not None:
        arr = arr.astype(dtype, copy=False)
    return cla.to_device(queue, np.ascontiguousarray(arr)), True


def shares_host_memory(queue: "cl.CommandQueue") -> bool:
    """True for CPU devices: their kernels can read and write NumPy arrays where they lie."""
    return bool(queue.device.type & cl.device_type.CPU)


def to_device_readonly(queue: "cl.CommandQueue", a, *, name: str,
                       dtype=None) -> Tuple["cla.Array", bool]:
    """:func:`to_device` for an input the kernels only read: on a CPU device a contiguous
    NumPy array is wrapped in place (a host-pointer buffer, no copy); elsewhere it is copied."""
    if isinstance(a, cla.Array) or not shares_host_memory(queue):
        return to_device(queue, a, name=name, dtype=dtype)
    arr = np.asarray(a)
    if dtype is not None:
        arr = arr.astype(dtype, copy=False)
    arr = np.ascontiguousarray(arr)
    if arr.size == 0:
        return cla.to_device(queue, arr), True
    buf = cl.Buffer(queue.context, cl.mem_flags.READ_ONLY | cl.mem_flags.USE_HOST_PTR,
                    hostbuf=arr)
    return cla.Array(queue, arr.shape, arr.dtype, data=buf), True


def host_result(queue: "cl.CommandQueue", shape, dtype) -> Tuple[Optional[np.ndarray],
                                                                  "cla.Array"]:
    """``(host, device)``: a device array a kernel may write for a NumPy result. On a CPU device
    it is a view of the NumPy array ``host`` (fetch it with :func:`fetch`, no copy); elsewhere
    ``host`` is None and :func:`fetch` copies."""
    shape = tuple(int(s) for s in shape)
    if not shares_host_memory(queue) or int(np.prod(shape, dtype=np.int64)) == 0:
        return None, cla.empty(queue, shape, dtype)
    host = np.empty(shape, dtype)
    buf = cl.Buffer(queue.context, cl.mem_flags.READ_WRITE | cl.mem_flags.USE_HOST_PTR,
                    hostbuf=host)
    return host, cla.Array(queue, shape, host.dtype, data=buf)


def fetch(host: Optional[np.ndarray], dev: "cla.Array") -> np.ndarray:
    """The NumPy result of :func:`host_result`'s pair once ``dev``'s kernels are done: mapping
    the host-pointer buffer is the synchronisation OpenCL asks for (no copy on CPU devices)."""
    if host is None:
        return dev.get()
    mapped, _ = cl.enqueue_map_buffer(dev.queue, dev.base_data, cl.map_flags.READ, 0,
                                      host.shape, host.dtype, wait_for=dev.events,
                                      is_blocking=True)
    mapped.base.release()
    dev.queue.finish()
    return host


def program_defines(dtype) -> dict:
    """Preprocessor macros selecting the precision of a kernel built from clholo_complex.h."""
    if real_dtype(dtype) == np.dtype(np.float64):
        return {"REAL": "double", "CLHOLO_FP64": True}
    return {"REAL": "float"}
