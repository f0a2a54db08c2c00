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

from clholo import validate
from clholo._arrays import (check_context, check_finite_result, check_holograms, fetch,
                            host_result, resolve_queue, to_device_readonly)
from clholo.host import runtime
from clholo.host.scheduler import HologramRenderer
from clholo.scene import MPI, Optics

__all__ = ["render_hologram", "iter_hologram_frames", "hologram_padded_shape", "focal_stack",
           "HologramRenderer"]


def render_hologram(mpi: MPI, optics: Optics, *, frames: int = 24, seed: int = 0, pad="auto",
                    band_limit: bool = True, memory_budget: Optional[int] = None,
                    out: Optional["cla.Array"] = None,
                    queue: Optional["cl.CommandQueue"] = None):
    r"""Random-phase MPI holograms at the hologram plane, ``[T, C, H, W]`` complex64.

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
        Padding of each propagation (a grid of ``2^a 3^b 5^c`` sizes; see
        :mod:`clholo.propagation`).
        :func:`hologram_padded_shape` tells the grid it resolves to.
    band_limit : bool
        Apply the Matsushima-Shimobaba band limit to every step (default).
    memory_budget : int, optional
        Bytes of device memory the renderer may plan for (default: half of the device's); it
        sets how many frames go into one launch (:class:`HologramRenderer`).
    out : pyopencl.array.Array, optional
        Device array ``[T, C, H, W]`` complex64 to render into (and return). Without it the
        holograms come back as a NumPy array.
    queue : pyopencl.CommandQueue, optional
        Queue to run on (default: clholo's default device, ``CLHOLO_DEVICE``).

    Returns
    -------
    numpy.ndarray or pyopencl.array.Array (``out``), complex64 ``[T, C, H, W]``

    Notes
    -----
    The paper's recursion (``docs/conventions.md``), per colour of wavelength :math:`\lambda`
    and frame :math:`t`, back to front from the farthest layer :math:`L` with :math:`u = 0` and
    :math:`d_0 = 0`:

    .. math::

        v = \sqrt{1 - \alpha_i}\, u + \sqrt{c_i \alpha_i}\, e^{i \phi_{i,t}}, \qquad
        u \leftarrow \mathrm{ASM}(v,\ d_i - d_{i-1}), \qquad i = L, \ldots, 1,

    with :math:`c_i` the layer's linear intensity, :math:`\alpha_i` its opacity and
    :math:`\phi_{i,t}` uniform on :math:`[0, 2\pi)` from the Philox stream keyed by ``seed``.
    A viewer sees the mean over frames, :math:`I = \frac{1}{T} \sum_t |O(u_t)|^2`.
    """
    band_limit = validate.flag(band_limit, name="band_limit")
    renderer = HologramRenderer(mpi, optics, seed=seed, pad=pad, band_limit=band_limit,
                                memory_budget=memory_budget, queue=validate.queue(queue))
    if out is not None:
        return renderer.render(frames, out=out)
    # NumPy out: on a CPU device the frames are written into it in place (no download)
    from clholo.host.memory import available_host_bytes

    shape = (validate.count(frames, name="frames"), mpi.channels) + tuple(mpi.shape)
    nbytes = float(np.prod(shape, dtype=np.float64)) * 8

    def too_big(free: int) -> MemoryError:
        return MemoryError(
            f"frames={shape[0]} holograms of {shape[1]}x{shape[2]}x{shape[3]} complex64 need "
            f"{nbytes / 2**30:.3g} GiB, more than the memory available ({free / 2**30:.3g} "
            f"GiB: free, within any ulimit -v): render fewer frames, or take them a batch at a time with "
            f"iter_hologram_frames")

    free = available_host_bytes()
    if nbytes > free:               # refused before anything is allocated or rendered
        raise too_big(free)
    try:
        host, dev = host_result(renderer.queue, shape, np.complex64)
    except MemoryError:
        raise too_big(available_host_bytes()) from None
    renderer.render(frames, out=dev)
    return fetch(host, dev)


