"""The real-time display loop: render -> encode -> upload, double-buffered.

Two threads share one hand-over slot:

* the **producer** renders batch ``k+1`` (``n`` time-multiplexed frames, all colours) on the
  OpenCL device with the renderer of a method of :data:`clholo.methods.METHODS` (``mpi`` by
  default; any method, since every renderer writes frames by absolute index into a device
  buffer, ``enqueue_frames``), encodes it to 8-bit phase patterns (``encode``, given the frames
  where they lie, on the device: the encoders here code and quantise there too, so only the
  uint8 patterns come back to the host), centres them on the SLM, puts them in the slot, and
  waits until the consumer has taken them before it starts batch ``k+2``: one batch on screen,
  one being made (double buffering), so latency stays at one batch;
* the **consumer** (the caller's thread) shows the patterns of the batch it holds colour after
  colour, one per refresh (colour-sequential: t0 c0, t0 c1, t0 c2, t1 c0, ...), and takes the next
  batch as soon as it is there. If the next batch is late it shows the current one again (the
  SLM never goes dark) and marks those patterns ``repeated``.

With a :class:`DeviceEncoder` (the encoders here) the producer is pipelined: it keeps
:data:`PIPELINE_DEPTH` chunks enqueued on the device (render, coding, read of the uint8
patterns into page-locked memory), so the device renders the next chunk while the host waits
for, centres and hands over this one; and when the display is waiting for a batch (the
producer is the slower), the next batch's first chunk is enqueued before this batch's last
chunk is read back. When the display is the slower, a batch is still started only once the one
before is on screen.

A batch is rendered and encoded in chunks of at most :data:`RENDER_CHUNK` frames (the
patterns are the same, frame by frame, as one call for the whole batch would give), so that a
run with ``seconds`` ends in about a chunk's time: the producer starts no chunk once the time is
up or the loop stops, and the consumer checks the time after every pattern it shows, so a batch
of many frames (``--frames 1000``) is not shown to its end after ``seconds`` have passed.

A new scene (:meth:`DisplayLoop.set_scene`) is picked up by the producer before its next batch:
the loop does not stop, the frame counter (and so the phase stream) goes on.

Every pattern shown is one row of the log (:meth:`DisplayLoop.write_log`, CSV): when its batch
started rendering and was ready, when it was shown, its latency (shown - render start), the
interval since the previous swap, and whether it was dropped (the interval exceeded 1.5 refresh
periods: a missed vertical blank) or repeated.
"""

from __future__ import annotations

import collections
import contextlib
import csv
import os
import threading
import time
from pathlib import Path
from typing import Callable, List, NamedTuple, Optional, Union

import numpy as np

__all__ = ["DisplayLoop", "PatternRecord", "DeviceEncoder", "phase_quantize_encoder",
           "dpac_encoder", "centre_on",
           "summarize", "write_pattern_log", "resample_mpi", "check_batch_memory", "RENDER_CHUNK",
           "PIPELINE_DEPTH", "batch_show_seconds"]

#: frames rendered and encoded per device call of the producer: between two chunks it checks
#: whether the loop stopped or its time is up, so a large batch cannot hold a run past its end
RENDER_CHUNK = 8

#: chunks a pipelined producer keeps enqueued on the device: while the host waits for one
#: chunk's patterns, the next is queued behind it, so the device works while the host centres
#: the patterns and hands them over (``DisplayLoop(pipeline=...)``)
PIPELINE_DEPTH = 2


def batch_show_seconds(frames_per_batch: int, channels: int, refresh_hz: float) -> float:
    """Seconds a display refreshing at ``refresh_hz`` takes to show one batch, colour after
    colour, one pattern per refresh: ``frames_per_batch * channels / refresh_hz``."""
    return frames_per_batch * channels / float(refresh_hz)


class DeviceEncoder:
    """An encoder whose work the display loop can overlap with the host's: ``encode(fields)``
    codes complex fields into uint8 patterns and returns them (NumPy), and
    ``encode.enqueue(fields, out=...)`` only enqueues that work and the read of the patterns
    into ``out`` and returns a :class:`clholo.encode.quantize.PendingPatterns` at once.

    :class:`DisplayLoop` uses :meth:`enqueue` where an encoder has it (its ``pipeline``
    option): it enqueues the next chunk's render and coding before it waits for this chunk's
    patterns, and reads them into page-locked memory (:func:`clholo.host.memory.pinned_empty`),
    so the device works while the host centres the patterns and hands them over. Any other
    callable ``encode(fields) -> uint8 array`` is called and waited for, chunk after chunk.
    :func:`phase_quantize_encoder` and :func:`dpac_encoder` make these.
    """

    def __init__(self, code: Callable, quantizer_for: Callable, what: str, *, queue=None):
        self._code = code                    # (fields, allocator) -> device float32 phases
        self._quantizer_for = quantizer_for  # colours -> DeviceQuantizer
        self.what = what
        self.queue = queue                   # where it enqueues; None: the fields' queue
        self._pools = {}                     # context handle -> its device memory pool

    def __repr__(self) -> str:
        return f"<DeviceEncoder {self.what}>"

    def enqueue(self, fields, *, out: Optional[np.ndarray] = None):
        """Enqueue the coding of ``fields`` (pyopencl complex64 ``[n, C, h, w]``, used where
        they lie, or NumPy, uploaded) and the read of the uint8 patterns into ``out`` (NumPy
        uint8 ``[n, C, h, w]``, C-contiguous; default a new array); returns a
        :class:`~clholo.encode.quantize.PendingPatterns`. The fields may be overwritten by
        commands enqueued later on the same (in-order) queue.

        The device arrays it makes for each call (fields coded, phases, levels) come from a
        memory pool of the encoder's, one per OpenCL context: the next call reuses them instead
        of allocating and freeing device memory every batch (some drivers free only once the
        device is idle, which would stall the pipeline). Reuse is safe because every command of
        a call is enqueued on one in-order queue: one call at a time per encoder and queue."""
        allocator = self._allocator(fields)     # the phases lie on the same queue
        phase = self._code(fields, allocator)
        return self._quantizer_for(phase.shape[-3]).enqueue_read(phase, out=out,
                                                                 allocator=allocator)

    def _allocator(self, array):
        """This encoder's memory pool for the context of ``array``'s queue (or its own)."""
        import pyopencl as cl
        import pyopencl.tools as cl_tools

        from clholo._arrays import resolve_queue

        queue = self.queue if self.queue is not None else (
            array.queue if isinstance(getattr(array, "queue", None), cl.CommandQueue)
            else resolve_queue(None))
        pool = self._pools.get(queue.context.int_ptr)
        if pool is None:
            # an immediate allocator: a pool must learn of an allocation failure at once
            pool = self._pools[queue.context.int_ptr] = cl_tools.MemoryPool(
                cl_tools.ImmediateAllocator(queue))
        return pool

    def __call__(self, fields) -> np.ndarray:
        """The uint8 patterns of ``fields`` (NumPy ``[n, C, h, w]``), waited for."""
        return self.enqueue(fields).wait()


