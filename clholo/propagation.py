"""Angular spectrum propagation on the OpenCL device.

The same physics as :func:`clholo.reference.propagate` (band-limited ASM, exact ``fftfreq``
grid, zero padding, top-left placement), built from a transfer-function builder
(:func:`build_transfer_function`, cached) and an applier (:class:`ASMPropagator`) whose two FFTs
carry the padding, the multiply by ``H`` and the crop inside their passes.

Padding on the device
---------------------
Our FFT takes sizes ``2^a 3^b 5^c`` (:func:`clholo.fft.next_fft_size`), so every padded size is
rounded up to the next such size (:func:`device_padded_shape`), from 8 up at most 25% above it
(1080, 1152, 1200, 1920, 2160 are accepted as they are):

* ``pad="auto"``: the smallest accepted size per axis that covers the field plus the kernel's
  spread ``|dz| tan(asin(lambda / 2p)) / p`` pixels (capped at 2N, which covers any distance).
  What it costs against ``pad=2`` comes from the band-limited kernel's sinc tail, which reaches
  past the geometric spread. Measured on real scenes (RGB holograms, 2 frames, relative L2 of
  the hologram / of the focal slices at the nearest and farthest layer, focal stacks at pad=2):

  ============================================  ==========  ===========  ========  ======
  scene (field)                                 auto grid   pad=2 grid   hologram  focal
  ============================================  ==========  ===========  ========  ======
  motorcycle RGB-D, 8 layers, 2-6 mm (500x741)  512 x 768   1000 x 1500  9.6e-3    5.6e-3
  motorcycle RGB-D, 32 layers, 2-10 mm          512 x 768   1000 x 1500  1.1e-2    6.9e-3
  twain MPI, 32 layers, 2-6 mm (784x1040)       800 x 1080  1600 x 2160  6.0e-3    2.6e-3
  ============================================  ==========  ===========  ========  ======

  With power-of-two grids (before radix 3 and 5) the same rows read 9.3e-3/5.5e-3,
  1.1e-2/6.7e-3 on 512 x 1024 and 4.8e-4/3.3e-4 for twain on 1024 x 2048: the auto grid now
  hugs the spread (2.5x fewer samples for twain, 1.3x for motorcycle), so the sinc tail that
  a generous power of two used to absorb shows up; use ``pad=2`` where a percent matters, or
  a pair ``(Hp, Wp)`` with a margin.
* a number ``s``: ``next_fft_size(ceil(N s))`` per axis (``pad=2`` on 384 columns gives 768).
* a pair ``(Hp, Wp)``: exactly that, each an accepted size >= the field's.

Compare with the reference at the same padded size: ``reference.propagate(..., pad=(Hp, Wp))``.
"""

from __future__ import annotations

import math
import threading
from fractions import Fraction
import weakref
from collections import OrderedDict
from typing import Optional, Sequence, Tuple, Union

import numpy as np
import pyopencl as cl
import pyopencl.array as cla

from clholo import reference, validate
from clholo.errors import InputError, InputTypeError
from clholo._arrays import (check_complex, check_precision, fetch, host_result, program_defines,
                            resolve_queue, to_device_readonly)
from clholo.fft import is_fft_size, next_fft_size
from clholo.host import runtime

__all__ = ["device_padded_shape", "next_pow2", "build_transfer_function",
           "TransferFunctionCache", "ASMPropagator", "propagate"]

Pad = Union[str, float, int, Tuple[int, int]]

MAX_FFT_SIZE = 8192


def next_pow2(n: int) -> int:
    return 1 << max(0, int(n - 1).bit_length())


def device_padded_shape(shape: Tuple[int, int], dz: Union[float, Sequence[float]], *,
                        wavelength: Union[float, Sequence[float]], pitch: float,
                        pad: Pad = "auto") -> Tuple[int, int]:
    """Padded grid (sizes ``2^a 3^b 5^c``) used on the device for a field of ``shape``.

    ``dz`` and ``wavelength`` may be sequences: the result covers the largest spread among them
    (one padded grid for every step and colour of a hologram).
    """
    H, W = (int(s) for s in shape)
    pad = validate.pad(pad)
    # the units first (NaN, nanometres, a pitch of 0 gave bare Python errors or wrong grids);
    # the entry points that call this have warned about far distances already
    with validate.far_warned_already():
        # every distance checked at once (a focal stack may have thousands); the spread grows
        # with |dz|, so only the largest sizes the grid
        farthest = float(np.max(np.abs(validate.depths(dz, name="dz", positive=False))))
        _check_optics(farthest, wavelength, pitch)
    if isinstance(pad, (tuple, list, np.ndarray)):
        Hp, Wp = reference.padded_shape((H, W), 0.0, wavelength=1e-6, pitch=1.0, pad=pad)
        _check_fft_limit((H, W), (Hp, Wp), pad)
        for axis, (n, name) in enumerate(((Hp, "rows"), (Wp, "columns"))):
            if not is_fft_size(n):
                raise ValueError(
                    f"pad shape axis {axis} ({name}) = {n} has a prime factor other than 2, 3 "
                    f"and 5; the FFT needs sizes 2^a 3^b 5^c: use {next_fft_size(n)}")
    else:
        if not isinstance(pad, str) and math.isfinite(float(pad)) and float(pad) >= 1:
            # exact, before any float product can overflow (pad 1e308 on 125 rows)
            factor = Fraction(float(pad))
            _check_fft_limit((H, W), (math.ceil(factor * H), math.ceil(factor * W)), pad)
        lams = np.atleast_1d(np.asarray(wavelength, dtype=float))
        Hp = Wp = 0
        for lam in lams:
            h, w = reference.padded_shape((H, W), farthest, wavelength=float(lam), pitch=pitch,
                                          pad=pad)
            Hp, Wp = max(Hp, h), max(Wp, w)
        # the limit before the search: a size beyond it is refused at once, whatever its size
        _check_fft_limit((H, W), (Hp, Wp), pad)
        Hp, Wp = next_fft_size(Hp), next_fft_size(Wp)
        _check_fft_limit((H, W), (Hp, Wp), pad)  # rounding up may cross it (8193..8191 + 1)
    return Hp, Wp


