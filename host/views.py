"""Host loops of the operators on holograms (:mod:`clholo.views`): frames in chunks under a
memory budget, kernels and FFTs enqueued per chunk, one host synchronisation at the end.

Device memory (bytes, complex64) with ``B = Tb C`` fields per chunk and ``(Hp, Wp)`` the padded
grid::

    pupil view    per frame   8 C H W (upload, NumPy input only) + 8 C H W (field)
                              + 16 C Hp Wp (spectrum + FFT work)
                  fixed       16 C Hp Wp (refocus and pupil transfer functions)
                              + 4 A C H W (accumulators)
    light field   per frame   8 C H W (upload, NumPy input only) + 16 C N w^2 (windows + FFT work)
                  fixed       4 C N w^2 (accumulator), N = Ny Nx windows

``Tb`` is the most frames that fit the budget (default: half the device's global memory, the
same rule as :class:`clholo.host.scheduler.HologramRenderer`).
"""

from __future__ import annotations

import contextlib
from typing import Optional

import numpy as np
import pyopencl as cl
import pyopencl.array as cla

from clholo.host import runtime

__all__ = ["frames_per_chunk", "device_allocation", "plan_pupil_views", "pupil_views",
           "light_field"]

_ALLOCATION_CODES = {cl.status_code.MEM_OBJECT_ALLOCATION_FAILURE,
                     cl.status_code.OUT_OF_RESOURCES, cl.status_code.OUT_OF_HOST_MEMORY}