def iter_hologram_frames(mpi: MPI, optics: Optics, *, frames: int = 24, seed: int = 0,
                         pad="auto", band_limit: bool = True,
                         frames_per_batch: Optional[int] = None,
                         memory_budget: Optional[int] = None,
                         queue: Optional["cl.CommandQueue"] = None
                         ) -> Iterator[Tuple[int, np.ndarray]]:
    """Yield ``(t0, holograms[n, C, H, W])`` as each batch of frames finishes.

    The device already computes the next batch while the caller handles this one. Frames are
    identical to :func:`render_hologram`'s with the same seed. ``frames_per_batch`` (>= 1) fixes
    the batch size; by default it follows ``memory_budget`` (bytes, default half the device's).

    Parameters
    ----------
    mpi : MPI
        ``L`` layers ``(H, W)`` with ``C`` channels, depths in metres behind the hologram.
    optics : Optics
        Pitch (metres) and ``C`` wavelengths (metres).
    frames : int
        ``T``, the number of frames to yield in all.
    seed : int
        Key of the phase stream (the same as :func:`render_hologram`'s).
    pad : "auto", float or (int, int)
        Padding of each propagation: ``"auto"`` (what the band-limited kernel's spread needs),
        a factor per axis, or the padded grid ``(Hp, Wp)`` itself (sizes ``2^a 3^b 5^c``).
    band_limit : bool
        Apply the Matsushima-Shimobaba band limit to every step (default).
    frames_per_batch : int, optional
        Frames per yielded batch (>= 1); default from ``memory_budget``.
    memory_budget : int, optional
        Bytes of device memory to plan for (default: half of the device's).
    queue : pyopencl.CommandQueue, optional
        Queue to run on (default: clholo's default device, ``CLHOLO_DEVICE``).
    """
    band_limit = validate.flag(band_limit, name="band_limit")
    # before the renderer uploads anything: frames beyond the phase stream are refused whole
    _, frames = validate.frame_range(0, frames)
    renderer = HologramRenderer(mpi, optics, seed=seed, pad=pad, band_limit=band_limit,
                                memory_budget=memory_budget, frames_per_batch=frames_per_batch,
                                queue=validate.queue(queue))
    yield from renderer.iter_frames(frames, frames_per_batch=frames_per_batch)


def hologram_padded_shape(mpi: MPI, optics: Optics, *, pad="auto") -> Tuple[int, int]:
    """The padded grid ``(Hp, Wp)`` (sizes ``2^a 3^b 5^c``) every propagation of ``render_hologram`` uses
    (give it to ``clholo.reference`` as ``pad=(Hp, Wp)`` to compare).

    Parameters
    ----------
    mpi : MPI
        The scene: its shape and its deepest step set the grid.
    optics : Optics
        Pitch and wavelengths, metres.
    pad : "auto", float or (int, int)
        Padding of each propagation: ``"auto"`` (what the band-limited kernel's spread needs),
        a factor per axis, or the padded grid ``(Hp, Wp)`` itself (sizes ``2^a 3^b 5^c``).
    """
    from clholo import reference
    from clholo.propagation import device_padded_shape

    return device_padded_shape(mpi.shape, reference.layer_steps(mpi.depths),
                               wavelength=optics.wavelengths, pitch=optics.pitch, pad=pad)


#: Largest hologram amplitude :func:`focal_stack` takes (its float32 intensities overflow
#: far beyond: a focus gathers up to ``sqrt(H W)`` times the amplitude).
FOCAL_STACK_MAX_AMPLITUDE = 1e15


