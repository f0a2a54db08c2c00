"""Device-memory planning shared by every scheduler: how many frames go into one launch, and
what a user is told when the device runs out.

A scheduler states its memory as ``fixed + frames * per_frame`` bytes (its docstring gives the
terms); :func:`frames_per_launch` returns the largest frame count that fits the budget (default:
half of the device's global memory), capped where batching further buys nothing
(:func:`batch_target_samples` complex samples per launch, by the device's kind; every
scheduler takes it from here). Allocation failures, which OpenCL
reports as ``MEM_OBJECT_ALLOCATION_FAILURE``, ``OUT_OF_RESOURCES`` or ``INVALID_BUFFER_SIZE``,
become a :class:`MemoryError` that names the sizes and the fix (:func:`device_allocation`).
"""

from __future__ import annotations

import contextlib
import math
from typing import Iterator, Optional, Tuple

import pyopencl as cl

# what the host can still give lives in a leaf module: readers of files (clholo.io) ask it
# too, without importing the device side
from clholo._sysmem import available_host_bytes

from clholo import validate

__all__ = ["BATCH_TARGET_SAMPLES", "GPU_SAMPLES_PER_COMPUTE_UNIT", "batch_target_samples",
           "device_batch_target", "default_budget", "frames_per_launch", "device_allocation",
           "available_host_bytes", "pinned_empty"]

#: Complex samples per launch past which batching buys nothing on a CPU (measured on PoCL) and
#: only delays the first frame; also the least any device gets.
BATCH_TARGET_SAMPLES = 1 << 23

#: A GPU's target per compute unit. A launch costs the host 20-70 us (an H100: 21.5 us per
#: kernel, 67 us per two-pass FFT; ../shared/gpu/H100.md), and a unit streams about 23 GB/s
#: (3 TB/s over an H100's 132): 2^19 complex64 samples per unit, read and written once, are a
#: pass of ~360 us, so the host's share of a launch stays near 10 %. At 2^23 samples an H100
#: ran one 1080p RGB frame per launch and its host never got ahead of the GPU (issue 23).
#: It is the default of the tunable setting ``launch_samples`` (:mod:`clholo.host.tuning`,
#: ``clholo tune``), which a device's stored tuning overrides there.
GPU_SAMPLES_PER_COMPUTE_UNIT = 1 << 19


def batch_target_samples(*, gpu: bool, compute_units: int,
                         per_unit: Optional[int] = None) -> int:
    """Complex samples one launch should carry on a device of this kind (a pure function).

    Parameters
    ----------
    gpu : bool
        The device is not a CPU (a GPU or an accelerator).
    compute_units : int
        ``CL_DEVICE_MAX_COMPUTE_UNITS``.
    per_unit : int, optional
        A GPU's samples per compute unit (default :data:`GPU_SAMPLES_PER_COMPUTE_UNIT`, or
        :func:`clholo.tuning.override`'s ``launch_samples``).

    Returns
    -------
    int
        :data:`BATCH_TARGET_SAMPLES` on CPUs; on GPUs
        ``compute_units x`` :data:`GPU_SAMPLES_PER_COMPUTE_UNIT`, at least the CPUs' target
        (an H100, 132 units: 69.2 M samples, ten 1080p RGB frames on its 1125x1944 grid). The
        memory budget still caps the frames (:func:`frames_per_launch`).
    """
    if not gpu:
        return BATCH_TARGET_SAMPLES
    if per_unit is None:
        from clholo.host import tuning

        per_unit = tuning.value("launch_samples")
    return int(max(BATCH_TARGET_SAMPLES, int(compute_units) * int(per_unit)))


def device_batch_target(device: "cl.Device") -> int:
    """:func:`batch_target_samples` of an OpenCL device (its type and compute units), with the
    device's tunable setting ``launch_samples`` (:func:`clholo.host.tuning.settings_for`)."""
    from clholo.host import tuning

    return batch_target_samples(gpu=not bool(int(device.type) & cl.device_type.CPU),
                                compute_units=int(device.max_compute_units),
                                per_unit=dict(tuning.settings_for(device))["launch_samples"])

_ALLOCATION_FAILURES = {"MEM_OBJECT_ALLOCATION_FAILURE", "OUT_OF_RESOURCES", "OUT_OF_HOST_MEMORY",
                        "INVALID_BUFFER_SIZE"}