def phase_quantize_encoder(gray_2pi: int = 255, *, queue=None) -> DeviceEncoder:
    """A phase-only encoding: the phase ``P`` of each field quantised as in HOLOGRAPHY.md
    section 8 (the kinoform of the random-phase hologram), through the linear lookup table
    ``linear:N``, ``N = gray_2pi`` the gray level that gives ``2 pi``: the nearest level
    ``2 pi g / N`` to ``wrap(P)`` on the circle, i.e. ``round(wrap(P) / (2 pi) * N) mod N`` (a
    tie goes to the lower level).

    Both steps run on the device: ``P = atan2`` (``kernels/encode.cl`` ``field_angle``, float32)
    and the 8-bit quantisation (:class:`clholo.encode.quantize.DeviceQuantizer`, bit for bit
    ``PhaseLUT.linear(N).to_gray`` of those float32 phases); only the uint8 patterns are read
    back. ``fields`` may be pyopencl arrays (used where they lie) or NumPy arrays (converted to
    complex64 and uploaded to ``queue``), ``[n, C, H, W]``; calling the encoder returns NumPy
    uint8 ``[n, C, H, W]`` (:class:`DeviceEncoder`: ``enqueue`` returns at once). The device's
    ``atan2`` may differ from NumPy's ``np.angle`` in the last bit, so a pixel whose phase sits
    on a level boundary may differ by one level from quantising ``np.angle`` on the host."""
    from clholo import validate
    from clholo.encode.quantize import DeviceQuantizer, PhaseLUT

    n2pi = validate.count(gray_2pi, name="gray_2pi", minimum=2, maximum=256)
    queue = validate.queue(queue)
    lut = PhaseLUT.linear(n2pi)
    quantizers = {}   # colours -> DeviceQuantizer (its tables are built once)

    def quantizer_for(C: int):
        quantizer = quantizers.get(C)
        if quantizer is None:
            quantizer = quantizers[C] = DeviceQuantizer(lut, C)
        return quantizer

    def _field_angle(fields, allocator=None):
        import pyopencl.array as cla

        from clholo._arrays import resolve_queue
        from clholo.host import runtime
        from clholo.host.phase_retrieval import encode_kernel

        if not isinstance(fields, cla.Array):
            fields = cla.to_device(resolve_queue(queue),
                                   np.ascontiguousarray(fields, np.complex64))
        if fields.dtype != np.complex64 or fields.ndim != 4 or not fields.flags.c_contiguous:
            raise ValueError(f"fields must be C-contiguous complex64 [n, C, H, W], got "
                             f"{fields.dtype} {fields.shape}")
        q = fields.queue
        phase = cla.empty(q, fields.shape, np.float32, allocator=allocator)
        runtime.launch(encode_kernel(q.context, "field_angle"), q, (fields.size,), None,
                       fields.data, phase.data)
        return phase

    return DeviceEncoder(_field_angle, quantizer_for, f"phase, linear:{n2pi}", queue=queue)


def centre_on(patterns: np.ndarray, shape, *, out: Optional[np.ndarray] = None) -> np.ndarray:
    """Centre ``patterns [..., h, w]`` on a ``(H, W)`` display: pad with 0, or crop the centre.
    ``out`` (uint8 ``[..., H, W]``, the leading axes of ``patterns``) receives them where given
    (the loop writes each chunk into its batch); returns it."""
    H, W = shape
    h, w = patterns.shape[-2:]
    if out is None:
        out = np.empty(patterns.shape[:-2] + (H, W), np.uint8)
    elif out.shape != patterns.shape[:-2] + (H, W):
        raise ValueError(f"out must have shape {patterns.shape[:-2] + (H, W)}, got {out.shape}")
    oy, ox = H // 2 - h // 2, W // 2 - w // 2
    sy0, sx0 = max(0, -oy), max(0, -ox)
    dy0, dx0 = max(0, oy), max(0, ox)
    hh, ww = min(h - sy0, H - dy0), min(w - sx0, W - dx0)
    if (hh, ww) != (H, W):
        out[...] = 0          # the margins; a pattern that fills the display needs none
    out[..., dy0:dy0 + hh, dx0:dx0 + ww] = patterns[..., sy0:sy0 + hh, sx0:sx0 + ww]
    return out


class PatternRecord(NamedTuple):
    batch: int
    frame: int          # absolute frame index (phase stream)
    channel: int
    scene: int          # how many scene swaps happened before this batch
    render_start_s: float
    ready_s: float
    shown_s: float
    latency_s: float
    interval_s: float   # since the previous swap (nan for the first)
    dropped: bool
    repeated: bool


class _Making:
    """A batch in the making (the pipelined producer): its frames are enqueued chunk by chunk
    and their patterns centred into :attr:`patterns` as they come back."""

    def __init__(self, index: int, frame0: int, scene: int, n: int, display_shape, channels):
        self.index, self.frame0, self.scene, self.n = index, frame0, scene, n
        self.enqueued = self.done = 0
        self.patterns = np.empty((n, channels) + tuple(display_shape), np.uint8)
        self.render_start_s = time.monotonic()

    def batch(self) -> "_Batch":
        return _Batch(self.index, self.frame0, self.scene, self.patterns[:self.n],
                      self.render_start_s, time.monotonic())