def focal_stack(holograms, optics: Optics, depths: Sequence[float], *, pad="auto",
                band_limit: bool = True, memory_budget: Optional[int] = None,
                queue: Optional["cl.CommandQueue"] = None) -> np.ndarray:
    """Frame-averaged intensity focused at each depth: ``[D, C, H, W]`` float32.

    ``I_d = mean_t |ASM(u_t, -d)|^2`` per colour (HOLOGRAPHY.md section 5), computed on the
    device, frames in chunks so that memory does not grow with ``T``.

    Parameters
    ----------
    holograms : array ``[T, C, H, W]`` complex64 (NumPy or device)
    optics : Optics
        One wavelength per channel ``C``.
    depths : sequence of float
        Metres behind the hologram plane (> 0 looks into the scene).
    pad : "auto", float or (int, int)
        One padded grid for every depth (the largest any needs).
    band_limit : bool
    memory_budget : int, optional
        Bytes of device memory this may plan for (default: half of the device's). Per chunk of
        ``Tc`` frames it uses ``8 Tc C (H W + 2 Hp Wp)`` bytes (fields, spectrum, FFT work),
        plus ``4 D C H W`` for the accumulators, plus the transfer functions (cached) and, for
        NumPy input, nothing more: each chunk is uploaded when it is needed.
    queue : pyopencl.CommandQueue, optional
        Queue to run on (default: clholo's default device, ``CLHOLO_DEVICE``).

    Raises
    ------
    MemoryError
        One frame does not fit the budget, or the device fails an allocation; the message gives
        the sizes and the fix.
    """
    from clholo import validate
    from clholo.elementwise import accumulate_intensity
    from clholo.host.memory import (available_host_bytes, default_budget, device_allocation,
                                    frames_per_launch)
    from clholo.propagation import (_propagator, device_padded_shape,
                                    transfer_function_cache)

    queue = resolve_queue(validate.queue(queue), holograms)
    T, C, H, W = check_holograms(holograms, optics)
    check_context(queue, holograms, name="holograms")
    if isinstance(holograms, np.ndarray):
        largest = float(np.abs(holograms).max())
        if largest > FOCAL_STACK_MAX_AMPLITUDE:
            # a focus gathers up to sqrt(H W) times the amplitude: its square would pass
            # float32's 3.4e38 and the stack hold inf and NaN without a word
            raise ValueError(f"holograms reach an amplitude of {largest:.3g}, beyond "
                             f"{FOCAL_STACK_MAX_AMPLITUDE:g}: their intensities would overflow "
                             f"float32; divide them by their largest amplitude first (the "
                             f"stack scales with its square)")
    band_limit = validate.flag(band_limit, name="band_limit")
    d = validate.depths(depths, positive=False)
    padded = device_padded_shape((H, W), -d, wavelength=optics.wavelengths, pitch=optics.pitch,
                                 pad=pad)
    Hp, Wp = padded
    device = queue.device
    # the stack itself is on the device and on the host whatever the chunks: too many depths
    # are said as such (the chunk plan's refusal speaks of layers and pads)
    stack_bytes = 4 * d.size * C * H * W
    budget = (default_budget(device) if memory_budget is None
              else validate.count(memory_budget, name="memory_budget", minimum=1))
    room = min(budget, available_host_bytes())
    if stack_bytes > room:
        given = memory_budget is not None and budget <= room
        raise MemoryError(
            f"a focal stack of {d.size} depths holds {d.size} x {C} x {H} x {W} float32 "
            f"intensities ({stack_bytes / 2**30:.3g} GiB) on the device and on the host, more "
            f"than the {room / 2**30:.3g} GiB there is room for"
            + (f" (memory_budget={budget})" if given else "")
            + ": use fewer depths (or a few at a time)"
            + (", or a larger memory_budget" if given else ""))
    Tc = frames_per_launch(
        fixed_bytes=4 * d.size * C * H * W + 8 * C * Hp * Wp,
        # a NumPy input's chunk is uploaded too: one more field per frame
        per_frame_bytes=8 * C * (H * W * (2 if isinstance(holograms, np.ndarray) else 1)
                                 + 2 * Hp * Wp),
        samples_per_frame=C * Hp * Wp, budget_bytes=memory_budget, device=device,
        what=f"a focal stack of {T} frame(s) x {C} colour(s) on a {Hp}x{Wp} grid",
        grid=((H, W), (Hp, Wp), 8 * C + 16 * C))
    Tc = min(Tc, T)
    cache = transfer_function_cache(queue.context)
    out = np.empty((d.size, C, H, W), np.float32)
    with device_allocation(f"focal stack chunks of {Tc} frame(s) on a {Hp}x{Wp} grid",
                           8 * Tc * C * (H * W + 2 * Hp * Wp), device):
        acc = [runtime.zeros(queue, (C, H, W), np.float32) for _ in range(d.size)]
        field = cla.empty(queue, (Tc * C, H, W), np.complex64)
        staged = None
        frame_bytes = C * H * W * 8
        for t0 in range(0, T, Tc):
            n = min(Tc, T - t0)
            if isinstance(holograms, np.ndarray):
                # read in place on CPU devices (a contiguous slice of frames), else uploaded
                chunk, _ = to_device_readonly(queue, holograms[t0:t0 + n], name="holograms")
            elif n == T:
                chunk = holograms
            else:  # a device array's frames t0.. start at a byte offset: copy them out
                if staged is None or staged.shape[0] != n:
                    staged = cla.empty(queue, (n, C, H, W), np.complex64)
                cl.enqueue_copy(queue, staged.data, holograms.base_data,
                                src_offset=holograms.offset + t0 * frame_bytes,
                                byte_count=n * frame_bytes)
                chunk = staged
            prop = _propagator(queue, n * C, (H, W), padded, np.complex64)
            fields = field if n == Tc else cla.empty(queue, (n * C, H, W), np.complex64)
            for k, depth in enumerate(d):
                tf = cache.get(queue, padded, -float(depth), wavelengths=optics.wavelengths,
                               pitch=optics.pitch, band_limit=band_limit, dtype=np.complex64)
                prop.apply(chunk.reshape((n * C, H, W)), tf, out=fields, tf_even=True)
                accumulate_intensity(fields.reshape((n, C, H, W)), acc[k], weight=1.0 / T,
                                     queue=queue)
        for k in range(d.size):
            acc[k].get(ary=out[k])
    return check_finite_result(out, holograms, what="focal stack")