def default_budget(device: "cl.Device") -> int:
    """Half the device's global memory, in bytes; on a CPU device (whose buffers are host
    memory) at most half of what the host can still give (:func:`available_host_bytes`):
    PoCL allocates a buffer when it is first used and aborts the process (an assertion,
    SIGABRT) where that fails, under an address-space limit (``ulimit -v``) as on a machine
    whose memory is taken, so the plan must stay within it."""
    budget = int(device.global_mem_size) // 2
    if int(device.type) & cl.device_type.CPU:
        budget = min(budget, available_host_bytes() // 2)
    return budget


def pinned_empty(queue: "cl.CommandQueue", shape, dtype) -> "np.ndarray":
    """An uninitialised NumPy array in page-locked host memory, for reads the device does
    while the host works (``enqueue_copy(..., is_blocking=False)``).

    A GPU's driver copies into page-locked memory by DMA, at the bus's speed and without the
    host; a read into ordinary (pageable) memory goes through a staging buffer, and NVIDIA's
    OpenCL waits for it on the host. The array is the host mapping of an
    ``ALLOC_HOST_PTR`` buffer (the way OpenCL asks for page-locked memory; NVIDIA's guide for
    its OpenCL does this) and keeps that buffer alive; the mapping is released, after every
    command enqueued before it on ``queue``, when the array is freed. On a CPU device (PoCL) it
    is ordinary host memory.

    Parameters
    ----------
    queue : pyopencl.CommandQueue
        The queue whose device reads into the array (its context owns the buffer).
    shape : tuple of int
        The array's shape; not empty.
    dtype : numpy dtype
        The array's dtype.
    """
    import numpy as np

    shape = tuple(int(v) for v in shape)
    dtype = np.dtype(dtype)
    nbytes = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
    if nbytes <= 0:
        raise ValueError(f"pinned_empty needs a shape that is not empty, got {shape}")
    with device_allocation("page-locked host memory", nbytes, queue.device):
        buf = cl.Buffer(queue.context, cl.mem_flags.READ_WRITE | cl.mem_flags.ALLOC_HOST_PTR,
                        nbytes)
        host, _ = cl.enqueue_map_buffer(queue, buf, cl.map_flags.READ | cl.map_flags.WRITE, 0,
                                        shape, dtype, is_blocking=True)
    return host


def _mib(n: float) -> str:
    return f"{n / 2**20:.0f} MiB" if n >= 2**20 else f"{n / 2**10:.1f} KiB"


Grid = Tuple[Tuple[int, int], Tuple[int, int], int]


def largest_grid(budget: int, fixed_bytes: int, per_frame_bytes: int, grid: Grid) -> str:
    """What the budget can hold, in words, for a refusal: the largest pad factor whose padded
    grid (rounded up to FFT sizes, as :func:`clholo.propagation.device_padded_shape` does)
    fits, and that grid.

    ``grid`` is ``((H, W), (Hp, Wp), padded_bytes)``: the field, the padded grid, and the
    bytes of one frame's work (fixed + per frame) that depend on the padding, either as a
    number of bytes per padded sample or as a function ``(hp, wp) -> bytes`` (arrays such as
    a row spectrum ``[H, Wp]`` grow with one side only); the rest of
    ``fixed_bytes + per_frame_bytes`` does not depend on the padding.
    """
    from clholo.fft import next_fft_size
    from clholo.propagation import MAX_FFT_SIZE

    (H, W), (Hp, Wp), cost = grid
    if not callable(cost):
        per_sample = int(cost)

        def cost(hp, wp):
            return per_sample * hp * wp
    rest = int(fixed_bytes) + int(per_frame_bytes) - int(cost(Hp, Wp))

    def padded(factor):
        return (next_fft_size(math.ceil(H * factor - 1e-9)),
                next_fft_size(math.ceil(W * factor - 1e-9)))

    # the padded grid grows in steps, at factors m/H and m/W for FFT sizes m: the largest
    # factor that fits is one of them
    best = None
    for n in (H, W):
        m = next_fft_size(n)
        while m <= MAX_FFT_SIZE:
            factor = m / n
            h, w = padded(factor)
            if factor >= 1 and rest + cost(h, w) <= budget and max(h, w) <= MAX_FFT_SIZE:
                best = factor if best is None else max(best, factor)
            m = next_fft_size(m + 1)
    if best is None:
        return f"not even pad 1 ({'x'.join(map(str, padded(1.0)))}) fits this budget"
    shown = math.floor(best * 100) / 100
    h, w = padded(shown)
    return f"the largest pad this budget holds on this {H}x{W} field is {shown:g} ({h}x{w})"


def frames_per_launch(*, fixed_bytes: int, per_frame_bytes: int, samples_per_frame: int,
                      budget_bytes: Optional[int], device: "cl.Device", what: str,
                      grid: Optional[Grid] = None) -> int:
    """The largest frame count whose ``fixed + n * per_frame`` bytes fit the budget, at most
    as many as carry :func:`device_batch_target` complex samples (``samples_per_frame`` each;
    at least one frame).

    A smaller budget never gives more frames, and ``fixed + n * per_frame`` never exceeds it.

    ``grid`` (see :func:`largest_grid`) lets a refusal say the largest padding that fits.

    Raises
    ------
    MemoryError
        Not even one frame fits: the message gives both sizes and what to change.
    """
    budget = (default_budget(device) if budget_bytes is None
              else validate.count(budget_bytes, name="memory_budget", minimum=1))
    room = budget - int(fixed_bytes)
    if room < per_frame_bytes:
        hint = "" if grid is None else "; " + largest_grid(budget, fixed_bytes, per_frame_bytes,
                                                            grid)
        raise MemoryError(
            f"{what} needs ~{_mib(fixed_bytes + per_frame_bytes)} of device memory for one frame "
            f"({_mib(fixed_bytes)} fixed + {_mib(per_frame_bytes)} per frame) but the budget is "
            f"{_mib(budget)}; pass a larger memory_budget (bytes; the device has "
            f"{_mib(device.global_mem_size)}), or use a smaller field, pad or fewer layers"
            + hint)
    by_memory = room // int(per_frame_bytes)
    by_work = max(1, device_batch_target(device) // max(1, int(samples_per_frame)))
    return int(max(1, min(by_memory, by_work)))


@contextlib.contextmanager
def device_allocation(what: str, nbytes: int, device: "cl.Device") -> Iterator[None]:
    """Turn an OpenCL allocation failure inside the block into a MemoryError naming sizes."""
    try:
        yield
    except cl.Error as exc:
        text = str(exc)
        codes = {getattr(cl.status_code, name, None) for name in _ALLOCATION_FAILURES}
        if not (isinstance(exc, cl.MemoryError) or getattr(exc, "code", None) in codes
                or any(k in text for k in _ALLOCATION_FAILURES)):
            raise
        raise MemoryError(
            f"the device ran out of memory for {what} (~{_mib(nbytes)} asked, device "
            f"{device.name.strip()} with {_mib(device.global_mem_size)}; OpenCL said: "
            f"{text.strip()[:200]}); pass a smaller memory_budget so the work is split into "
            f"more launches, or free device memory held by other arrays") from None