def _check_fft_limit(shape: Tuple[int, int], padded: Tuple[int, int], pad: Pad) -> None:
    """Refuse a padded grid beyond :data:`MAX_FFT_SIZE` per axis, naming the grid it would need
    and the largest padding this field can have."""
    H, W = shape
    Hp, Wp = padded
    if max(Hp, Wp) <= MAX_FFT_SIZE:
        return
    if max(H, W) > MAX_FFT_SIZE:
        fix = (f"the field ({H} x {W}) is itself larger: use a field of at most "
               f"{MAX_FFT_SIZE} pixels per axis")
    elif isinstance(pad, str):
        fix = f"use a field of at most {MAX_FFT_SIZE // 2} pixels per axis, or pad 1"
    elif isinstance(pad, (tuple, list, np.ndarray)):
        fix = f"the largest pad shape is ({MAX_FFT_SIZE}, {MAX_FFT_SIZE})"
    else:
        # MAX_FFT_SIZE is 2^13: the largest factor s with ceil(N s) <= MAX_FFT_SIZE is its own
        # next FFT size, so it is the largest pad that works on this field
        largest = math.floor(MAX_FFT_SIZE / max(H, W) * 1000) / 1000
        fix = f"the largest pad for this {H} x {W} field is {largest:g} (or use pad 'auto')"
    raise ValueError(
        f"pad {_pad_text(pad)} needs a padded grid of {_size_text(Hp)} x {_size_text(Wp)}, but "
        f"the FFT's largest size is {MAX_FFT_SIZE} per axis: {fix}")


def _size_text(n: int) -> str:
    """A size in digits, or in powers of ten beyond 15 digits (exact ints of any length)."""
    digits = str(int(n))
    if len(digits) <= 15:
        return digits
    return f"{digits[0]}.{digits[1:3]}e+{len(digits) - 1}"


def _pad_text(pad: Pad) -> str:
    if isinstance(pad, str):
        return repr(pad)
    if isinstance(pad, (tuple, list, np.ndarray)):
        return str(tuple(int(p) for p in pad))
    return f"{float(pad):g}"


def _check_optics(dz, wavelengths, pitch) -> Tuple[float, list, float]:
    """The one set of unit checks (:mod:`clholo.validate`) for every propagation entry point."""
    dz = validate.distance(dz, name="dz")
    pitch = validate.pitch(pitch)
    # one wavelength may be given as a number (``wavelengths=520e-9``)
    lams = [validate.wavelength(w) for w in
            ([wavelengths] if np.ndim(wavelengths) == 0 else wavelengths)]
    if not lams:
        raise InputError("wavelengths is empty: give one wavelength in metres per "
                                  "colour channel, e.g. [520e-9]")
    for w in lams:
        validate.wavelength_for_pitch(w, pitch)
    return dz, lams, pitch


def _complex_dtype(dtype) -> np.dtype:
    """``dtype`` as complex64 or complex128, or an error naming it."""
    try:
        dt = np.dtype(dtype)
    except TypeError:
        dt = None
    if dt not in (np.dtype(np.complex64), np.dtype(np.complex128)):
        raise InputTypeError(f"dtype={dt.name if dt is not None else repr(dtype)}: transfer "
                             f"functions are complex64 or complex128")
    return dt


def transfer_function_kernel(queue: "cl.CommandQueue", dtype=np.complex64) -> "cl.Kernel":
    """The ``asm_transfer_function`` kernel :func:`build_transfer_function` launches for
    ``dtype`` on ``queue``'s device, built (once per context): renderers call it to build their
    programs before they are timed."""
    fp64 = runtime.has_fp64(queue.device)
    defines = dict(program_defines(dtype))
    defines["TF_REAL"] = "double" if fp64 else "float"
    if fp64:
        defines["CLHOLO_FP64"] = True
    return runtime.get_kernel(queue.context, "asm.cl", "asm_transfer_function", defines=defines)


