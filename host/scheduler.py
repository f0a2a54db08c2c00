"""Host scheduler of the MPI -> hologram recursion (HOLOGRAPHY.md section 4).

One :class:`HologramRenderer` is built per (MPI, optics, seed, padding): it validates once,
uploads every layer once (shared by all frames), chooses the padded grid and how many frames go
into one launch, and then renders batches of frames with the layer loop entirely on the device.

A layer is two kernels (the default wherever the lines fit fast memory, ``two_pass=True``). The
field lives between layers as its row spectrum ``R = FFT_x(pad_x(u))``, ``[B, H, Wp]``
(B = Tb*C fields; rows y >= H of the padded field are zero and never stored):

    composite_layer       u <- sqrt(c_{L-1} a_{L-1}) exp(i phi)        (farthest layer alone)
    row forward           R <- FFT_x(pad_x(u))                          (1D FFTPlan, W -> Wp)
    for layer i = L-1 ... 0 (back to front):
        column round trip R <- IFFT_y(H_i . FFT_y(pad_y(R)))[:H]       (RoundTripPlan, cols)
        i > 0: row round trip
                          R <- FFT_x(pad_x(over_{i-1}(IFFT_x(R)[:, :W])))  (RoundTripPlan, rows;
                              the composite of layer i-1 as its mid callback,
                              kernels/composite_store.h)
        i = 0: row inverse u <- IFFT_x(R)[:, :W]                        (1D FFTPlan, Wp -> W)

so each layer reads and writes an ``H x Wp`` array twice, against four passes (two of them
over ``Hp x Wp``) before. ``two_pass=False`` keeps the four-pass layer, which lines too long
for the GPU variant's local memory still need (and the layer sum without occlusion uses):

        forward           U <- FFT2(pad(u))
        inverse           u <- crop(IFFT2(U * H_i)), stored through the next layer's composite
                              (kernels/composite_store.h) with ``fuse_composite``, else the
                              composite runs as its own pass before each propagation.

``fuse_composite`` defaults to on for non-CPU devices only: on PoCL (2-core Xeon, 8 layers,
540 x 960 RGB, interleaved) the fused four-pass loop still took 1.07-1.2x the time of the
separate pass.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from typing import TYPE_CHECKING, Callable, Hashable, Iterator, Optional, Tuple

import numpy as np
import pyopencl as cl
import pyopencl.array as cla

from clholo.host import runtime
from clholo.host.kernel_args import COMPOSITE_LAYER
from clholo.host.memory import BATCH_TARGET_SAMPLES, default_budget, frames_per_launch  # noqa: F401

if TYPE_CHECKING:  # the annotation's name only: clholo.fft is imported where it plans
    from clholo.fft import EvenFactors  # noqa: F401

# The inverse transform's store callback that composites the next layer (kernels/composite_store.h)
COMPOSITE_STORE_PARAMS = ("__global const float *", "__global const float *", "uint", "uint",
                          "uint", "uint", "uint", "uint")
# GPUs' two-pass renderers hold the layers as given ("rows": the composite gathers one colour
# channel of [H*W, C] and takes two square roots per pixel, colour and frame) until a GPU
# session measures the planes there (layer_layout "planes": a colour's row of sqrt(c a) and of
# sqrt(1 - a), each read coalesced): the tunable setting "layer_planes" (clholo.host.tuning;
# `clholo tune`; benchmarks/fft_variants.py --variants fixed,layer-planes)


class PlanSets:
    """A renderer's FFT plans and work buffers, one set per batch size, at most ``keep`` sets.

    A long-lived renderer asked for many different frame counts (a notebook, a service) used
    to keep a set for every batch size it had seen, each with work buffers sized for that
    batch: ``render(T)`` for T = 1..213 under a 64 MiB budget held 4.7 GB. The renderers'
    memory plans count one set of the full batch and one of a smaller last batch, so two sets
    are kept: the set of the renderer's frames per batch (``pinned``, the last to go) and the
    most recently used other. Plans are deterministic in their size, so a set made again
    gives the same bits.

    Parameters
    ----------
    keep : int
        Most sets kept (>= 1).

    Notes
    -----
    A set evicted while its kernels are still enqueued is safe: OpenCL frees a released
    buffer only once the commands that use it are done. Callers that share a renderer between
    threads hold its lock around :meth:`get` and the launches; :meth:`get` has its own lock
    too (for renderers without one). The builder is passed to each :meth:`get`, not kept: a
    bound method of the renderer held here would make a reference cycle, and the renderer's
    device memory would then wait for the garbage collector after ``del renderer``.
    """

    def __init__(self, *, keep: int = 2):
        self.keep = int(keep)
        self._sets: "OrderedDict[Hashable, object]" = OrderedDict()
        self._lock = threading.RLock()

    def get(self, frames: int, make: Callable[[int], object], *,
            pinned: Optional[Hashable] = None):
        """The set of a batch of ``frames`` frames, made (and an older set released) if it is
        not kept.

        Parameters
        ----------
        frames : int
            Frames of the batch (the key).
        make : callable ``(frames) -> set``
            Builds the set when it is not kept.
        pinned : int, optional
            The batch size released last (the renderer's frames per batch).

        Returns
        -------
        object
            What ``make(frames)`` returned, now or before.
        """
        with self._lock:
            found = self._sets.get(frames)
            if found is not None:
                self._sets.move_to_end(frames)
                return found
            # release before making: the new set's buffers then take the old one's room,
            # and a render never holds more than the ``keep`` sets its memory plan counts
            while len(self._sets) >= self.keep:
                victim = next((k for k in self._sets if k != pinned), next(iter(self._sets)))
                del self._sets[victim]
            made = self._sets[frames] = make(frames)
            return made

    def __len__(self) -> int:
        return len(self._sets)

    def __contains__(self, frames) -> bool:
        return frames in self._sets

    def sizes(self) -> Tuple[int, ...]:
        """The batch sizes whose sets are kept, least recently used first."""
        return tuple(self._sets)

    def clear(self) -> None:
        """Release every set."""
        with self._lock:
            self._sets.clear()


class HologramRenderer:
    """Builds once, renders many times: MPI -> random-phase holograms ``[T, C, H, W]``.

    Parameters
    ----------
    mpi : clholo.MPI
        Layers nearest first, depths in metres behind the hologram plane.
    optics : clholo.Optics
        Pitch and one wavelength per colour channel of the MPI.
    seed : int
        Key of the Philox phase stream, in [0, 2^64).
    pad : "auto", float or (int, int)
        Padding of every propagation step, see :func:`clholo.propagation.device_padded_shape`;
        one padded grid serves every step and colour (the largest any of them needs).
    band_limit : bool
    memory_budget : int, optional
        Bytes of device memory the renderer may plan for (default: half of the device's).
    frames_per_batch : int, optional
        Override the frames per launch (default: from the memory formula above).
    occlusion : bool
        ``False``: no occlusion, every layer's own wave is propagated from its depth to the
        hologram plane and the layers are summed (the RGB-D baseline,
        :mod:`clholo.baselines.rgbd`); the padded grid then covers the largest depth.
    queue : pyopencl.CommandQueue, optional
    fuse_composite : bool, optional
        Four-pass layers only: composite each next layer in the inverse transform's store
        instead of in a separate pass over the field. Default: on non-CPU devices only (see
        the module docstring).
    two_pass : bool, optional
        A layer as two kernels (column and row round trips, :class:`clholo.fft.RoundTripPlan`).
        Default: wherever both round trips fit the FFT variant's fast memory and occlusion is
        on; ``True`` where they do not fit raises ``ValueError``.
    variant : {"auto", "cpu", "gpu"}
        FFT kernel variant of the two-pass layer (:class:`clholo.fft.FFTPlan`); ``"auto"``
        picks by device type.
    layer_layout : {"auto", "rows", "blocks", "planes"}
        How the device holds the layers (:attr:`layer_layout`): ``"blocks"``, each layer's
        ``sqrt(c a)`` and ``sqrt(1 - a)`` made once, eight rows to a block, needs a CPU
        device and the two-pass layer; ``"planes"``, the same made once as rows of each
        colour (what a GPU's work-items read side by side), needs the two-pass layer.
        ``"auto"`` takes ``"blocks"`` on a CPU's two-pass renderer, else ``"rows"``, or
        ``"planes"`` where the device's tuning says so (:mod:`clholo.tuning`, setting
        ``layer_planes``; the project's default is off until a GPU measures it). The same holograms either way (up to the sign of a zero).

    Notes
    -----
    Threads may share a renderer: each batch's kernels are enqueued together, one thread's
    batch at a time (they share the renderer's working buffers).
    """

    def __init__(self, mpi, optics, *, seed: int = 0, pad="auto", band_limit: bool = True,
                 memory_budget: Optional[int] = None, frames_per_batch: Optional[int] = None,
                 occlusion: bool = True, queue: Optional["cl.CommandQueue"] = None,
                 fuse_composite: Optional[bool] = None, two_pass: Optional[bool] = None,
                 variant: str = "auto", layer_layout: str = "auto"):
        from clholo import reference
        from clholo.propagation import ASMPropagator, device_padded_shape, transfer_function_cache
        from clholo.scene import MPI, Optics

        if not isinstance(mpi, MPI):
            raise TypeError(f"mpi must be a clholo.MPI, got {type(mpi).__name__}")
        if not isinstance(optics, Optics):
            raise TypeError(f"optics must be a clholo.Optics, got {type(optics).__name__}")
        if mpi.channels != optics.channels:
            raise ValueError(
                f"the MPI has {mpi.channels} colour channel(s) but optics has "
                f"{optics.channels} wavelength(s); give one wavelength per channel")
        from clholo import validate

        validate.depths(mpi.depths)  # warns when depths look like scene units
        frames_per_batch = validate.optional_count(frames_per_batch, name="frames_per_batch")
        if memory_budget is not None:
            memory_budget = validate.count(memory_budget, name="memory_budget")
        queue = validate.queue(queue)
        self.queue = queue if queue is not None else runtime.get_queue()
        self.mpi = mpi
        self.optics = optics
        self.key = reference.seed_key(seed)
        self.seed = int(seed)
        self.band_limit = validate.flag(band_limit, name="band_limit")
        occlusion = validate.flag(occlusion, name="occlusion")
        L, (H, W), C = mpi.layers, mpi.shape, mpi.channels
        self.shape = (H, W)
        self.steps = reference.layer_steps(mpi.depths)
        self.occlusion = bool(occlusion)
        # the recursion propagates by the steps between layers; the layer sum carries every layer
        # from its own depth to the hologram plane, so its grid covers the largest depth
        spans = self.steps if self.occlusion else mpi.depths
        self.padded = device_padded_shape((H, W), spans, wavelength=optics.wavelengths,
                                          pitch=optics.pitch, pad=pad)
        Hp, Wp = self.padded
        self.memory_budget = (int(memory_budget) if memory_budget is not None
                              else default_budget(self.queue.device))
        q = self.queue
        self._tf_cache = transfer_function_cache(q.context)
        # FFT plans and work buffers per batch size: two sets at most (PlanSets), the
        # frames_per_batch one kept longest
        self._propagators = PlanSets()
        # frames -> field-sized buffer of the layer sum (occlusion=False), bounded alike
        self._scratch = PlanSets()
        self._batch = None  # the batch buffer of enqueue_frames (_batch_buffer), largest so far
        # Held while a batch is enqueued (and copied into place): its kernels share the
        # renderer's working buffers (row spectrum, batch buffer, the plans' work buffers), so
        # a render of another thread must not enqueue between them
        self._lock = threading.RLock()
        self._ASMPropagator = ASMPropagator
        if fuse_composite is None:
            fuse_composite = not (q.device.type & cl.device_type.CPU)
        self.fuse_composite = validate.flag(fuse_composite, name="fuse_composite")
        from clholo.fft import DeviceLimits, round_trip_fits, row_pitch

        if variant not in ("auto", "cpu", "gpu"):
            raise ValueError(f"variant={variant!r}: use 'auto', 'cpu' or 'gpu'")
        self.variant = variant
        limits = DeviceLimits.of(q.device)
        fits = (round_trip_fits((1, H, Wp), Hp, device=limits, axis="cols", variant=variant)
                and round_trip_fits((1, H, Wp), Wp, device=limits, axis="rows",
                                    variant=variant))
        if two_pass and not fits:
            raise ValueError(f"two_pass=True: lines of the padded grid {Hp}x{Wp} do not fit the "
                             f"{variant} FFT variant's fast memory on {q.device.name.strip()}; "
                             f"leave two_pass unset (four passes per layer there)")
        if two_pass and not self.occlusion:
            raise ValueError("two_pass=True needs occlusion=True (the layer sum without "
                             "occlusion runs four passes per layer); leave two_pass unset")
        self.two_pass = bool(fits and self.occlusion) if two_pass is None else \
            validate.flag(two_pass, name="two_pass")
        #: How the device holds the layers, as the composites read them: ``"rows"``, colour
        #: ``[H*W, C]`` and alpha ``[H*W]`` as given; or ``"blocks"`` (the two-pass layer on
        #: CPUs), each layer's ``sqrt(c a)`` and ``sqrt(1 - a)`` made once, eight rows to a
        #: block (:func:`clholo.reference.layer_blocks`): the row round trip's composite
        #: then loads them as they are instead of gathering, transposing and taking two
        #: square roots per pixel, colour and frame (the same bits); or ``"planes"``, the
        #: same one row to a block, ``[H, C, W]`` and ``[H, W]`` (the GPU kernels' coalesced
        #: form, ``layer_blocks(..., rows=1)``)
        blocks_fit = self.two_pass and limits.is_cpu
        if layer_layout not in ("auto", "rows", "blocks", "planes"):
            raise ValueError(f"layer_layout={layer_layout!r}: use 'auto', 'rows', 'blocks' or "
                             "'planes'")
        if layer_layout == "blocks" and not blocks_fit:
            raise ValueError("layer_layout='blocks' needs a CPU device and the two-pass layer "
                             f"(this renderer: {q.device.name.strip()}, two_pass="
                             f"{self.two_pass}); use 'auto' or 'rows'")
        if layer_layout == "planes" and not self.two_pass:
            raise ValueError("layer_layout='planes' needs the two-pass layer (this renderer: "
                             f"two_pass={self.two_pass}, occlusion={self.occlusion}); use "
                             "'auto' or 'rows'")
        if layer_layout == "auto":
            layer_layout = ("blocks" if blocks_fit else "planes"
                            if self.two_pass and limits.setting("layer_planes") else "rows")
        self.layer_layout = layer_layout
        #: Rows per block of :attr:`layer_layout` (``CLHOLO_LAYER_ROWS``): 8, 1 or 0 (rows)
        self._layer_rows = {"rows": 0, "blocks": 8, "planes": 1}[layer_layout]
        R = self._layer_rows
        #: Device bytes of the layers (with ``"blocks"`` or ``"planes"``: those, and one layer
        #: as given while they are made)
        self.layer_bytes = (4 * L * H * W * (C + 1) if R == 0
                            else 4 * (L * -(-H // R) * R * W + H * W) * (C + 1))
        self._two_pass_plans = PlanSets()
        #: Row stride of the two-pass layer's row spectrum, in elements: ``Wp``, or more where
        #: ``Wp`` elements are a multiple of 4 KiB on a CPU or where the device's tuning says so
        #: (:func:`clholo.fft.row_pitch`)
        def pitch_of(wp):
            return row_pitch(wp, np.complex64, cpu=limits.is_cpu,
                             gpu_pitch=limits.setting("row_pitch"))

        self.row_pitch = pitch_of(Wp)
        self._row_spectrum = None  # [frames*C, H, pitch] of the largest batch so far (two-pass)
        # Device memory: fixed = the layers + one step's transfer functions [C, Hp, Wp] (and,
        # while the two-pass layer's strips of them are made on a CPU, those); per
        # frame = the batch's field, double-buffered by iter_frames, and the layer's working
        # arrays: the two kernels' row spectrum [C, H, row_pitch] (every batch size shares the
        # largest one's, and its field buffers: a last, smaller batch adds nothing), or the
        # four passes' spectrum [C, Hp, Wp], pruned inverse work [C, H, Wp] and the layer
        # sum's scratch field [C, H, W], twice: a last, smaller batch builds its own propagator
        # (tests/test_memory_budget.py counts every allocation against this plan).
        two_pass_layer, layer_sum = self.two_pass, not self.occlusion
        #: Bytes of one step's transfer functions laid out strip by strip for the two-pass
        #: layer's column round trips on CPUs (made from ``[C, Hp, Wp]`` built for them: both
        #: live while it is made), else 0
        self.tf_strip_bytes = 0
        if two_pass_layer:
            from clholo.fft import even_factors_bytes, round_trip_geometry

            self.tf_strip_bytes = even_factors_bytes(round_trip_geometry(
                (C, H, Wp), Hp, device=limits, axis="cols", variant=variant,
                pitch=self.row_pitch), C)

        def tf_bytes(hp, wp):
            """One step's transfer functions (and strips of them: lines not rounded up to
            whole strips, for padded_bytes' hint)."""
            return 8 * C * hp * wp + (8 * C * (hp // 2 + 1) * wp if self.tf_strip_bytes else 0)

        def padded_bytes(hp, wp):
            """Bytes of the plan (fixed + one frame) that grow with the padded grid."""
            tf = tf_bytes(hp, wp)
            if two_pass_layer:
                return tf + 8 * C * H * pitch_of(wp)
            return tf + 2 * 8 * C * (hp * wp + H * wp)

        per_frame = (2 * 8 * C * H * W + padded_bytes(Hp, Wp) - tf_bytes(Hp, Wp)
                     + (2 * 8 * C * H * W if layer_sum else 0))
        #: ``(fixed, per_frame)`` bytes of the plan :func:`clholo.host.memory.frames_per_launch`
        #: sized :attr:`frames_per_batch` with
        self.memory_plan = (self.layer_bytes + 8 * C * Hp * Wp + self.tf_strip_bytes, per_frame)
        self.frames_per_batch = frames_per_launch(
            fixed_bytes=self.memory_plan[0], per_frame_bytes=self.memory_plan[1],
            samples_per_frame=C * Hp * Wp, budget_bytes=self.memory_budget,
            device=self.queue.device,
            what=f"this hologram ({L} layers {H}x{W}x{C}, padded grid {Hp}x{Wp})",
            grid=((H, W), (Hp, Wp), padded_bytes))
        if frames_per_batch is not None:
            if int(frames_per_batch) < 1:
                raise ValueError(f"frames_per_batch must be >= 1, got {frames_per_batch}")
            self.frames_per_batch = int(frames_per_batch)
        # upload every layer once (after the memory plan: a refusal comes before any copy);
        # all frames and colours share them
        #: Per layer, the two arrays every composite of it reads, in :attr:`layer_layout`
        self.layers = self._upload_layers(mpi)
        self._composite = runtime.get_kernel(
            q.context, "composite.cl", "composite_layer",
            defines=None if self.occlusion else {"CLHOLO_NO_OCCLUSION": True})
        # On CPUs the composites launched on their own (the farthest layer; every layer of the
        # four passes without fusion and of the layer sum) take 8x8 blocks through the row
        # round trip's composite: the same values, 1.5-2x faster on PoCL than the four
        # pixels per work-item of composite_layer (kernels/composite_cpu.cl)
        self._composite_blocks = None
        if q.device.type & cl.device_type.CPU:
            self._composite_blocks = runtime.get_kernel(
                q.context, "composite_cpu.cl", "composite_layer_rows8",
                defines=self._layer_defines())
        # GPUs' planes: composite_layer reads the layers as given; the callback's four-pixel
        # form reads any layout
        self._composite_rows4 = None
        if self._composite_blocks is None and self.layer_layout != "rows":
            self._composite_rows4 = runtime.get_kernel(
                q.context, "composite.cl", "composite_layer_rows4",
                defines=self._layer_defines())

    def _layer_defines(self) -> dict:
        """Defines of every composite program: the occlusion mode and the layers' layout."""
        defines = {} if self.occlusion else {"CLHOLO_NO_OCCLUSION": True}
        if self.layer_layout != "rows":
            defines["CLHOLO_LAYER_BLOCKS"] = True
        if self.layer_layout == "planes":
            defines["CLHOLO_LAYER_ROWS"] = 1
        return defines

    def _upload_layers(self, mpi) -> list:
        """Every layer on the device as :attr:`layer_layout` says: ``[(color, alpha)]``, or
        ``[(amp, keep)]`` made by kernel ``layer_blocks`` (blocks) or ``layer_planes`` (planes)
        from each layer staged in one pair of buffers that every layer reuses."""
        q, L = self.queue, mpi.layers
        (H, W), C = self.shape, mpi.channels
        if self.layer_layout == "rows":
            return [(cla.to_device(q, np.ascontiguousarray(mpi.color[i])),
                     cla.to_device(q, np.ascontiguousarray(mpi.alpha[i]))) for i in range(L)]
        R = self._layer_rows
        S = -(-H // R)
        make = (runtime.get_kernel(q.context, "composite_cpu.cl", "layer_blocks") if R == 8
                else runtime.get_kernel(q.context, "composite.cl", "layer_planes"))
        grid = (W, S)  # layer_blocks: a work-item per column of a block; layer_planes: a pixel
        color = cla.empty(q, (H, W, C), np.float32)
        alpha = cla.empty(q, (H, W), np.float32)
        layers = []
        for i in range(L):
            color.set(np.ascontiguousarray(mpi.color[i], np.float32))
            alpha.set(np.ascontiguousarray(mpi.alpha[i], np.float32))
            amp = cla.empty(q, (S, C, W, R), np.float32)
            keep = cla.empty(q, (S, W, R), np.float32)
            runtime.launch(make, q, grid, None, color.data, alpha.data, amp.data, keep.data,
                           np.uint32(H), np.uint32(W), np.uint32(C))
            layers.append((amp, keep))
        q.finish()  # the staging pair is read before it goes
        return layers

    # ---------------------------------------------------------------------------------------
    def _propagator(self, frames: int):
        """The four-pass layer's propagator of a batch of ``frames`` frames (kept in
        :class:`PlanSets`: two batch sizes at most)."""
        return self._propagators.get(frames, self._make_propagator,
                                     pinned=self.frames_per_batch)

    def _make_propagator(self, frames: int):
        from clholo.fft import FFTCallback

        C = self.mpi.channels
        store = None
        if self.fuse_composite:
            # the same define as composite.cl's, so a no-occlusion mode survives the fusion
            store = FFTCallback('#include "composite_store.h"\n',
                                params=COMPOSITE_STORE_PARAMS,
                                defines=self._layer_defines())
        # the four-pass layer as it was (two 2D transforms per step)
        return self._ASMPropagator(frames * C, self.shape, self.padded, queue=self.queue,
                                   store_callback=store, three_pass=False)

    def _make_scratch(self, frames: int) -> "cla.Array":
        (H, W), C = self.shape, self.mpi.channels
        return cla.empty(self.queue, (frames, C, H, W), np.complex64)

    def prepare(self, frames: int, *, frames_per_batch: Optional[int] = None) -> None:
        """Build every OpenCL program that :meth:`iter_frames` of ``frames`` frames needs (the
        FFT plans of each batch size, the transfer-function kernel; the compositing kernel is
        built with the renderer), so that a timed render holds no compiler work. Nothing is
        rendered or computed.

        Parameters
        ----------
        frames : int
            Frames the render will make.
        frames_per_batch : int, optional
            Frames per launch (default: the renderer's own, :attr:`frames_per_batch`).
        """
        from clholo.propagation import transfer_function_kernel

        T = _check_frames(frames)
        from clholo import validate

        Tb = validate.optional_count(frames_per_batch, name="frames_per_batch")
        Tb = min(Tb or self.frames_per_batch, T)
        for n in sorted({Tb, T % Tb} - {0}):
            with self._lock:  # a render of another thread may be making the same plans
                if self.two_pass:
                    self._layer_plans(n)  # the layer's two kernels and the row transforms
                else:
                    self._propagator(n)
        transfer_function_kernel(self.queue, np.complex64)

    def _launch_composite(self, u: "cl.Buffer", layer: int, frame0: int, frames: int,
                          farthest: bool) -> None:
        """Layer ``layer``'s composite onto ``u`` (complex64 ``[frames, C, H, W]``) in place, or
        its emission alone where ``farthest`` (``u`` then not read)."""
        (H, W), C = self.shape, self.mpi.channels
        if self._composite_blocks is not None or self._composite_rows4 is not None:
            # composite_layer_rows8 (CPUs): 8x8 pixels a work-item; composite_layer_rows4: four
            # pixels of a row
            kern, grid = ((self._composite_blocks, (-(-W // 8), -(-H // 8), frames * C))
                          if self._composite_blocks is not None else
                          (self._composite_rows4, (-(-W // 4), H, frames * C)))
            runtime.launch(kern, self.queue, grid, None, u,
                           self.layers[layer][0].data, self.layers[layer][1].data, np.uint32(H),
                           np.uint32(W), np.uint32(C), np.uint32(layer), np.uint32(frame0),
                           self.key[0], self.key[1], np.int32(farthest))
            return
        runtime.launch(self._composite, self.queue, ((H * W + 3) // 4, C, frames), None,
                       *COMPOSITE_LAYER.args(
                           u=u, color=self.layers[layer][0].data,
                           alpha=self.layers[layer][1].data,
                           npix=H * W, n_channels=C, layer=layer, frame0=frame0, colour0=0,
                           key_lo=self.key[0], key_hi=self.key[1], farthest=int(farthest)))

    def _layer_plans(self, frames: int):
        """The two-pass layer's plans over its row spectrum ``[frames*C, H, row_pitch]`` (kept
        in :class:`PlanSets`: two batch sizes at most)."""
        return self._two_pass_plans.get(frames, self._make_layer_plans,
                                        pinned=self.frames_per_batch)

    def _make_layer_plans(self, frames: int):
        from clholo.fft import FFTCallback, FFTPlan, RoundTripPlan

        (H, W), (Hp, Wp), C = self.shape, self.padded, self.mpi.channels
        B, q, v, P = frames * C, self.queue, self.variant, self.row_pitch
        rows = (B, H, Wp)
        composite = FFTCallback('#include "composite_store.h"\n',
                                params=COMPOSITE_STORE_PARAMS,
                                defines=self._layer_defines())
        return (FFTPlan(rows, np.complex64, queue=q, axes=(-1,), input_shape=(W,),
                        output_shape=(P,), variant=v),
                RoundTripPlan(rows, Hp, np.complex64, axis="cols", first="forward",
                              queue=q, variant=v, pitch=P),
                RoundTripPlan(rows, Wp, np.complex64, axis="rows", first="inverse",
                              mid_n=W, mid_callback=composite, queue=q, variant=v,
                              pitch=P),
                FFTPlan(rows, np.complex64, queue=q, axes=(-1,), input_shape=(P,),
                        output_shape=(W,), variant=v))

    def _row_spectrum_buffer(self, frames: int) -> "cla.Array":
        """The two-pass layer's row spectrum ``[frames*C, H, row_pitch]`` (its first ``Wp``
        columns hold the spectrum): a view of one buffer that every batch size shares (grown
        when a larger batch comes)."""
        H, C = self.shape[0], self.mpi.channels
        B = frames * C
        if self._row_spectrum is None or self._row_spectrum.shape[0] < B:
            self._row_spectrum = cla.empty(self.queue, (B, H, self.row_pitch), np.complex64)
        return self._row_spectrum[:B]

    def _enqueue_two_pass(self, frame0: int, frames: int, field: "cla.Array") -> "cla.Array":
        """The layer loop with a layer as two kernels (see the module docstring)."""
        L, (H, W), C = self.mpi.layers, self.shape, self.mpi.channels
        row_forward, columns, rows, row_inverse = self._layer_plans(frames)
        spec = self._row_spectrum_buffer(frames)
        flat = field.reshape((frames * C, H, W))
        self._launch_composite(field.data, L - 1, frame0, frames, farthest=True)
        row_forward.execute(flat, out=spec)
        for i in range(L - 1, -1, -1):
            columns.execute(spec, out=spec, multiply=self.even_transfer_functions(i, columns))
            if i > 0:
                rows.execute(spec, out=spec, mid_args=[
                    *self.layers[i - 1], np.uint32(W), np.uint32(C),
                    np.uint32(i - 1), np.uint32(frame0), self.key[0], self.key[1]])
            else:
                row_inverse.execute(spec, out=flat, inverse=True)
        return field

    def even_transfer_functions(self, step: int, plan) -> "EvenFactors":
        """:meth:`transfer_functions` as a column round trip reads them fastest
        (:meth:`clholo.propagation.TransferFunctionCache.get_even`: on CPUs laid out strip by
        strip, half their bytes; the same bits).

        Parameters
        ----------
        step : int
            The propagation after layer ``step``.
        plan : clholo.fft.RoundTripPlan
            The two-pass layer's column round trip over the padded grid's columns.

        Returns
        -------
        clholo.fft.EvenFactors
        """
        return self._tf_cache.get_even(self.queue, plan, self.padded, float(self.steps[step]),
                                       wavelengths=self.optics.wavelengths,
                                       pitch=self.optics.pitch, band_limit=self.band_limit,
                                       dtype=np.complex64)

    def transfer_functions(self, step: int) -> "cla.Array":
        """``[C, Hp, Wp]`` transfer functions of the propagation after layer ``step``."""
        return self._tf_cache.get(self.queue, self.padded, float(self.steps[step]),
                                  wavelengths=self.optics.wavelengths, pitch=self.optics.pitch,
                                  band_limit=self.band_limit, dtype=np.complex64)

    def enqueue_batch(self, frame0: int, frames: int, field: "cla.Array") -> "cla.Array":
        """Enqueue the whole layer loop for frames ``frame0 .. frame0+frames-1`` into ``field``
        (complex64 ``[frames, C, H, W]``); returns without waiting.

        Parameters
        ----------
        frame0 : int
            Absolute index of the first frame (a whole number >= 0; ``frame0 + frames`` at most
            ``2**32``).
        frames : int
            Frames of the batch (>= 1).
        field : pyopencl.array.Array
            complex64 ``[frames, C, H, W]`` on this renderer's device.

        Returns
        -------
        pyopencl.array.Array
            ``field``, its kernels enqueued.

        Raises
        ------
        clholo.errors.InputTypeError
            ``frame0`` or ``frames`` not a whole number (``int()`` would cut 2.9 to frame 2,
            another frame's phases, where :meth:`enqueue_frames` refused it).
        clholo.errors.InputError
            Frames outside ``[0, 2**32)``.
        ValueError
            ``field`` of another shape or dtype.
        """
        from clholo import validate

        frame0, frames = validate.frame_range(frame0, frames, start_name="frame0")
        L, (H, W), C = self.mpi.layers, self.shape, self.mpi.channels
        if field.shape != (frames, C, H, W) or field.dtype != np.complex64:
            raise ValueError(f"field must be complex64 {(frames, C, H, W)}, got "
                             f"{field.dtype} {field.shape}")
        with self._lock:  # one thread's batch at a time through the shared working buffers
            if self.two_pass:
                return self._enqueue_two_pass(frame0, frames, field)
            prop = self._propagator(frames)
            flat = field.reshape((frames * C, H, W))
            if not self.occlusion:
                return self._enqueue_layer_sum(frame0, frames, field, prop)
            for i in range(L - 1, -1, -1):
                if i == L - 1 or not self.fuse_composite:
                    self._launch_composite(field.data, i, frame0, frames, farthest=i == L - 1)
                store_args = None
                if self.fuse_composite and i > 0:
                    store_args = [*self.layers[i - 1], np.uint32(W), np.uint32(C),
                                  np.uint32(i - 1), np.uint32(frame0), self.key[0], self.key[1]]
                prop.apply(flat, self.transfer_functions(i), out=flat, store_args=store_args,
                           tf_even=True)
            return field

    def _enqueue_layer_sum(self, frame0: int, frames: int, field: "cla.Array",
                           prop) -> "cla.Array":
        """``occlusion=False``, the RGB-D baseline of HOLOGRAPHY.md section 7: every layer's own
        wave ``sqrt(c_i a_i) exp(i phi_i)`` propagated from its depth straight to z = 0 and
        summed. (Not the recursion with transmission 1: that crops to the image at every
        intermediate plane and loses light that would diffract back in.) Same phases as the
        MPI method: layer i, frame, colour of the one stream."""
        L, (H, W), C = self.mpi.layers, self.shape, self.mpi.channels
        scratch = self._scratch.get(frames, self._make_scratch, pinned=self.frames_per_batch)
        flat = scratch.reshape((frames * C, H, W))
        for i in range(L):
            # "farthest": the emission alone, nothing behind
            self._launch_composite(scratch.data, i, frame0, frames, farthest=True)
            tf = self._tf_cache.get(self.queue, self.padded, float(self.mpi.depths[i]),
                                    wavelengths=self.optics.wavelengths,
                                    pitch=self.optics.pitch, band_limit=self.band_limit,
                                    dtype=np.complex64)
            prop.apply(flat, tf, out=flat, tf_even=True)
            if i == 0:
                cl.enqueue_copy(self.queue, field.data, scratch.data)
            else:
                with runtime.pyopencl_op():  # pyopencl's shared kernel: see pyopencl_op
                    field += scratch
        return field

    def enqueue_frames(self, frame0: int, frames: int, out: "cla.Array") -> "cla.Array":
        """Enqueue frames ``frame0 .. frame0+frames-1`` into ``out`` (complex64
        ``[frames, C, H, W]`` on this renderer's device) in launches of at most
        :attr:`frames_per_batch` frames; returns ``out`` without waiting.

        The device-side twin of :meth:`iter_frames`: frame ``t`` is the same hologram, bit for
        bit, whatever ``frame0`` and the batching (phases depend on the absolute frame index).
        """
        from clholo import validate

        # a whole number (int() would cut 1.9 to frame 1, another frame's phases), and the
        # whole range checked before the first batch: a batch refused part-way would leave the
        # earlier ones written into out
        frame0, T = validate.frame_range(frame0, frames, start_name="frame0")
        C, (H, W) = self.mpi.channels, self.shape
        if not isinstance(out, cla.Array):
            raise ValueError(f"out must be a pyopencl device array, complex64 {(T, C, H, W)}, "
                             f"got {type(out).__module__}.{type(out).__name__}: leave out= off "
                             f"to get the frames as NumPy")
        if out.shape != (T, C, H, W) or out.dtype != np.complex64 or not out.flags.c_contiguous:
            order = "" if out.flags.c_contiguous else "a non-contiguous "
            raise ValueError(f"out must be a C-contiguous complex64 device array "
                             f"{(T, C, H, W)}, got {order}{out.dtype} {out.shape}")
        if out.context != self.queue.context:
            raise ValueError("out is a device array of another OpenCL context than the "
                             "renderer's: pass queue=out.queue")
        Tb = min(self.frames_per_batch, T)
        if Tb == T and out.offset == 0:
            return self.enqueue_batch(frame0, T, out)
        frame_bytes = C * H * W * 8
        for t0 in range(0, T, Tb):
            n = min(Tb, T - t0)
            with self._lock:  # the batch buffer is read by the copy before another batch
                buf = self._batch_buffer(n)
                self.enqueue_batch(frame0 + t0, n, buf)
                cl.enqueue_copy(self.queue, out.base_data, buf.data,
                                dst_offset=out.offset + t0 * frame_bytes,
                                byte_count=n * frame_bytes)
        return out

    def _batch_buffer(self, frames: int) -> "cla.Array":
        """The renderer's own ``[frames, C, H, W]`` complex64 buffer of a batch that
        :meth:`enqueue_frames` renders before copying it into place: allocated once per batch
        and kept (an allocation per call can wait for the device on some drivers), sized for the
        largest batch so far; smaller batches use its front. The queue is in order, so the next
        batch's kernels write it after the copy has read it."""
        buf = self._batch
        if buf is None or buf.shape[0] < frames:
            C, (H, W) = self.mpi.channels, self.shape
            buf = self._batch = cla.empty(self.queue, (frames, C, H, W), np.complex64)
        return buf[:frames]  # a smaller batch (the last one) uses the front of the same buffer

    def render(self, frames: int, *, out: Optional["cla.Array"] = None) -> "cla.Array":
        """All ``frames`` holograms on the device, complex64 ``[T, C, H, W]``.

        Parameters
        ----------
        frames : int
            ``T``, the number of frames, from frame 0.
        out : pyopencl.array.Array, optional
            Device array ``[T, C, H, W]`` complex64 to render into; default a new one.
        """
        T = _check_frames(frames)
        C, (H, W) = self.mpi.channels, self.shape
        if out is None:
            out = cla.empty(self.queue, (T, C, H, W), np.complex64)
        elif out.shape != (T, C, H, W) or out.dtype != np.complex64:
            raise ValueError(f"out must be complex64 {(T, C, H, W)}, got {out.dtype} {out.shape}")
        return self.enqueue_frames(0, T, out)

    def iter_frames(self, frames: int, *, start: int = 0,
                    frames_per_batch: Optional[int] = None
                    ) -> Iterator[Tuple[int, np.ndarray]]:
        """Yield ``(t0, holograms)`` with ``holograms`` NumPy complex64 ``[n, C, H, W]`` for
        frames ``t0 .. t0+n-1``, as soon as each batch is finished.

        The next batch is already enqueued when a batch is yielded, so the device computes
        while the caller displays or stores (double buffering). Frame ``t`` is the same
        hologram whatever the batching: phases depend on the absolute frame index.

        Parameters
        ----------
        frames : int
            Number of frames to yield in all.
        start : int
            Absolute index of the first frame (its phases are those of frame ``start``);
            ``start + frames`` at most ``2**32``.
        frames_per_batch : int, optional
            Frames per batch (>= 1); default what the renderer's memory budget allows.

        Returns
        -------
        iterator of (int, numpy.ndarray)
            The batches, made one at a time (a display loop's ``frames`` may be large).

        Raises
        ------
        clholo.errors.InputTypeError, clholo.errors.InputError
            At the call, before any work: counts that are not whole numbers, or frames beyond
            the phase stream (``start + frames > 2**32``), which used to be refused only at
            the batch that crossed it, after the earlier ones were yielded.
        """
        from clholo import validate

        # a whole number: int() would cut 2.7 to frame 2 (another frame's phases)
        start, T = validate.frame_range(start, frames)
        Tb = validate.optional_count(frames_per_batch, name="frames_per_batch")
        return self._iter_frames(start, T, min(Tb or self.frames_per_batch, T))

    def _iter_frames(self, start: int, T: int, Tb: int) -> Iterator[Tuple[int, np.ndarray]]:
        """:meth:`iter_frames` once its arguments are checked."""
        C, (H, W) = self.mpi.channels, self.shape
        buffers = [cla.empty(self.queue, (Tb, C, H, W), np.complex64) for _ in range(2)]
        pending = None  # (t0, n, host array, copy event)
        # batches made as they come (a list of all of them took 7 GB before frame one for
        # frames=10**8 and one frame a batch)
        for k, t0 in enumerate(range(0, T, Tb)):
            n = min(Tb, T - t0)
            buf = buffers[k % 2][:n]  # the last batch may be smaller: the front of a buffer
            self.enqueue_batch(start + t0, n, buf)
            host = np.empty((n, C, H, W), np.complex64)
            event = cl.enqueue_copy(self.queue, host, buf.data, is_blocking=False)
            if pending is not None:
                pending[3].wait()
                yield start + pending[0], pending[2]
            pending = (t0, n, host, event)
        if pending is not None:
            pending[3].wait()
            yield start + pending[0], pending[2]


def _check_frames(frames) -> int:
    from clholo import validate

    return validate.count(frames, name="frames")