def frames_per_chunk(queue, frames: int, *, per_frame: int, fixed: int,
                     memory_budget: Optional[int], what: str, fix: str = "smaller inputs",
                     grid=None) -> int:
    """The most frames per chunk that keep ``fixed + n per_frame`` bytes under the budget;
    a :class:`MemoryError` naming the sizes and the fix (``fix``: what else to make smaller)
    when not even one frame fits.

    ``grid`` (``((H, W), (Hp, Wp), bytes_per_padded_sample)``, as
    :func:`clholo.host.memory.largest_grid` takes it) adds the largest pad that fits the budget
    to the refusal, as the renderer's and the focal stack's refusals say it."""
    budget = (int(memory_budget) if memory_budget is not None
              else int(queue.device.global_mem_size) // 2)
    room = budget - fixed
    if room < per_frame:
        hint = ""
        if grid is not None:
            from clholo.host.memory import largest_grid

            hint = "; " + largest_grid(budget, fixed, per_frame, grid)
        raise MemoryError(
            f"{what} needs ~{(fixed + per_frame) / 2**20:.1f} MiB of device memory for one frame "
            f"({fixed / 2**20:.1f} MiB fixed + {per_frame / 2**20:.1f} MiB per frame) but "
            f"memory_budget is {budget / 2**20:.1f} MiB; raise memory_budget or use {fix}{hint}")
    return int(max(1, min(frames, room // per_frame)))


@contextlib.contextmanager
def device_allocation(what: str, nbytes: int):
    """Turn an OpenCL allocation failure inside the block into a :class:`MemoryError`."""
    try:
        yield
    except cl.Error as exc:
        code = getattr(exc, "code", None)
        if isinstance(exc, cl.MemoryError) or code in _ALLOCATION_CODES:
            raise MemoryError(
                f"{what}: the device could not allocate its buffers (~{nbytes / 2**20:.1f} MiB "
                f"planned; OpenCL said: {exc}); pass a smaller memory_budget so that fewer "
                f"frames go into one chunk") from exc
        raise


def _chunks(frames: int, per_chunk: int):
    for t0 in range(0, frames, per_chunk):
        yield t0, min(per_chunk, frames - t0)


def _frames_on_device(queue, holograms, t0: int, n: int, staging):
    """Frames ``t0 .. t0+n-1`` of ``holograms`` as a device array (a view of a device input,
    an upload of a NumPy one into ``staging``)."""
    if isinstance(holograms, cla.Array):
        return holograms[t0:t0 + n]
    view = staging[:n]
    view.set(np.ascontiguousarray(holograms[t0:t0 + n]), queue=queue)
    return view


def plan_pupil_views(queue, holograms, *, angles: int, padded,
                     memory_budget: Optional[int]):
    """Frames per chunk of :func:`pupil_views` for ``holograms`` ``[T, C, H, W]`` (NumPy or
    device), ``angles`` pupils and the ``padded`` grid ``(Hp, Wp)``, and the chunk's bytes
    ``(Tb, fixed, per_frame)`` (module docstring). Cheap: :func:`clholo.views.pupil_view` calls
    it before it builds the refocus transfer function, so that a pad beyond the budget is
    refused at once, naming the largest pad that fits."""
    T, C, H, W = holograms.shape
    Hp, Wp = padded
    host_input = not isinstance(holograms, cla.Array)
    per_frame = 8 * C * H * W * (1 + host_input) + 16 * C * Hp * Wp
    fixed = 16 * C * Hp * Wp + 4 * int(angles) * C * H * W
    Tb = frames_per_chunk(queue, T, per_frame=per_frame, fixed=fixed,
                          memory_budget=memory_budget, what="pupil_view",
                          fix="fewer angles or a smaller pad",
                          grid=((H, W), (Hp, Wp), 32 * C))
    return Tb, fixed, per_frame


def pupil_views(queue, holograms, *, pupils: np.ndarray, refocus_tf: "cla.Array",
                padded, square: bool, memory_budget: Optional[int]) -> np.ndarray:
    """Frame-mean intensity ``[A, C, H, W]`` float32 of ``crop(IFFT2(FFT2(pad(u)) * H * A_a))``.

    ``pupils`` is ``[A, C, 4]``: per angle and channel the pupil's centre and half-sizes in
    frequency bins ``(cx, cy, rx, ry)`` (see ``kernels/views.cl``); ``refocus_tf`` is the
    refocus transfer function ``[C, Hp, Wp]``.
    """
    from clholo.elementwise import accumulate_intensity
    from clholo.propagation import _propagator

    T, C, H, W = holograms.shape
    A = pupils.shape[0]
    Hp, Wp = padded
    host_input = not isinstance(holograms, cla.Array)
    Tb, fixed, per_frame = plan_pupil_views(queue, holograms, angles=A, padded=padded,
                                            memory_budget=memory_budget)
    fp64 = runtime.has_fp64(queue.device)
    tf_real = np.float64 if fp64 else np.float32
    defines = {"TF_REAL": "double" if fp64 else "float"}
    if fp64:
        defines["CLHOLO_FP64"] = True
    kern = runtime.get_kernel(queue.context, "views.cl", "pupil_transfer_function",
                              defines=defines)
    with device_allocation("pupil_view", fixed + Tb * per_frame):
        dpupils = [cla.to_device(queue, np.ascontiguousarray(pupils[a], dtype=tf_real))
                   for a in range(A)]
        product = cla.empty(queue, (C, Hp, Wp), np.complex64)
        accs = [runtime.zeros(queue, (C, H, W), np.float32) for _ in range(A)]
        staging = cla.empty(queue, (Tb, C, H, W), np.complex64) if host_input else None
        field = cla.empty(queue, (Tb * C, H, W), np.complex64)
        for t0, n in _chunks(T, Tb):
            chunk = _frames_on_device(queue, holograms, t0, n, staging)
            prop = _propagator(queue, n * C, (H, W), (Hp, Wp), np.complex64)
            out = field[:n * C]
            for a in range(A):
                runtime.launch(kern, queue, (Wp, Hp, C), None, refocus_tf.data, product.data, dpupils[a].data,
                     np.uint32(Hp), np.uint32(Wp), np.int32(bool(square)))
                prop.apply(chunk.reshape((n * C, H, W)), product, out=out)
                accumulate_intensity(out.reshape((n, C, H, W)), accs[a], weight=1.0 / T,
                                     queue=queue)
        return np.stack([acc.get() for acc in accs])


def light_field(queue, holograms, *, window: int, hop: int, hann: bool,
                memory_budget: Optional[int]) -> np.ndarray:
    """STFT light field ``[C, Ny, Nx, w, w]`` float32 (frame mean of ``|FFT2|^2``, bins
    fftshifted)."""
    from clholo.fft import FFTPlan

    T, C, H, W = holograms.shape
    w = int(window)
    Ny, Nx = (H - w) // hop + 1, (W - w) // hop + 1
    N = Ny * Nx
    host_input = not isinstance(holograms, cla.Array)
    per_frame = 8 * C * H * W * host_input + 16 * C * N * w * w
    fixed = 4 * C * N * w * w
    Tb = frames_per_chunk(queue, T, per_frame=per_frame, fixed=fixed,
                          memory_budget=memory_budget, what="light_field",
                          fix="a smaller window or a larger hop")
    windows_k = runtime.get_kernel(queue.context, "views.cl", "stft_windows")
    accumulate_k = runtime.get_kernel(queue.context, "views.cl", "stft_accumulate")
    with device_allocation("light_field", fixed + Tb * per_frame):
        acc = runtime.zeros(queue, (C, Ny, Nx, w, w), np.float32)
        staging = cla.empty(queue, (Tb, C, H, W), np.complex64) if host_input else None
        windows = cla.empty(queue, (Tb * C * N, w, w), np.complex64)
        plans = {}
        for t0, n in _chunks(T, Tb):
            chunk = _frames_on_device(queue, holograms, t0, n, staging)
            win = windows[:n * C * N]
            runtime.launch(windows_k, queue, (w * w, N, n * C), None, chunk.base_data,
                      np.uint64(chunk.offset // 8), win.data, np.uint32(H),
                      np.uint32(W), np.uint32(Nx), np.uint32(w), np.uint32(hop),
                      np.int32(bool(hann)))
            plan = plans.get(n)
            if plan is None:
                plan = plans[n] = FFTPlan((n * C * N, w, w), np.complex64, queue=queue)
            plan.execute(win, out=win)
            runtime.launch(accumulate_k, queue, (w * w, C * N), None, win.data, acc.data,
                         np.float32(1.0 / T), np.uint32(w), np.uint32(n))
        return acc.get()