def build_transfer_function(queue: "cl.CommandQueue", padded: Tuple[int, int], dz: float, *,
                            wavelengths: Sequence[float], pitch: float, band_limit: bool = True,
                            dtype=np.complex64, out: Optional["cla.Array"] = None) -> "cla.Array":
    """Band-limited ASM transfer functions ``[C, Hp, Wp]`` on the device, one per wavelength.

    Same function as :func:`clholo.reference.transfer_function` (the ``fftfreq`` grid, the
    band limit, evanescent frequencies zero), even in both frequencies, bin for bin, as
    :meth:`ASMPropagator.apply`'s ``tf_even`` expects. The phase is the carrier
    ``2 pi dz / lambda`` reduced mod 2 pi on the host plus the remainder
    ``-2 pi dz f^2 / (1/lambda + sqrt(1/lambda^2 - f^2))`` in double, reduced mod 2 pi:

    * on devices with fp64, ``kernels/asm.cl`` computes the remainder in double and its sine
      in the precision of ``dtype``: within 5e-7 of the complex128 reference from millimetres
      to metres (8192-point grids at 20 cm and 1 m, ``clholo selftest`` checks both);
    * on devices without fp64 the remainder in float32 would be off by 3e-4 rad at 20 cm on an
      8192-point grid and by radians at sub-micron pitches, so the host computes the same
      function in float64 (the kernel's formulas, on the quarter of non-negative frequencies,
      mirrored) and uploads it in ``dtype``: rounded once, as accurate as with fp64. It costs
      host time (about half a second per colour for 4096 x 4096, four times that for 8192 x
      8192); callers cache it
      (:class:`TransferFunctionCache`), once per distance.

    Parameters
    ----------
    queue : pyopencl.CommandQueue
        Queue to build on; the result lives in its context.
    padded : (int, int)
        The padded grid ``(Hp, Wp)``, sizes >= 1.
    dz : float
        Propagation distance, metres.
    wavelengths : sequence of float
        The ``C`` wavelengths, metres.
    pitch : float
        Sample pitch, metres.
    band_limit : bool
        Apply the Matsushima-Shimobaba band limit (default).
    dtype : complex64 or complex128
        The kernel writes complex values: a real ``out`` would be written past its end.
    out : pyopencl.array.Array, optional
        A C-contiguous device array ``[C, Hp, Wp]`` of ``dtype`` on ``queue``'s context.

    Returns
    -------
    pyopencl.array.Array, shape (C, Hp, Wp), ``dtype``
    """
    from clholo._arrays import check_context

    dtype = _complex_dtype(dtype)
    Hp, Wp = validate.shape2d(padded, name="padded")
    band_limit = validate.flag(band_limit, name="band_limit")
    dz, lams, pitch = _check_optics(dz, wavelengths, pitch)
    check_precision(queue, dtype, "build_transfer_function(dtype=complex128)")
    C = len(lams)
    fp64 = runtime.has_fp64(queue.device)

    def limits(n):
        if not band_limit:
            return [np.inf] * C
        return [1.0 / (lam * math.sqrt((2.0 * dz / (n * pitch)) ** 2 + 1.0)) for lam in lams]

    consts = np.array([[1.0 / lam for lam in lams],
                       [math.fmod(2.0 * math.pi * dz / lam, 2.0 * math.pi) for lam in lams],
                       limits(Hp), limits(Wp)], dtype=np.float64)
    if out is None:
        out = cla.empty(queue, (C, Hp, Wp), dtype)
    elif not isinstance(out, cla.Array):
        raise InputTypeError(f"out must be a pyopencl device array {dtype} "
                                      f"{(C, Hp, Wp)}, got {type(out).__name__}")
    elif out.shape != (C, Hp, Wp) or out.dtype != dtype or not out.flags.c_contiguous \
            or out.offset:
        raise ValueError(f"out must be a C-contiguous {dtype} device array {(C, Hp, Wp)} "
                         f"(no offset), got {out.dtype} {out.shape}")
    else:
        check_context(queue, out, name="out")
    if not fp64:
        _host_transfer_function(queue, out, (Hp, Wp), consts, pitch, 2.0 * math.pi * dz)
        return out
    kern = transfer_function_kernel(queue, dtype)
    dconsts = cla.to_device(queue, consts)
    # OpenCL defers releasing dconsts until the kernel that uses it has run
    # round the range up to a multiple of 16 so the driver can pick wide work-groups (the
    # kernel returns early outside the quarter)
    gx = -(-(Wp // 2 + 1) // 64) * 16  # four x per work-item
    runtime.launch(kern, queue, (gx, C * (Hp // 2 + 1)), None, out.data, np.uint32(Hp), np.uint32(Wp),
         np.float64(1.0 / (Hp * pitch)), np.float64(1.0 / (Wp * pitch)), dconsts.data,
         np.uint32(C), np.float64(2.0 * math.pi * dz))
    return out


#: Quarter rows the host transfer function computes at a time: its float64 temporaries stay
#: a few MiB whatever the grid (an 8192-point grid's whole quarter would take 134 MiB each)
_HOST_TF_ROWS = 256


def _host_transfer_function(queue, out: "cla.Array", padded: Tuple[int, int],
                            consts: np.ndarray, pitch: float, two_pi_dz: float) -> None:
    """``kernels/asm.cl``'s ``asm_transfer_function`` in float64 on the host, written to
    ``out [C, Hp, Wp]`` (for devices without fp64, where the kernel's float32 remainder is
    out of tolerance at accepted distances).

    ``consts`` is the kernel's ``[4, C]`` table (``1/lambda``, the reduced carrier, the band
    limits of rows and columns). Like the kernel it evaluates the quarter of non-negative
    frequency indices ``0..Hp/2 x 0..Wp/2`` and writes each value to its mirrored bins too,
    so the result is exactly even in both frequencies; rows are done in blocks and uploaded
    as they are made.
    """
    Hp, Wp = padded
    hh, hw = Hp // 2, Wp // 2
    C = consts.shape[1]
    dtype = out.dtype
    item = dtype.itemsize
    fx = np.arange(hw + 1, dtype=np.float64) * (1.0 / (Wp * pitch))
    fx2 = fx * fx
    for c in range(C):
        il, carrier, lim_y, lim_x = (float(v) for v in consts[:, c])
        il2 = il * il
        in_x = fx < lim_x
        plane = c * Hp * Wp
        for q0 in range(0, hh + 1, _HOST_TF_ROWS):
            q1 = min(hh + 1, q0 + _HOST_TF_ROWS)
            fy = np.arange(q0, q1, dtype=np.float64)[:, None] * (1.0 / (Hp * pitch))
            f2 = fx2[None, :] + fy * fy
            inside = (f2 < il2) & in_x[None, :] & (fy < lim_y)
            root = np.sqrt(np.maximum(il2 - f2, 0.0))
            phase = carrier - two_pi_dz * f2 / (il + root)
            phase -= np.rint(phase * (0.5 / math.pi)) * (2.0 * math.pi)
            quarter = np.where(inside, np.exp(1j * phase), 0.0).astype(dtype)
            rows = np.empty((q1 - q0, Wp), dtype)
            rows[:, :hw + 1] = quarter
            rows[:, hw + 1:] = quarter[:, Wp - hw - 1:0:-1]  # column x = Wp - kx, kx >= 1
            cl.enqueue_copy(queue, out.data, rows, dst_offset=(plane + q0 * Wp) * item)
            # rows Hp - q for the quarter rows q >= 1 that have a mirror of their own (row 0
            # and, on an even grid, row Hp/2 are their own mirrors)
            qs, qe = max(q0, 1), min(q1, Hp - hh)
            if qs < qe:
                mirror = np.ascontiguousarray(rows[qs - q0:qe - q0][::-1])
                cl.enqueue_copy(queue, out.data, mirror,
                                dst_offset=(plane + (Hp - qe + 1) * Wp) * item)


class TransferFunctionCache:
    """LRU cache of device transfer functions with a byte budget, one per context.

    Keyed by (padded shape, dz, wavelengths, pitch, band limit, dtype). A hologram needs
    ``L`` of them (one per layer step, all colours in one array) and every frame reuses them,
    so a display loop that re-renders the same depths builds them once.

    Parameters
    ----------
    budget_bytes : int
        The most bytes it holds; past it the least recently used go first, and an array
        larger than the whole budget is built and returned but not kept.
        :func:`transfer_function_cache` sizes each context's (a quarter of the device's
        memory, less on CPU devices).

    Notes
    -----
    Every propagation entry point shares its context's cache, so a sweep over many
    distances fills it up to the budget and keeps it filled: :meth:`clear` gives the memory
    back. Thread-safe.
    """

    def __init__(self, budget_bytes: int):
        self.budget_bytes = int(budget_bytes)
        self._items: "OrderedDict[tuple, cla.Array]" = OrderedDict()
        self._bytes = 0
        self._lock = threading.Lock()

    def get(self, queue, padded, dz, *, wavelengths, pitch, band_limit=True, dtype=np.complex64):
        """The transfer functions ``[C, Hp, Wp]`` of ASM by ``dz`` metres (built on a miss by
        :func:`build_transfer_function`). Shared: callers must not write to it."""
        key = self.key(padded, dz, wavelengths=wavelengths, pitch=pitch, band_limit=band_limit,
                       dtype=dtype)
        return self.get_or_build(key, lambda: build_transfer_function(
            queue, padded, dz, wavelengths=wavelengths, pitch=pitch, band_limit=band_limit,
            dtype=dtype))

    @staticmethod
    def key(padded, dz, *, wavelengths, pitch, band_limit=True, dtype=np.complex64) -> tuple:
        """The cache key of :meth:`get`'s transfer functions (callers that fold something in
        put what it is in front of it)."""
        return (tuple(int(n) for n in padded), float(dz), tuple(float(w) for w in wavelengths),
                float(pitch), bool(band_limit), np.dtype(dtype).str)

    def get_even(self, queue, plan, padded, dz, *, wavelengths, pitch, band_limit=True,
                 dtype=np.complex64):
        """The transfer functions of :meth:`get` as ``plan``'s
        :meth:`clholo.fft.RoundTripPlan.even_factors` (``plan`` a column round trip over the
        padded grid's columns). Where ``plan`` reads them strip by strip (CPUs) the strips
        are cached on their own, under the plan's ``even_key``: made from transfer functions
        built for them and dropped (half their bytes); elsewhere they are the cached
        transfer functions themselves. Shared: callers must not write to them."""
        from clholo.fft import even_strip_lanes

        kw = dict(wavelengths=wavelengths, pitch=pitch, band_limit=band_limit, dtype=dtype)
        if not even_strip_lanes(plan.geometry):
            return plan.even_factors(self.get(queue, padded, dz, **kw))
        key = ("even factors",) + plan.even_key + self.key(padded, dz, **kw)
        return self.get_or_build(key, lambda: plan.even_factors(
            build_transfer_function(queue, padded, dz, **kw)))

    def get_or_build(self, key: tuple, build) -> "cla.Array":
        """The array cached under ``key``, else ``build()``'s, kept within the budget (for
        transfer functions with something folded in, e.g. DPAC's Fourier filter, whose key
        must then say so; or anything else with an ``nbytes``, e.g.
        :class:`clholo.fft.EvenFactors`). Shared: callers must not write to it."""
        with self._lock:
            hit = self._items.get(key)
            if hit is not None:
                self._items.move_to_end(key)
                return hit
        # Every caller of a cache is an entry point that has checked its distances and warned
        # about a far one at the user's line: a build does not warn again from inside clholo.
        with validate.far_warned_already():
            tf = build()
        with self._lock:
            hit = self._items.get(key)
            if hit is not None:  # another thread built it meanwhile: keep one, count it once
                self._items.move_to_end(key)
                return hit
            if tf.nbytes <= self.budget_bytes:
                self._items[key] = tf
                self._bytes += tf.nbytes
                while self._bytes > self.budget_bytes and self._items:
                    _, old = self._items.popitem(last=False)
                    self._bytes -= old.nbytes
        return tf

    def clear(self) -> None:
        """Drop every cached transfer function (e.g. after a sweep over many distances that
        will not come again): the cache's references go at once, and the device memory with
        them unless a caller still holds an array it was given (a renderer keeps its layer
        steps' transfer functions while it lives). Later calls build what they need again;
        nothing else changes.

        Examples
        --------
        >>> from clholo.propagation import transfer_function_cache  # doctest: +SKIP
        >>> transfer_function_cache(queue.context).clear()  # doctest: +SKIP
        """
        with self._lock:
            self._items.clear()
            self._bytes = 0


_tf_caches: "weakref.WeakKeyDictionary[cl.Context, TransferFunctionCache]" = \
    weakref.WeakKeyDictionary()


#: Share of the memory the host can still give (:func:`clholo._sysmem.available_host_bytes`,
#: when the cache is made) that a CPU device's transfer-function cache may hold
HOST_CACHE_SHARE = 1 / 8


def transfer_function_cache(context: "cl.Context") -> TransferFunctionCache:
    """The context's transfer-function cache (made on first use, kept while the context
    lives; :meth:`TransferFunctionCache.clear` empties it).

    Its budget is a quarter of the device's global memory (a 32-layer hologram on a 2048^2
    padded grid needs 1 GiB of them). On a CPU device, whose buffers are host memory and
    whose reported global memory is about all of the host's RAM, it is at most an eighth
    (:data:`HOST_CACHE_SHARE`) of what the host can still give when the cache is made: a
    quarter would let the cache of a long sweep over distances hold gigabytes of RAM that
    no host-memory check counts.
    """
    cache = _tf_caches.get(context)
    if cache is None:
        budget = min(d.global_mem_size for d in context.devices) // 4
        if any(int(d.type) & cl.device_type.CPU for d in context.devices):
            from clholo._sysmem import available_host_bytes

            budget = min(budget, int(available_host_bytes() * HOST_CACHE_SHARE))
        cache = _tf_caches[context] = TransferFunctionCache(budget)
    return cache


class ASMPropagator:
    """Applier of ASM transfer functions to a batch of fields, on the device.

    :meth:`apply` runs ``crop(IFFT2(FFT2(pad(u)) * H))`` without host synchronisation, in
    three passes where the columns fit fast memory (``three_pass``: row FFT, column round trip
    with ``H``, row inverse), else with the forward FFT that reads ``[B, H, W]`` zero-padded to
    ``(Hp, Wp)`` and the inverse FFT that multiplies by ``H`` as its first pass loads the
    spectrum and writes only the ``(H, W)`` window. (On CPU devices the multiply costs least
    there: the inverse's row pass reads whole rows of ``H`` beside the spectrum's, where the
    forward's column pass would read it at the grid's row stride.)

    Parameters
    ----------
    batch : int
        Number of fields ``B`` per call (flattened leading axes).
    shape : (int, int)
        Field size ``(H, W)``.
    padded : (int, int)
        Padded grid, sizes ``2^a 3^b 5^c`` (:func:`device_padded_shape`).
    dtype : complex64 or complex128
    queue : pyopencl.CommandQueue, optional
    load_callback : clholo.fft.FFTCallback, optional
        A load callback for the first pass: :meth:`apply` with ``load_args`` runs it on every
        element of the field ``[B, H, W]`` as it is read (SGD fuses its residual there).
    store_callback : clholo.fft.FFTCallback, optional
        A store callback for the last pass: :meth:`apply` with ``store_args`` runs it on every
        output element instead of the plain store (the four-pass renderer fuses the next
        layer's composite there, SGD its Adam step).
    three_pass : bool, optional
        Propagate in three passes over memory (issue 23): a row FFT of the padded field into
        its row spectrum ``[B, H, Wp]`` (``row_spectrum``, rows ``row_pitch`` apart), a column
        round trip that multiplies by ``H`` between its forward and inverse column FFTs
        (:class:`clholo.fft.RoundTripPlan`), and the row inverse with the crop. Default:
        wherever the column round trip fits the device's fast
        memory; ``False``: the two 2D transforms (forward, inverse with the multiply at its
        load), four passes.
    variant : {"auto", "cpu", "gpu"}
        The FFT kernels' family (:class:`clholo.fft.FFTPlan`); ``"auto"`` picks the device's.
        Tests run the GPU kernels on a CPU device with ``"gpu"``.

    Notes
    -----
    In both forms a callback sees ``(b, row, col)`` as in a 2D plan: ``b`` the field of the
    batch, ``(row, col)`` the pixel of the ``(H, W)`` field (the three-pass form's row plans
    number their lines ``b H + row``; the propagator translates). A propagator with callbacks
    also keeps the plain plans: :meth:`apply` without ``load_args`` / ``store_args`` runs them.

    Threads may share a propagator (:func:`propagate`, :func:`clholo.focal_stack` and the
    encoders share one per queue and shape): :meth:`apply` holds the propagator's lock while it
    enqueues its passes, which share the spectrum buffer, so they run back to back on its
    (in-order) queue; the result is in ``out``, the caller's own. Who runs the plans or reads
    ``row_spectrum`` / ``spectrum`` directly, outside :meth:`apply`, holds ``_lock`` over that.

    Device memory: ``8 B H Wp`` (complex64) for the row spectrum of the three-pass form, or
    ``8 B Hp Wp`` for the spectrum of the four-pass one, plus the FFT plans' work buffers (see
    :class:`clholo.fft.FFTPlan`).
    """

    def __init__(self, batch: int, shape: Tuple[int, int], padded: Tuple[int, int], *,
                 dtype=np.complex64, queue: Optional["cl.CommandQueue"] = None,
                 load_callback=None, store_callback=None, three_pass: Optional[bool] = None,
                 variant: str = "auto"):
        from clholo.fft import DeviceLimits, FFTPlan, RoundTripPlan, round_trip_fits, row_pitch

        self.queue = resolve_queue(queue)
        self.dtype = np.dtype(dtype)
        check_precision(self.queue, self.dtype, "complex128 propagation")
        # apply's passes share the spectrum buffer and the plans' work buffers: held over the
        # whole sequence, so another thread's passes cannot land between them (the launch lock
        # covers one pass only). Reentrant: a caller may hold it across its own work too.
        self._lock = threading.RLock()
        self.batch = int(batch)
        self.shape = (int(shape[0]), int(shape[1]))
        self.padded = (int(padded[0]), int(padded[1]))
        if self.padded[0] < self.shape[0] or self.padded[1] < self.shape[1]:
            raise ValueError(f"padded grid {self.padded} is smaller than the field {self.shape}")
        full = (self.batch,) + self.padded
        (H, W), (Hp, Wp) = self.shape, self.padded
        rows = (self.batch, H, Wp)
        fits = round_trip_fits(rows, Hp, self.dtype, device=DeviceLimits.of(self.queue.device),
                               axis="cols", variant=variant)
        if three_pass and not fits:
            raise ValueError(f"three_pass=True needs columns of {Hp} points that fit the "
                             f"device's fast memory; leave it unset (four passes here)")
        self.three_pass = fits if three_pass is None else bool(three_pass)
        self.load_callback, self.store_callback = load_callback, store_callback
        self._first_cb = self._last_cb = None
        kw = dict(queue=self.queue, variant=variant)
        #: Row stride of ``row_spectrum``, in elements (:func:`clholo.fft.row_pitch`)
        self.row_pitch = Wp
        if self.three_pass:
            limits = DeviceLimits.of(self.queue.device)
            P = self.row_pitch = row_pitch(Wp, self.dtype, cpu=limits.is_cpu,
                                           gpu_pitch=limits.setting("row_pitch"))
            self.row_forward = FFTPlan(rows, self.dtype, axes=(-1,), input_shape=(W,),
                                       output_shape=(P,), **kw)
            self.columns = RoundTripPlan(rows, Hp, self.dtype, axis="cols", first="forward",
                                         pitch=P, **kw)
            self.row_inverse = FFTPlan(rows, self.dtype, axes=(-1,), input_shape=(P,),
                                       output_shape=(W,), **kw)
            # the callback plans share the plain ones' work buffers (one queue, in order)
            if load_callback is not None:
                self._first_cb = FFTPlan(
                    rows, self.dtype, axes=(-1,), input_shape=(W,), output_shape=(P,),
                    load_callback=_field_rows_callback(load_callback, "load", H),
                    share_work_with=self.row_forward, **kw)
            if store_callback is not None:
                self._last_cb = FFTPlan(
                    rows, self.dtype, axes=(-1,), input_shape=(P,), output_shape=(W,),
                    store_callback=_field_rows_callback(store_callback, "store", H),
                    share_work_with=self.row_inverse, **kw)
            # [B, H, row_pitch]: the spectrum in the first Wp elements of each row
            self.row_spectrum = cla.empty(self.queue, (self.batch, H, P), self.dtype)
            return
        self.forward = FFTPlan(full, self.dtype, input_shape=self.shape, **kw)
        self.inverse = FFTPlan(full, self.dtype, output_shape=self.shape, **kw)
        if load_callback is not None:
            self._first_cb = FFTPlan(full, self.dtype, input_shape=self.shape,
                                     load_callback=load_callback,
                                     share_work_with=self.forward, **kw)
        if store_callback is not None:
            self._last_cb = FFTPlan(full, self.dtype, output_shape=self.shape,
                                    store_callback=store_callback,
                                    share_work_with=self.inverse, **kw)
        self.spectrum = cla.empty(self.queue, full, self.dtype)

    def even_factors(self, tf: "cla.Array") -> "EvenFactors":
        """Transfer functions ``tf [(M,) Hp, Wp]``, even in both frequencies as
        :func:`build_transfer_function`'s are, prepared for :meth:`apply` (the three-pass
        column round trip's :meth:`clholo.fft.RoundTripPlan.even_factors`: on CPUs a copy
        laid out strip by strip, half of ``tf``'s bytes). Make it once per transfer
        function; it does not follow later writes to ``tf``."""
        from clholo.fft import EvenFactors

        if self.three_pass:
            return self.columns.even_factors(tf)
        frames = tf if tf.ndim == 3 else tf.reshape((1,) + tuple(tf.shape))
        return EvenFactors(frames, "quarter", 0, frames.shape[0], ("four-pass",) + self.padded)

    def _as_batch(self, a, name: str):
        """``a`` as ``[B, H, W]``: its last two axes must be the propagator's ``(H, W)`` and its
        leading ones hold ``B`` fields (``[T, C, H, W]`` with ``T C = B``). Any other shape of
        as many elements is refused: reshaped, a ``[B, W, H]`` field would be propagated as
        garbage without a word."""
        want = (self.batch,) + self.shape
        shape = tuple(getattr(a, "shape", ()))
        if shape == want:
            return a
        if len(shape) < 2 or shape[-2:] != self.shape or \
                int(np.prod(shape[:-2], dtype=np.int64)) != self.batch:
            raise ValueError(f"{name}.shape is {shape}; this propagator takes {self.batch} "
                             f"fields of {self.shape[0]}x{self.shape[1]} (H, W): {want}, or "
                             f"leading axes that multiply to {self.batch} (e.g. [T, C, H, W])")
        return a.reshape(want)

    def apply(self, field: "cla.Array", tf, *, out: Optional["cla.Array"] = None,
              load_args=None, store_args=None, tf_even: bool = False) -> "cla.Array":
        """Propagate ``field [B, H, W]`` with transfer functions ``tf [(M,) Hp, Wp]``
        (field ``b`` uses ``tf[b % M]``); ``out`` may be ``field`` itself. With ``load_args``
        the first pass loads through the ``load_callback`` given at construction, with
        ``store_args`` the last pass stores through the ``store_callback``. ``tf_even=True``:
        the caller's word that ``tf`` is even in both frequencies, as
        :func:`build_transfer_function`'s are; the three-pass column round trip then reads
        only its quarter (``multiply_even`` of :meth:`clholo.fft.RoundTripPlan.execute`).
        ``tf`` may also be this propagator's :meth:`even_factors` (the fastest on CPUs;
        even implied)."""
        from clholo.fft import EvenFactors

        if isinstance(tf, EvenFactors) and not self.three_pass:
            if tf.key != ("four-pass",) + self.padded:
                raise ValueError("tf is EvenFactors made for another propagator: make them "
                                 "with this propagator's even_factors()")
            tf = tf.frames  # the four-pass inverse multiplies its whole frames
        want = (self.batch,) + self.shape
        field = self._as_batch(field, "field")
        out = cla.empty(self.queue, want, self.dtype) if out is None else \
            self._as_batch(out, "out")
        for args, plan, name in ((load_args, self._first_cb, "load"),
                                 (store_args, self._last_cb, "store")):
            if args is not None and plan is None:
                raise ValueError(f"{name}_args given but this propagator has no "
                                 f"{name}_callback")
        if self.three_pass:
            first, last, r = self.row_forward, self.row_inverse, self.row_spectrum
        else:
            first, last, r = self.forward, self.inverse, self.spectrum
        # the callback plans where their arguments are given, the plain ones otherwise
        first = self._first_cb if load_args is not None else first
        last = self._last_cb if store_args is not None else last
        # enqueued as one step: on the propagator's in-order queue the passes then run back to
        # back, and work any thread enqueues after apply returns (reading ``out``) runs after
        # them, so ``out`` is the only buffer a caller reads and it is the caller's own
        with self._lock:
            first.execute(field, out=r, load_args=load_args or ())
            if self.three_pass:
                self.columns.execute(r, out=r, multiply=tf, multiply_even=tf_even)
                last.execute(r, out=out, inverse=True, store_args=store_args or ())
            else:
                last.execute(r, out=out, inverse=True, multiply=tf, multiply_at="input",
                             store_args=store_args or ())
        return out


def _field_rows_callback(cb, kind: str, height: int):
    """``cb`` (an :class:`clholo.fft.FFTCallback` written for a 2D plan over ``[B, H, W]``
    fields: ``b`` the field, ``(row, col)`` the pixel) as a callback of a 1D row plan over
    ``[B, H, Wp]``, whose lines are numbered ``b H + row``: a wrapper under the callback's own
    name translates the position (and of ``clholo_store4``, ``clholo_load8``, ``clholo_store8``
    where the source defines ``FFT_STORE_CB_QUAD``, ``FFT_LOAD_CB_OCT``, ``FFT_STORE_CB_OCT``)."""
    from clholo.fft import FFTCallback

    if not isinstance(cb, FFTCallback):
        raise TypeError(f"{kind}_callback must be a clholo.fft.FFTCallback, got "
                        f"{type(cb).__name__}")
    names = [f"cbf{i}" for i in range(len(cb.params))]
    decl = "".join(f", {p} {n}" for p, n in zip(cb.params, names))
    args = "".join(f", {n}" for n in names)
    h = int(height)
    pos = f"b / {h}, (int)(b % {h}), col"
    # (name, its optional-form define or None, return type, parameters before b, their names)
    forms = {"load": [("clholo_load", None, "real2", "real2 v", "v"),
                      ("clholo_load8", "FFT_LOAD_CB_OCT", "void", "float16 *v", "v")],
             "store": [("clholo_store", None, "void", "__global real2 *p, real2 v", "p, v"),
                       ("clholo_store4", "FFT_STORE_CB_QUAD", "void",
                        "__global real2 *p, real2 v0, real2 v1, real2 v2, real2 v3",
                        "p, v0, v1, v2, v3"),
                       ("clholo_store8", "FFT_STORE_CB_OCT", "void",
                        "__global real2 *p, const float16 *v", "p, v")]}[kind]
    source = "".join(f"#define {f} {f}_of_field\n" for f, *_ in forms) + cb.source + "\n"
    for f, define, ret, lead, lead_names in forms:
        body = (f"#undef {f}\n{ret} {f}({lead}, long b, int row, int col{decl})\n"
                f"{{ {'return ' if ret != 'void' else ''}{f}_of_field({lead_names}, "
                f"{pos}{args}); }}\n")
        source += f"#ifdef {define}\n{body}#endif\n" if define else body
    return FFTCallback(source, params=cb.params, defines=cb.defines)


def propagate(field, dz: float, *, wavelength: float, pitch: float, pad: Pad = "auto",
              band_limit: bool = True, queue: Optional["cl.CommandQueue"] = None):
    r"""Angular spectrum propagation of ``field`` by ``dz`` metres on the OpenCL device.

    Same signature and physics as :func:`clholo.reference.propagate`; padded sizes are
    ``2^a 3^b 5^c`` (module docstring). ``pad="auto"`` on random-phase fields differs from ``pad=2`` by
    the kernel's sinc tail only: see the module docstring for the measured figures.

    Parameters
    ----------
    field : array, shape (..., H, W), complex64 or complex128
        NumPy in gives NumPy out; a pyopencl array stays on the device.
    dz : float
        Metres; positive propagates towards the viewer (+z).
    wavelength, pitch : float
        Metres.
    pad : "auto", float or (int, int)
    band_limit : bool
        Apply the Matsushima-Shimobaba band limit (default).
    queue : pyopencl.CommandQueue, optional
        Queue to run on (default: clholo's default device, ``CLHOLO_DEVICE``).

    Returns
    -------
    array, shape (..., H, W), same dtype and kind (NumPy/device) as ``field``.

    Notes
    -----
    On the padded grid of :math:`N_x \times N_y` samples at pitch :math:`p`, with frequencies
    :math:`f_x = k / (N_x p)` (NumPy's ``fftfreq``, unshifted),

    .. math::

        u' = \mathrm{crop}\left(\mathcal{F}^{-1}\left[\mathcal{F}[\mathrm{pad}(u)]\,
        e^{2\pi i\, dz \sqrt{1/\lambda^2 - f_x^2 - f_y^2}}\, B(f_x, f_y)\right]\right),

    evanescent frequencies set to zero, and :math:`B` the band limit of Matsushima and
    Shimobaba, :math:`|f_x| < 1 / (\lambda \sqrt{(2\, \Delta f_x\, dz)^2 + 1})` with
    :math:`\Delta f_x = 1/(N_x p)` (the same for :math:`y`).
    """
    if not isinstance(field, (np.ndarray, cla.Array)):
        raise TypeError(f"field must be a NumPy or pyopencl array [..., H, W] of complex64 or "
                        f"complex128, got {type(field).__name__}; convert with "
                        f"np.asarray(field, np.complex64)")
    queue = resolve_queue(validate.queue(queue), field)
    dt = check_complex("field", field)
    check_precision(queue, dt, "complex128 propagation")
    if field.ndim < 2:
        raise ValueError(f"field must be at least 2-D [..., H, W], got shape {field.shape}")
    if min(field.shape) < 1:
        raise ValueError(f"field must hold at least one pixel on every axis [..., H, W], got "
                         f"shape {field.shape}")
    band_limit = validate.flag(band_limit, name="band_limit")
    dz, (wavelength,), pitch = _check_optics(dz, [wavelength], pitch)
    if isinstance(field, np.ndarray) and not np.all(np.isfinite(field)):
        raise ValueError("field contains NaN/inf values; every value must be finite")
    shape = tuple(field.shape[-2:])
    padded = device_padded_shape(shape, dz, wavelength=wavelength, pitch=pitch, pad=pad)
    batch = int(np.prod(field.shape[:-2], dtype=np.int64)) if field.ndim > 2 else 1
    dfield, host = to_device_readonly(queue, field, name="field")
    tf = transfer_function_cache(queue.context).get(
        queue, padded, dz, wavelengths=[wavelength], pitch=pitch, band_limit=band_limit,
        dtype=dt)
    prop = _propagator(queue, batch, shape, padded, dt)
    if host:  # NumPy out: written in place on CPU devices
        host_out, out = host_result(queue, (batch,) + shape, dfield.dtype)
        prop.apply(dfield.reshape((batch,) + shape), tf, out=out, tf_even=True)
        return fetch(host_out, out).reshape(field.shape)
    out = prop.apply(dfield.reshape((batch,) + shape), tf, tf_even=True)
    return out.reshape(field.shape)


# A few propagators, most recently used last: building FFT plans and the spectrum buffer costs
# more than a small propagation. Entries hold their queue, so its handle cannot be reused while
# cached (queues cannot be weakly referenced).
_propagators: "OrderedDict[tuple, ASMPropagator]" = OrderedDict()
_MAX_PROPAGATORS = 6


def _forget_context(context: "cl.Context") -> None:
    """Drop the transfer functions and propagators kept for ``context``
    (:func:`clholo.host.runtime.release_context`)."""
    with _propagators_lock:
        for key in [k for k, p in _propagators.items() if p.queue.context == context]:
            del _propagators[key]
    _tf_caches.pop(context, None)


runtime.on_release_context(_forget_context)


def _propagator(queue, batch, shape, padded, dtype) -> ASMPropagator:
    key = (queue.int_ptr, batch, tuple(shape), tuple(padded), np.dtype(dtype).str)
    with _propagators_lock:
        prop = _propagators.get(key)
        if prop is not None:
            _propagators.move_to_end(key)
            return prop
    prop = ASMPropagator(batch, shape, padded, dtype=dtype, queue=queue)
    with _propagators_lock:
        _propagators[key] = prop
        while len(_propagators) > _MAX_PROPAGATORS:
            _propagators.popitem(last=False)
    return prop


_propagators_lock = threading.Lock()
