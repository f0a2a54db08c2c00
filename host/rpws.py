"""Host launch loop of random-phase wave splatting (docs/rpws.md).

One :class:`RPWSRenderer` per (primitives, optics, seed, padding). For each batch of ``Tb``
frames (all ``C`` colours at once, ``B = Tb C`` fields, all of them on the device)::

    u = 0
    for k = K-1 ... 0 (back to front, one primitive at a time):
        rpws_composite     over k's bounding box only, B fields, phases drawn in place
        if step_k != 0:    build H(step_k) [C, Hp, Wp] on the device into ONE reused buffer
                           u <- crop(IFFT2(FFT2(pad(u)) * H))        (2 fused FFTs, B fields)

With thousands of distinct steps the transfer functions are not cached: each is built, applied
and overwritten by the next (a build costs about one FFT pass over ``C Hp Wp`` samples, against
two whole FFTs over ``B Hp Wp``). Consecutive equal steps reuse the buffer without a rebuild.

The host waits for the device only every ``sync_every`` primitives (and at the end) so that it
can report progress without letting the queue grow by tens of thousands of commands.

Device memory (complex64 bytes): fields ``8 B H W``, spectrum and FFT work ``16 B Hp Wp``,
one transfer function ``8 C Hp Wp``, primitive tables ``4 K (8 + C)``.
"""

from __future__ import annotations

import time
from typing import Callable, Iterator, Optional, Tuple

import numpy as np
import pyopencl as cl
import pyopencl.array as cla

from clholo.host import memory, runtime
from clholo.host.scheduler import PlanSets