class _Batch(NamedTuple):
    index: int
    frame0: int
    scene: int
    patterns: np.ndarray    # uint8 [n, C, H, W], display-sized
    render_start_s: float
    ready_s: float



def check_batch_memory(frames_per_batch: int, channels: int, render_shape, display_shape, *,
                       available: Optional[int] = None) -> int:
    """Refuse a batch size whose two batches (one on screen, one being made) do not fit in the
    host's memory, before anything is allocated; returns the bytes they need.

    Per frame and colour a batch holds the rendered field (complex64 ``h x w``), its 8-bit
    encoding (``h x w``) and the display-sized pattern (``H x W`` bytes). The field now stays
    on the device, but the count keeps it: on a CPU device (PoCL) device buffers are host
    memory, and an encoder may fetch the field to the host.

    Raises
    ------
    MemoryError
        Naming the size and the largest batch that fits.
    """
    h, w = render_shape
    H, W = display_shape
    per_frame = channels * (h * w * 9 + H * W)
    need = 2 * frames_per_batch * per_frame
    from clholo.host.memory import available_host_bytes

    room = available_host_bytes() if available is None else int(available)
    if need > room * 0.8:
        fits = max(0, int(room * 0.8 // (2 * per_frame)))
        raise MemoryError(
            f"{frames_per_batch} frames per batch need {need / 2**30:.1f} GiB of host memory "
            f"(two batches of {channels} colour(s), rendered {h}x{w}, shown {H}x{W}) but "
            f"{room / 2**30:.1f} GiB is available: use at most {fits} frames per batch "
            f"(clholo display --frames)")
    return need


def _check_display_colours(display, optics) -> None:
    """Refuse a display that cannot show every colour of ``optics``: one with fewer LUTs (one
    per colour) than ``optics.channels``, or, without LUTs (identity), more colours than it
    takes (``Display.MAX_CHANNELS``, red, green and blue). Without this the loop would fail
    only after its first batch was rendered, at the first colour the display has no LUT for."""
    from clholo.errors import InputError

    channels = optics.channels
    nm = ", ".join(f"{w * 1e9:g} nm" for w in optics.wavelengths)
    luts = getattr(display, "luts", None)
    if luts is not None:
        if len(luts) < channels:
            raise InputError(
                f"the display has {len(luts)} LUT(s) (display.luts, one per colour) but the "
                f"optics have {channels} colour(s) ({nm}): give the display one LUT per "
                f"colour (or luts=None for identity), or optics with {len(luts)} "
                f"wavelength(s)")
        return
    most = getattr(display, "MAX_CHANNELS", None)
    if most is not None and channels > most:
        raise InputError(
            f"the optics have {channels} colour(s) ({nm}) but a display without LUTs shows at "
            f"most {most}: give the display one LUT per colour (luts=...), or optics with at "
            f"most {most} wavelength(s)")


def _device_memory_error(exc: BaseException, frames: int) -> BaseException:
    """An OpenCL allocation failure as a :class:`MemoryError` naming the batch size (so the
    command line reports it as "this machine cannot", exit 3); anything else unchanged."""
    if isinstance(exc, MemoryError):
        return exc
    text = f"{type(exc).__name__}: {exc}"
    if any(code in text for code in ("MEM_OBJECT_ALLOCATION_FAILURE", "OUT_OF_RESOURCES",
                                     "OUT_OF_HOST_MEMORY", "MemoryError")):
        return MemoryError(f"the OpenCL device ran out of memory rendering a batch of {frames} "
                           f"frame(s) ({exc}): use fewer frames per batch (clholo display "
                           f"--frames) or a smaller --size")
    return exc


class DisplayLoop:
    """Render holograms on the device while the display shows the previous batch.

    Parameters
    ----------
    scene : clholo.scenes.Scene or clholo.MPI
        The first scene (an MPI is taken as a scene of that MPI); what ``method`` renders from.
    optics : clholo.Optics
        Pitch and one wavelength per colour.
    display : clholo.tools.slm.Display
        Where patterns go (``SLMWindow`` or ``MemoryDisplay``); its LUTs apply on top of the
        encoder's output (give the display no LUTs when the encoder already applies them).
    encode : callable
        ``encode(fields) -> uint8 [n, C, h, w]`` (NumPy) for ``fields`` complex64
        ``[n, C, h, w]``, a pyopencl array on the renderer's queue (the frames stay on the
        device; call ``fields.get()`` for NumPy). The buffer is reused for the next batch once
        ``encode`` has returned. E.g. :func:`dpac_encoder` (double-phase coding + LUT
        quantisation) or :func:`phase_quantize_encoder`, both on the device.
    method : str or clholo.methods.Method
        The hologram method (:data:`clholo.methods.METHODS`), ``"mpi"`` by default.
    frames_per_batch : int
        Time-multiplexed frames rendered per batch.
    seed : int
        Phase-stream key.
    pad : "auto", float or (int, int)
        Padding of the propagations.
    queue : pyopencl.CommandQueue, optional
    log_path : path, optional
        Stream the pattern log to this CSV while running (one row per pattern, flushed after
        every batch), so a run of any length can be plotted. Its folder must exist. As for
        ``clholo display --log`` (:func:`clholo.io.output.check_output_file`), an existing file
        is replaced only when clholo wrote it, is unchanged since, and ``overwrite`` is given;
        checked here and again when :meth:`run` starts. The rows go to a temporary file beside
        it, renamed to ``log_path`` when the run ends (by its time or batches, :meth:`stop`,
        Ctrl-C or an error of the producer: the rows are those shown), so ``log_path`` is never
        half-written; a later run of this loop replaces the log of its earlier run (if
        unchanged since). Assigning ``loop.log_path`` afterwards follows the same rule, except
        that an existing *empty* file (nothing in it to lose) is written directly: ``clholo
        display`` streams into the temporary name that :func:`clholo.io.output.output_file`
        made for its ``--log``.
    keep_records : int
        How many recent records :attr:`records` keeps in memory (older ones are only in the
        streamed CSV): memory stays flat however long the loop runs. The display's own frame
        log is trimmed to the same length.
    pipeline : bool, optional
        Overlap the host's work with the device's: the producer enqueues the next chunk's
        render and coding (:data:`PIPELINE_DEPTH` chunks in all) before it waits for this
        chunk's patterns, which the device reads into page-locked host memory. When the
        display is waiting for a batch, the next batch's first chunk is enqueued before the
        last chunk of this one is read back; when the display is busy showing, a batch is
        still started only once the one before is on screen, so latency stays at one batch.
        Needs a :class:`DeviceEncoder` (``encode.enqueue``: :func:`dpac_encoder`,
        :func:`phase_quantize_encoder`) and an in-order queue. ``None`` (default): where those
        hold; ``True``: required (an encoder without ``enqueue`` is refused); ``False``: each
        chunk is rendered, coded and read back before the next is enqueued. The patterns are
        the same bits either way.
    overwrite : bool
        Let ``log_path`` replace a log that clholo wrote there before (never a file it did not
        write, nor one changed since); ``clholo display --overwrite``. Default False.

    Raises
    ------
    clholo.errors.InputError
        The scene is larger than the display (it would be cropped), or the display has fewer
        LUTs than the optics have colours.
    clholo.errors.OutputRefused
        ``log_path`` is a file that may not be replaced (see ``log_path``).
    FileNotFoundError
        ``log_path``'s folder does not exist.
    MemoryError
        Two batches of ``frames_per_batch`` frames (one shown, one being made) do not fit in
        the host's memory (:func:`check_batch_memory`), before anything is allocated.
    """

    def __init__(self, scene, optics, display, encode: Callable, *, method="mpi",
                 frames_per_batch: int = 2, seed: int = 0, pad="auto", queue=None,
                 log_path=None, keep_records: int = 100_000, pipeline: Optional[bool] = None,
                 overwrite: bool = False):
        from clholo import validate
        from clholo.errors import InputError
        from clholo.io.output import check_output_file
        from clholo.methods import get_method
        from clholo.scene import Optics

        if not isinstance(optics, Optics):
            raise TypeError(f"optics must be a clholo.Optics (pitch and one wavelength per "
                            f"colour), got {type(optics).__name__}")
        if not all(hasattr(display, a) for a in ("shape", "show", "refresh_hz", "log")):
            raise TypeError(f"display must be a clholo.tools.slm.Display (SLMWindow or "
                            f"MemoryDisplay), got {type(display).__name__}")
        if not callable(encode):
            raise TypeError(f"encode must be a callable encode(fields) -> uint8 patterns, e.g. "
                            f"dpac_encoder(optics) or phase_quantize_encoder(), got "
                            f"{type(encode).__name__}")
        _check_display_colours(display, optics)
        overwrite = validate.flag(overwrite, name="overwrite")
        if overwrite and log_path is None:
            raise InputError("overwrite=True lets log_path replace an earlier log: give "
                             "log_path, or drop overwrite")
        if log_path is not None:
            # before the scene is loaded onto the device: a log that may not be written, or a
            # missing folder, is found out now, not when run() starts (nor after it)
            check_output_file(log_path, overwrite=overwrite, option="log_path")
        self.optics = optics
        self.display = display
        self.encode = encode
        self.method = get_method(method) if isinstance(method, str) else method
        self.frames_per_batch = validate.count(frames_per_batch, name="frames_per_batch")
        self.seed = validate.seed(seed)
        self.pad = pad
        self.queue = queue
        self.keep_records = validate.count(keep_records, name="keep_records")
        self.records = collections.deque(maxlen=self.keep_records)
        self.log_path = None if log_path is None else Path(log_path)
        self.overwrite = overwrite
        self._log_written: Optional[Path] = None   # the log this loop's last run installed
        self.errors: List[BaseException] = []      # what the producer of the last run raised
        self._scene_count = 0
        self._next_scene = None
        self._fields = None         # the device buffer the renderer writes each batch into
        if pipeline not in (None, True, False):
            raise TypeError(f"pipeline must be None (where the encoder allows), True or False, "
                            f"got {pipeline!r}")
        if pipeline and not callable(getattr(encode, "enqueue", None)):
            raise TypeError(f"pipeline=True needs an encoder with enqueue(fields, out=...) (a "
                            f"DeviceEncoder: dpac_encoder, phase_quantize_encoder); "
                            f"{encode!r} has none: pass pipeline=None or False")
        self._pipeline = pipeline
        self._staging = {}          # patterns shape -> free page-locked host arrays
        self._renderer = self._make_renderer(self._as_scene(scene))   # validates it here
        self._pipelined()                                               # and the queue
        check_batch_memory(self.frames_per_batch, self.optics.channels, self._renderer_shape,
                           display.shape)
        self._cv = threading.Condition()
        self._slot: Optional[_Batch] = None
        self._stop = threading.Event()
        self._producer: Optional[threading.Thread] = None
        self._producing = False
        self._running: Optional[threading.Thread] = None   # the thread inside run(), if any
        self._consumer_waiting = True   # the display has nothing new to show (no batch yet)
        self._deadline: Optional[float] = None
        self.batches_rendered = 0
        self._next_index = 0        # batch index and first frame of the next batch to render
        self._next_frame0 = 0

    def _as_scene(self, scene):
        from clholo.scene import MPI
        from clholo.scenes import Scene, SceneSpec

        if isinstance(scene, MPI):
            return Scene(spec=SceneSpec(inputs=("MPI",)), kind="mpi", mpi=scene)
        if not isinstance(scene, Scene):
            raise TypeError(f"scene must be a clholo.scenes.Scene or a clholo.MPI, got "
                            f"{type(scene).__name__}")
        what = scene.mpi if self.method.needs == "mpi" else scene.primitives
        if what is None:
            raise ValueError(f"method {self.method.name!r} renders from "
                             f"{'an MPI' if self.method.needs == 'mpi' else 'splat primitives'}"
                             f"; load the scene with scenes.load(spec, needs="
                             f"{self.method.needs!r})")
        return scene

    def _make_renderer(self, scene):
        source = scene.mpi if self.method.needs == "mpi" else scene.primitives
        if source.channels != self.optics.channels:
            raise ValueError(f"the scene has {source.channels} channel(s), the loop shows "
                             f"{self.optics.channels}")
        self._check_fits(source, "the scene")
        renderer = self.method.renderer(scene, self.optics, seed=self.seed, pad=self.pad,
                                        queue=self.queue)
        self._renderer_shape = tuple(source.shape)
        self._fields = None         # the old scene's buffer is freed with the old renderer
        self._staging = {}          # and its page-locked arrays once their chunks are read
        return renderer

    def _check_fits(self, source, what: str) -> None:
        """Refuse a scene (an MPI or splat primitives) larger than the display:
        :func:`centre_on` would crop it, silently losing its edges."""
        from clholo.errors import InputError

        h, w = (int(v) for v in source.shape)
        H, W = (int(v) for v in self.display.shape)
        if h <= H and w <= W:
            return
        if self.method.needs == "mpi":
            s = min(H / h, W / w)    # the largest size of the same aspect ratio that fits
            fit = (max(1, int(h * s)), max(1, int(w * s)))
            how = (f"resample it to fit, e.g. resample_mpi(mpi, {fit}) "
                   f"(clholo.host.display_loop.resample_mpi; clholo display --size), or give a "
                   f"smaller scene")
        else:
            how = ("render the splats smaller (a smaller scale: clholo display --scale), or "
                   "give a smaller scene")
        raise InputError(f"{what} is {h}x{w} pixels, larger than the display ({H}x{W}, height "
                         f"x width): the display loop would crop it; {how}")

    # -- producer --------------------------------------------------------------------------
    def set_scene(self, scene) -> None:
        """Swap the scene without stopping: the producer uses ``scene`` (a
        :class:`clholo.scenes.Scene` or an MPI) from its next batch. It must have the loop's
        colours and fit on the display (no larger; :func:`resample_mpi` makes it fit)."""
        from clholo.scene import MPI
        from clholo.scenes import Scene

        if not isinstance(scene, (MPI, Scene)):
            raise TypeError(f"scene must be a clholo.scenes.Scene or a clholo.MPI, got "
                            f"{type(scene).__name__}")
        scene = self._as_scene(scene)
        source = scene.mpi if self.method.needs == "mpi" else scene.primitives
        if source.channels != self.optics.channels:
            raise ValueError(f"the new scene has {source.channels} channel(s), the loop shows "
                             f"{self.optics.channels}")
        self._check_fits(source, "the new scene")
        check_batch_memory(self.frames_per_batch, self.optics.channels, tuple(source.shape),
                           self.display.shape)
        with self._cv:
            self._next_scene = scene

    def _render_batch(self, frame0: int, n: int):
        """Frames ``frame0 .. frame0+n-1`` of the current scene, enqueued into the loop's
        device buffer of ``n`` frames (complex64 ``[n, C, H, W]``, reused from chunk to chunk
        and batch to batch: a batch's chunks have at most two sizes)."""
        import pyopencl.array as cla

        r = self._renderer
        shape = (n, self.optics.channels) + tuple(self._renderer_shape)
        if self._fields is None:
            self._fields = {}
        buf = self._fields.get(n)
        if buf is None or buf.shape != shape:
            buf = self._fields[n] = cla.empty(r.queue, shape, np.complex64)
        return r.enqueue_frames(frame0, n, buf)

    def _time_up(self) -> bool:
        return self._deadline is not None and time.monotonic() >= self._deadline

    def _pipelined(self) -> bool:
        """Whether the producer pipelines (see the ``pipeline`` option)."""
        import pyopencl as cl

        if self._pipeline is False or not callable(getattr(self.encode, "enqueue", None)):
            return False
        queue = self._renderer.queue
        in_order = not (queue.properties
                        & cl.command_queue_properties.OUT_OF_ORDER_EXEC_MODE_ENABLE)
        own = getattr(self.encode, "queue", None)
        same_queue = own is None or own == queue
        if self._pipeline and not (in_order and same_queue):
            why = ("an in-order queue" if not in_order else
                   "the encoder on the loop's queue (make it with queue=None)")
            raise ValueError(f"pipeline=True needs {why}: a chunk's fields buffer is rendered "
                             f"again while the chunk before is coded, which only one in-order "
                             f"queue keeps in order; or pass pipeline=None")
        return in_order and same_queue

    def _produce(self) -> None:
        try:
            if self._pipelined():
                self._produce_pipelined()
            else:
                self._produce_in_turn()
        except BaseException as exc:  # reported by run()
            self.errors.append(exc)
            self._stop.set()
        finally:
            with self._cv:
                self._producing = False
                self._cv.notify_all()

    def _swap_scene_if_asked(self) -> None:
        with self._cv:
            new = self._next_scene
            self._next_scene = None
        if new is not None:
            self._renderer = self._make_renderer(new)   # old device buffers are freed
            self._scene_count += 1

    def _hand_over(self, batch: _Batch) -> bool:
        """Put ``batch`` in the slot and wait until the display takes it; False if the loop
        stopped meanwhile."""
        with self._cv:
            self._slot = batch
            self._cv.notify_all()
            # double buffering: the next batch is started only once this one is on screen
            # (taken), so at most two batches exist: shown and in the making
            while self._slot is not None and not self._stop.is_set():
                self._cv.wait(0.1)
            if self._stop.is_set():
                return False
        self.batches_rendered += 1
        self._next_index = batch.index + 1
        self._next_frame0 = batch.frame0 + batch.patterns.shape[0]
        return True

    def _produce_in_turn(self) -> None:
        """Each chunk rendered, coded and read back before the next is enqueued (an encoder
        without ``enqueue``, or ``pipeline=False``)."""
        first = True   # a run shows at least its first chunk, however short its time
        while not self._stop.is_set() and (first or not self._time_up()):
            first = False
            self._swap_scene_if_asked()
            n = self.frames_per_batch
            t0 = time.monotonic()
            parts, done = [], 0
            while done < n:
                if done and self._stop.is_set():
                    return                  # stopped: a batch cut short is not shown
                if done and self._time_up():
                    break                   # time is up: hand over what is made
                m = min(RENDER_CHUNK, n - done)
                try:
                    fields = self._render_batch(self._next_frame0 + done, m)
                    part = np.asarray(self.encode(fields))
                except Exception as exc:
                    raise _device_memory_error(exc, n) from None
                if part.dtype != np.uint8 or part.shape != fields.shape:
                    raise TypeError(f"encode must return uint8 {fields.shape}, got "
                                    f"{part.dtype} {part.shape}")
                del fields
                parts.append(centre_on(part, self.display.shape))
                done += m
            patterns = parts[0] if len(parts) == 1 else np.concatenate(parts)
            del parts
            batch = _Batch(self._next_index, self._next_frame0, self._scene_count, patterns, t0,
                           time.monotonic())
            del patterns
            if not self._hand_over(batch):
                return

    def _staging_array(self, shape) -> np.ndarray:
        """A free page-locked host array of ``shape`` (uint8) for a chunk's patterns."""
        from clholo.host.memory import pinned_empty

        free = self._staging.setdefault(tuple(shape), [])
        return free.pop() if free else pinned_empty(self._renderer.queue, shape, np.uint8)

    def _produce_pipelined(self) -> None:
        """Up to :data:`PIPELINE_DEPTH` chunks enqueued at once (render, coding, read into
        page-locked memory): the host waits for the oldest, centres its patterns into its
        batch and hands finished batches over while the device works on the next."""
        inflight = collections.deque()    # (batch, offset, frames, pending, staging array)
        making = collections.deque()      # batches not yet handed over, oldest first
        first = True                      # a run shows at least its first chunk
        while not self._stop.is_set():
            # enqueue: chunks of the newest batch; a new batch when it is all enqueued and
            # either nothing is in flight or the display is waiting for one
            while len(inflight) < PIPELINE_DEPTH:
                newest = making[-1] if making else None
                if newest is not None and newest.enqueued < newest.n:
                    if self._time_up():
                        newest.n = newest.enqueued      # time is up: hand over what is made
                        continue
                elif (first or not self._time_up()) and (not inflight
                                                         or self._consumer_waiting):
                    first = False
                    frame0 = self._next_frame0 if newest is None else newest.frame0 + newest.n
                    index = self._next_index if newest is None else newest.index + 1
                    self._swap_scene_if_asked()
                    newest = _Making(index, frame0, self._scene_count, self.frames_per_batch,
                                     self.display.shape, self.optics.channels)
                    making.append(newest)
                else:
                    break
                m = min(RENDER_CHUNK, newest.n - newest.enqueued)
                try:
                    fields = self._render_batch(newest.frame0 + newest.enqueued, m)
                    staging = self._staging_array(fields.shape)
                    pending = self.encode.enqueue(fields, out=staging)
                except Exception as exc:
                    raise _device_memory_error(exc, newest.n) from None
                del fields
                if not callable(getattr(pending, "wait", None)):
                    raise TypeError(f"encode.enqueue must return a pending result whose wait() "
                                    f"gives the patterns (e.g. PendingPatterns), got "
                                    f"{type(pending).__name__}")
                inflight.append((newest, newest.enqueued, m, pending, staging))
                newest.enqueued += m
            if not inflight:
                return                            # time is up and every batch handed over
            batch, offset, m, pending, staging = inflight.popleft()
            try:
                part = np.asarray(pending.wait())
            except Exception as exc:
                raise _device_memory_error(exc, batch.n) from None
            if part.dtype != np.uint8 or part.shape != staging.shape:
                raise TypeError(f"encode's patterns must be uint8 {staging.shape}, got "
                                f"{part.dtype} {part.shape}")
            centre_on(part, self.display.shape, out=batch.patterns[offset:offset + m])
            if staging.shape[2:] == tuple(self._renderer_shape):   # not an old scene's size
                self._staging.setdefault(staging.shape, []).append(staging)
            batch.done += m
            while making and making[0].done == making[0].n == making[0].enqueued:
                done = making.popleft()
                if not self._hand_over(done.batch()):
                    return

    # -- consumer --------------------------------------------------------------------------
    def _take(self, block: bool) -> Optional[_Batch]:
        with self._cv:
            if block:
                self._consumer_waiting = True
                while self._slot is None and self._producing and not self._stop.is_set():
                    self._cv.wait(0.1)
            batch, self._slot = self._slot, None
            # nothing new: the display repeats its batch, so the producer may work ahead
            self._consumer_waiting = batch is None
            if batch is not None:
                self._cv.notify_all()
            return batch

    def run(self, *, seconds: Optional[float] = None, batches: Optional[int] = None,
            on_pattern: Optional[Callable[[PatternRecord], None]] = None) -> List[PatternRecord]:
        """Run until ``seconds`` pass or ``batches`` new batches were shown (or :meth:`stop`);
        returns the records of this run (the last ``keep_records``). Raises what the producer
        raised (in this run: :attr:`errors` is cleared when a run starts).

        ``seconds`` is honoured whatever the batch size: the time is checked after every
        pattern shown, and the producer renders in chunks of :data:`RENDER_CHUNK` frames and
        starts none once the time is up (the first batch of a run, cut short, is still shown
        up to the deadline), so a run ends within about a chunk's render time of ``seconds``.

        One thread at a time runs a loop: the display shows one stream of patterns.

        Raises
        ------
        RuntimeError
            The loop is already running (in another thread, or ``on_pattern`` called run()),
            or the producer of the last run is still finishing a chunk.
        clholo.errors.OutputRefused, FileNotFoundError, PermissionError
            ``log_path`` may not be written (see the class); found out before anything starts.
        """
        from clholo import validate

        if seconds is None and batches is None:
            raise ValueError("give seconds or batches (or both), or the loop never ends")
        if seconds is not None:
            seconds = validate.real_scalar("seconds", seconds)
            if seconds <= 0:
                raise ValueError(f"seconds must be > 0, got {seconds!r}")
        if batches is not None:
            batches = validate.count(batches, name="batches")
        with self._cv:
            # a second run() would start a second producer and show on the same display
            # beside the first; its stop() would end the first too
            if self._running is threading.current_thread():
                raise RuntimeError("the loop is already running (run() was called from "
                                   "on_pattern): call stop() there instead, and run() again "
                                   "once run() has returned")
            if self._running is not None:
                raise RuntimeError("the loop is already running (in another thread): call "
                                   "stop() first, or wait for run() to return")
            self._running = threading.current_thread()
        try:
            return self._run(seconds, batches, on_pattern)
        finally:
            with self._cv:
                self._running = None
                self._cv.notify_all()

    def _open_log(self, stack: contextlib.ExitStack):
        """The file a run streams its log into (``None`` without ``log_path``), opened on
        ``stack``, and where the finished log will lie when clholo installs it (else ``None``).

        ``log_path`` follows ``clholo display --log``'s rule (checked again: the file may have
        appeared since the loop was made): the rows go to a temporary file that replaces
        ``log_path`` when the stack closes without an error. An existing empty file is written
        directly: nothing in it can be lost, and it is what ``clholo display`` hands over (the
        temporary name that :func:`clholo.io.output.output_file` made for ``--log``)."""
        from clholo.io.output import output_file

        if self.log_path is None:
            return None, None
        path = Path(self.log_path)
        installed = None
        if path.is_file() and not path.is_symlink() and path.stat().st_size == 0:
            target = path
        else:
            installed = Path(os.path.abspath(os.fspath(path)))
            # the log of this loop's earlier run is its own to replace (if unchanged since)
            overwrite = self.overwrite or installed == self._log_written
            target = stack.enter_context(output_file(path, overwrite=overwrite,
                                                     command="DisplayLoop.run",
                                                     option="log_path"))
        return stack.enter_context(open(target, "w", newline="")), installed

    def _run(self, seconds, batches, on_pattern) -> List[PatternRecord]:
        old = self._producer
        if old is not None and old.is_alive():
            # the last run's producer was told to stop but outlived the join (Ctrl-C waits
            # 2 s): it ends after its chunk. Clearing _stop now would set it going again,
            # beside this run's producer (batches shown twice or skipped)
            old.join(timeout=60.0)
            if old.is_alive():
                raise RuntimeError("the producer of this loop's last run is still rendering a "
                                   "chunk: wait for it to end, then call run() again")
        self.errors = []            # this run's errors only: an earlier one is not raised again
        interrupted = None
        with contextlib.ExitStack() as stack:
            # the log is opened before the producer starts: a log that cannot be written
            # leaves no thread running
            log_file, installed = self._open_log(stack)
            log_writer = None
            if log_file is not None:
                log_writer = csv.writer(log_file)
                log_writer.writerow(PatternRecord._fields)
            self._stop.clear()
            self._deadline = None if seconds is None else time.monotonic() + seconds
            self._producing = True
            self._consumer_waiting = True
            self._producer = threading.Thread(target=self._produce, name="clholo-render",
                                              daemon=True)
            self._producer.start()
            run_records = collections.deque(maxlen=self.keep_records)
            period = 1.0 / self.display.refresh_hz
            deadline = self._deadline
            shown_batches = 0
            last_swap = self.records[-1].shown_s if self.records else None
            join_timeout = 60.0
            try:
                current = self._take(block=True)
                repeated = False
                ending = False
                while current is not None and not self._stop.is_set() and not ending:
                    n, C = current.patterns.shape[:2]
                    for t in range(n):
                        if ending:
                            break
                        for c in range(C):
                            rec = self.display.show(current.patterns[t, c], channel=c,
                                                    t=current.frame0 + t)
                            interval = (float("nan") if last_swap is None
                                        else rec.shown_s - last_swap)
                            last_swap = rec.shown_s
                            pr = PatternRecord(current.index, current.frame0 + t, c,
                                               current.scene, current.render_start_s,
                                               current.ready_s, rec.shown_s,
                                               rec.shown_s - current.render_start_s, interval,
                                               bool(interval > 1.5 * period), repeated)
                            self.records.append(pr)
                            run_records.append(pr)
                            if log_writer is not None:
                                log_writer.writerow(_row(pr))
                            if on_pattern is not None:
                                on_pattern(pr)
                            # the time is checked after every pattern: a batch of many frames
                            # is not shown to its end after `seconds`; nor after stop() (or a
                            # producer's error), so stop() does not wait for a whole batch
                            if ((deadline is not None and time.monotonic() >= deadline)
                                    or self._stop.is_set()):
                                ending = True
                                break
                    if log_file is not None:
                        log_file.flush()
                    del self.display.log[:-self.keep_records]
                    if not repeated:
                        shown_batches += 1
                    if batches is not None and shown_batches >= batches:
                        break
                    if ending:
                        break
                    nxt = self._take(block=False)
                    repeated = nxt is None
                    if nxt is not None:
                        current = nxt
            except KeyboardInterrupt as exc:
                # Ctrl-C: do not wait long for a batch in the making (the producer is a daemon
                # thread and stops before its next batch); the rows streamed so far are whole,
                # so the log is kept (installed as log_path) as the record of what was shown
                join_timeout = 2.0
                interrupted = exc
            finally:
                self.stop(join_timeout=join_timeout)
        if installed is not None:
            self._log_written = installed
        if interrupted is not None:
            raise interrupted
        if self.errors:
            raise self.errors[0]
        return list(run_records)

    def stop(self, *, join_timeout: float = 60.0) -> None:
        """Stop the producer (the consumer returns after the pattern it is showing); wait at
        most ``join_timeout`` seconds for the batch it is making and, called from another
        thread than the one in :meth:`run`, for that run() to return."""
        here = threading.current_thread()
        self._stop.set()
        with self._cv:
            self._cv.notify_all()
        end = time.monotonic() + join_timeout
        if self._producer is not None and self._producer is not here:
            self._producer.join(timeout=join_timeout)
        with self._cv:
            self._slot = None
            # called from another thread than run()'s: wait for run() to return, so that
            # run() may be called again as soon as stop() has returned
            while self._running not in (None, here) and self._producer is not here:
                left = end - time.monotonic()
                if left <= 0:
                    break
                self._cv.wait(min(left, 0.1))

    def write_log(self, path: Union[str, Path], *, overwrite: bool = False) -> None:
        """The records kept in memory (the last ``keep_records``) as CSV (one row per pattern
        shown; times in seconds of ``time.monotonic()``), written under a temporary name and
        renamed. For the whole of a long run, give ``log_path``.

        Parameters
        ----------
        path : str or os.PathLike
            The CSV file. As for ``clholo display --log``, an existing file is replaced only
            when clholo wrote it, is unchanged since, and ``overwrite`` is given.
        overwrite : bool
            Replace a log clholo wrote at ``path`` before.

        Raises
        ------
        clholo.errors.OutputRefused
            ``path`` may not be replaced.
        FileNotFoundError
            Its folder does not exist.
        """
        write_pattern_log(list(self.records), path, overwrite=overwrite)


def write_pattern_log(records, path: Union[str, Path], *, overwrite: bool = False) -> None:
    """Pattern records as CSV, one row per pattern shown, written under a temporary name and
    renamed (:func:`clholo.io.output.output_file`): an existing ``path`` is replaced only when
    clholo wrote it, is unchanged since, and ``overwrite`` is given (the rule of ``clholo
    display --log``); otherwise :class:`clholo.errors.OutputRefused`."""
    from clholo import validate
    from clholo.io.output import output_file

    overwrite = validate.flag(overwrite, name="overwrite")
    with output_file(path, overwrite=overwrite, command="write_pattern_log",
                     option="path") as tmp, open(tmp, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(PatternRecord._fields)
        for r in records:
            w.writerow(_row(r))


def _row(record: PatternRecord) -> list:
    return [f"{v:.6f}" if isinstance(v, float) else int(v) for v in record]


def summarize(records, channels: int) -> dict:
    """Achieved rates from a pattern log: full-colour frames per second shown, new (not
    repeated) frames per second, mean and max latency, dropped and repeated counts."""
    if not records:
        return {"patterns": 0}
    shown = np.array([r.shown_s for r in records])
    span = shown[-1] - shown[0] if len(shown) > 1 else float("nan")
    new = [r for r in records if not r.repeated]
    lat = np.array([r.latency_s for r in new]) if new else np.array([np.nan])
    def rate(count):
        return float(count / channels / span) if span > 0 else float("nan")

    return {"patterns": len(records), "display_fps": rate(len(records) - 1),
            "new_frames_per_s": rate(len(new)),
            "latency_mean_s": float(np.mean(lat)), "latency_max_s": float(np.max(lat)),
            "dropped": int(sum(r.dropped for r in records)),
            "repeated": int(sum(r.repeated for r in records))}


def resample_mpi(mpi, size):
    """``mpi`` resampled to ``size = (h, w)`` pixels (the whole scene; stretched when the aspect
    ratio differs), anti-aliased when shrinking. Premultiplied colour ``c a`` and alpha are
    resampled (so transparent pixels' colour does not bleed into edges), then colour is
    un-premultiplied (0 where alpha is 0). Depths are unchanged."""
    from clholo.io.load import resampled_layers

    h, w = (int(v) for v in size)
    if (h, w) == tuple(mpi.shape):
        return mpi
    return resampled_layers(mpi, (h, w))


def dpac_encoder(optics, *, z_slm: float = 0.04, luts="linear", cutoff: float = 0.5,
                 queue=None) -> DeviceEncoder:
    """The real-time path: double-phase amplitude coding of each field at ``z_slm`` metres
    from the SLM (:func:`clholo.encode.dpac.dpac_encode_device`) and 8-bit quantisation through
    the per-wavelength phase lookup tables ``luts`` (``"linear"``, ``"linear:N"``, a file of 256
    phases, or one per colour) with :class:`clholo.encode.quantize.DeviceQuantizer`, both on the
    device: only the uint8 patterns are read back. The patterns are bit for bit
    ``quantize(dpac_encode(fields), luts)`` (:func:`clholo.encode.quantize.quantize`, the host's
    float64 quantisation). ``fields``: pyopencl (used where they lie) or NumPy (uploaded)
    complex64 ``[n, C, H, W]``; calling the encoder returns NumPy uint8 ``[n, C, H, W]``
    (:class:`DeviceEncoder`: ``enqueue`` returns at once). The tables are read, checked and
    built once, here, and ``z_slm``, ``cutoff`` and ``queue`` checked."""
    from clholo import validate
    from clholo.encode.dpac import check_cutoff, dpac_encode_device
    from clholo.encode.quantize import DeviceQuantizer
    from clholo.scene import Optics

    if not isinstance(optics, Optics):
        raise TypeError(f"optics must be a clholo.Optics, got {type(optics).__name__}")
    z_slm = validate.distance(z_slm, name="z_slm", nonzero=True)
    cutoff = check_cutoff(cutoff)
    queue = validate.queue(queue)
    quantizer = DeviceQuantizer(luts, optics.channels)

    def code(fields, allocator=None):
        # z_slm was checked (and a far one warned about) once, above: not again every batch
        with validate.far_warned_already():
            return dpac_encode_device(
                fields, optics, z_slm=z_slm, cutoff=cutoff,
                queue=queue if queue is not None else getattr(fields, "queue", None),
                allocator=allocator)

    return DeviceEncoder(code, lambda C: quantizer, f"DPAC at {z_slm:g} m", queue=queue)