class RPWSRenderer:
    """Builds once, renders many times: primitives -> RPWS holograms ``[T, C, H, W]``.

    Parameters
    ----------
    primitives : clholo.baselines.rpws.Primitives
        Nearest first, depths in metres (already merged if merging is wanted).
    optics : clholo.Optics
        One wavelength per colour channel of the primitives.
    seed : int
        Key of the Philox phase stream, in [0, 2^64).
    pad : "auto", float or (int, int)
        One padded grid (sides ``2^a 3^b 5^c``) for every step (the largest any of them needs).
    band_limit : bool
    alpha_max, alpha_min : float
        Footprint clamp and cut (see ``kernels/rpws.cl``).
    memory_budget : int, optional
        Bytes of device memory to plan for (default half of the device's).
    frames_per_batch : int, optional
    sync_every : int
        Primitives between host waits (progress reports).
    queue : pyopencl.CommandQueue, optional
    """

    def __init__(self, primitives, optics, *, seed: int = 0, pad="auto", band_limit: bool = True,
                 alpha_max: float = 0.99, alpha_min: float = 1.0 / 255.0,
                 memory_budget: Optional[int] = None, frames_per_batch: Optional[int] = None,
                 sync_every: int = 32, queue: Optional["cl.CommandQueue"] = None):
        from clholo import reference, validate
        from clholo.propagation import ASMPropagator, device_padded_shape

        self.queue = queue if queue is not None else runtime.get_queue()
        self.primitives = primitives
        self.optics = optics
        if primitives.channels != optics.channels:
            raise ValueError(
                f"the primitives have {primitives.channels} colour channel(s) but optics has "
                f"{optics.channels} wavelength(s); give one wavelength per channel")
        self.seed = validate.seed(seed)
        self.key = reference.seed_key(self.seed)
        self.band_limit = validate.flag(band_limit, name="band_limit")
        self.alpha_max, self.alpha_min = validate.alpha_cut(alpha_max, alpha_min)
        self.sync_every = validate.count(sync_every, name="sync_every")
        K, (H, W), C = len(primitives), primitives.shape, primitives.channels
        if K >= 2 ** 32:
            raise ValueError(f"{K} primitives: the phase counter holds at most 2**32 - 1")
        self.shape = (H, W)
        self.steps = reference.layer_steps(primitives.depths)
        nonzero = self.steps[self.steps != 0]
        self.padded = device_padded_shape((H, W), nonzero if nonzero.size else [0.0],
                                          wavelength=optics.wavelengths, pitch=optics.pitch,
                                          pad=pad)
        Hp, Wp = self.padded
        device_mem = int(self.queue.device.global_mem_size)
        self.memory_budget = int(memory_budget) if memory_budget is not None else device_mem // 2
        fixed = 8 * C * Hp * Wp + 4 * K * (8 + C)
        per_frame = 8 * C * H * W + 16 * C * Hp * Wp
        room = self.memory_budget - fixed
        if room < per_frame:
            from clholo.host.memory import largest_grid

            raise MemoryError(
                f"one RPWS frame needs ~{(fixed + per_frame) / 2**20:.0f} MiB of device memory "
                f"(padded grid {Hp}x{Wp}) but the budget is {self.memory_budget / 2**20:.0f} "
                f"MiB; use a smaller image or pad, or a larger memory_budget; "
                + largest_grid(self.memory_budget, fixed, per_frame,
                               ((H, W), (Hp, Wp), 8 * C + 16 * C)))
        # the one batch target of every scheduler, by the device's kind (host/memory.py)
        by_work = max(1, memory.device_batch_target(self.queue.device) // (C * Hp * Wp))
        self.frames_per_batch = int(max(1, min(room // per_frame, by_work)))
        if frames_per_batch is not None:
            self.frames_per_batch = validate.count(frames_per_batch, name="frames_per_batch")
        self.boxes = reference.rpws_boxes(primitives.xy, primitives.radius, (H, W))
        params = np.zeros((max(K, 1), 8), np.float32)
        params[:K, 0:2] = primitives.xy
        params[:K, 2:5] = primitives.conic
        params[:K, 5] = primitives.opacity
        colors = np.zeros((max(K, 1), C), np.float32)
        colors[:K] = primitives.color
        q = self.queue
        self._params = cla.to_device(q, params)
        self._colors = cla.to_device(q, colors)
        self._tf = cla.empty(q, (C, Hp, Wp), np.complex64)
        self._tf_dz = None
        # FFT plans and work buffers per batch size: two at most (the scheduler's PlanSets)
        self._propagators = PlanSets()
        self._ASMPropagator = ASMPropagator
        # a kernel object of our own: its arguments are set once and only k and the box change
        self._kernel = cl.Kernel(runtime.build_program(q.context, "rpws.cl"), "rpws_composite")

    # ---------------------------------------------------------------------------------------
    def _propagator(self, frames: int):
        """The propagator of a batch of ``frames`` frames (two batch sizes kept at most)."""
        return self._propagators.get(frames, self._make_propagator,
                                     pinned=self.frames_per_batch)

    def _make_propagator(self, frames: int):
        return self._ASMPropagator(frames * self.primitives.channels, self.shape,
                                   self.padded, queue=self.queue)

    def prepare(self, frames: int) -> None:
        """Build every OpenCL program rendering ``frames`` frames needs (the FFT plans of each
        batch size, the transfer-function kernel; the splat kernel is built with the
        renderer), rendering nothing: commands time the builds apart from the render."""
        from clholo import validate
        from clholo.propagation import transfer_function_kernel

        T = validate.count(frames, name="frames")
        Tb = min(self.frames_per_batch, T)
        for n in sorted({Tb, T % Tb} - {0}):
            self._propagator(n)
        transfer_function_kernel(self.queue, np.complex64)

    def _transfer_function(self, dz: float) -> "cla.Array":
        """The step's ``[C, Hp, Wp]`` transfer functions, built into the one reused buffer."""
        from clholo.propagation import build_transfer_function

        if self._tf_dz != dz:
            build_transfer_function(self.queue, self.padded, dz,
                                    wavelengths=self.optics.wavelengths, pitch=self.optics.pitch,
                                    band_limit=self.band_limit, out=self._tf)
            self._tf_dz = dz
        return self._tf

    def enqueue_primitive(self, k: int, field: "cla.Array", prop) -> None:
        """Composite primitive ``k`` onto ``field [Tb, C, H, W]`` and propagate by its step
        (the kernel's other arguments, the frame offset among them, come from :meth:`_bind`)."""
        x0, y0, x1, y1 = (int(v) for v in self.boxes[k])
        if x1 > x0 and y1 > y0:
            kern = self._kernel
            kern.set_arg(3, np.uint32(k))
            kern.set_arg(4, np.int32(x0))
            kern.set_arg(5, np.int32(y0))
            kern.set_arg(6, np.uint32(x1 - x0))
            kern.set_arg(7, np.uint32(y1 - y0))
            runtime.enqueue_nd_range(self.queue, kern,
                                       (x1 - x0, y1 - y0, field.shape[0] * field.shape[1]),
                                       None)
        dz = float(self.steps[k])
        if dz != 0.0:  # a zero step is the identity on the grid (all frequencies propagate)
            flat = field.reshape((field.shape[0] * field.shape[1],) + self.shape)
            prop.apply(flat, self._transfer_function(dz), out=flat, tf_even=True)

    def _bind(self, field: "cla.Array", frame0: int) -> None:
        H, W = self.shape
        C = self.primitives.channels
        kern = self._kernel
        kern.set_arg(0, field.data)
        kern.set_arg(1, self._params.data)
        kern.set_arg(2, self._colors.data)
        kern.set_arg(8, np.uint32(W))
        kern.set_arg(9, np.uint32(H * W))
        kern.set_arg(10, np.uint32(C))
        kern.set_arg(11, np.uint32(frame0))
        kern.set_arg(12, self.key[0])
        kern.set_arg(13, self.key[1])
        kern.set_arg(14, np.float32(self.alpha_max))
        kern.set_arg(15, np.float32(self.alpha_min))

    def render(self, frames: int, *, out: Optional["cla.Array"] = None,
               progress: Optional[Callable[[int, int], None]] = None) -> "cla.Array":
        """All ``frames`` holograms on the device, complex64 ``[T, C, H, W]``.

        ``progress(done, total)`` is called with primitive-steps done (over all batches)
        after every host wait.
        """
        from clholo import validate

        T = validate.count(frames, name="frames")
        (H, W), C = self.shape, self.primitives.channels
        if out is None:
            out = cla.empty(self.queue, (T, C, H, W), np.complex64)
        elif out.shape != (T, C, H, W) or out.dtype != np.complex64:
            raise ValueError(f"out must be complex64 {(T, C, H, W)}, got {out.dtype} {out.shape}")
        self.enqueue_frames(0, T, out, progress=progress)
        self.queue.finish()
        return out

    def enqueue_frames(self, frame0: int, frames: int, out: "cla.Array", *,
                       progress: Optional[Callable[[int, int], None]] = None) -> "cla.Array":
        """Render frames ``frame0 .. frame0+frames-1`` into ``out`` (complex64
        ``[frames, C, H, W]`` on this renderer's device), in batches of at most
        :attr:`frames_per_batch` frames; returns ``out``.

        The device-side twin of :meth:`iter_frames`: frame ``t`` is the same hologram, bit for
        bit, whatever ``frame0`` and the batching. The host waits for the device every
        ``sync_every`` primitives and after each batch (``progress(done, total)`` is called
        then), as :meth:`render` does.
        """
        from clholo import validate

        frame0, T = validate.frame_range(frame0, frames, start_name="frame0")
        (H, W), C = self.shape, self.primitives.channels
        if not isinstance(out, cla.Array) or out.shape != (T, C, H, W) or \
                out.dtype != np.complex64 or not out.flags.c_contiguous:
            raise ValueError(f"out must be a C-contiguous complex64 device array "
                             f"{(T, C, H, W)}, got {getattr(out, 'dtype', type(out).__name__)} "
                             f"{getattr(out, 'shape', '')}")
        frame_bytes = C * H * W * 8
        direct = T <= self.frames_per_batch and out.offset == 0
        for t0, n, field in self._iter_device_batches(T, frame0, progress,
                                                      into=out if direct else None):
            if not direct:
                cl.enqueue_copy(self.queue, out.base_data, field.data,
                                dst_offset=out.offset + (t0 - frame0) * frame_bytes,
                                byte_count=n * frame_bytes)
        return out

    def iter_frames(self, frames: int, *, start: int = 0,
                    progress: Optional[Callable[[int, int], None]] = None
                    ) -> Iterator[Tuple[int, np.ndarray]]:
        """Yield ``(t0, holograms)``, NumPy complex64 ``[n, C, H, W]`` for frames
        ``t0 .. t0+n-1`` (absolute indices from ``start``), as each batch finishes.

        Frame ``t`` is the same hologram whatever the batching and ``start``: its phases depend
        on the absolute frame index (the same stream as :meth:`render`).

        Parameters
        ----------
        frames : int
            Number of frames (>= 1).
        start : int
            Absolute index of the first frame; ``start + frames`` at most ``2**32``.
        progress : callable ``(done, total)``, optional
            Called with primitive-steps done after every host wait.

        Returns
        -------
        iterator of (int, numpy.ndarray)
            The batches, made one at a time.

        Raises
        ------
        clholo.errors.InputTypeError, clholo.errors.InputError
            At the call, before any work: counts that are not whole numbers, or frames beyond
            the phase stream (the kernel's ``uint`` frame counter wrapped, and frame ``2**32``
            was frame 0 again without a word).
        """
        from clholo import validate

        start, T = validate.frame_range(start, frames)
        return self._iter_host_batches(T, start, progress)

    def _iter_host_batches(self, T: int, start: int, progress):
        """:meth:`iter_frames` once its arguments are checked."""
        for t0, n, field in self._iter_device_batches(T, start, progress):
            yield t0, field.get()

    def _iter_device_batches(self, T: int, start: int, progress, into=None):
        """``(t0, n, field)`` per batch of frames ``start ..``, the batch enqueued into a fresh
        zeroed field (or into ``into``, all ``T`` frames in one batch)."""
        from clholo import validate

        # the callers check this before any work; here too, so that no way in reaches the
        # kernel's uint frame counter with frames it would wrap to frame 0's phases
        validate.frame_range(start, T)
        K, (H, W), C = len(self.primitives), self.shape, self.primitives.channels
        Tb = min(self.frames_per_batch, T)
        # batches made as they come, not listed first (a long display run's frames)
        total = K * -(-T // Tb)
        done = 0
        for t0 in range(0, T, Tb):
            n = min(Tb, T - t0)
            if into is not None:
                field = into
                with runtime.pyopencl_op():  # pyopencl's shared fill kernel: see pyopencl_op
                    field.fill(0)
            else:
                field = runtime.zeros(self.queue, (n, C, H, W), np.complex64)
            prop = self._propagator(n)
            self._bind(field, start + t0)
            for k in range(K - 1, -1, -1):
                self.enqueue_primitive(k, field, prop)
                done += 1
                if done % self.sync_every == 0:
                    self.queue.finish()
                    if progress is not None:
                        progress(done, total)
            self.queue.finish()
            if progress is not None:
                progress(done, total)
            yield start + t0, n, field

    def time_per_primitive(self, frames: int, *, primitives: int = 64) -> dict:
        """Seconds per primitive-step at this size, measured over the ``primitives`` farthest
        primitives of one batch of ``frames`` frames (host wall clock after a warm-up)."""
        K = len(self.primitives)
        n = min(K, int(primitives))
        Tb = min(self.frames_per_batch, int(frames))
        field = runtime.zeros(self.queue, (Tb,) + (self.primitives.channels,) + self.shape,
                          np.complex64)
        prop = self._propagator(Tb)
        self._bind(field, 0)
        self.enqueue_primitive(K - 1, field, prop)  # warm-up: builds, first launches
        self.queue.finish()
        t = time.perf_counter()
        for k in range(K - 1, K - 1 - n, -1):
            self.enqueue_primitive(k, field, prop)
        self.queue.finish()
        seconds = time.perf_counter() - t
        return {"seconds_per_primitive": seconds / n, "frames": Tb,
                "colours": self.primitives.channels, "padded": self.padded, "primitives": n}
