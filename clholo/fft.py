"""Fast Fourier transforms on OpenCL devices (sizes 2^a 3^b 5^c, complex64/complex128).

NumPy's conventions throughout (see ``HOLOGRAPHY.md`` section 1): the forward transform is
``X[k] = sum_n x[n] exp(-2j pi k n / N)`` and unnormalised, the inverse carries ``1/N``, results
are in unshifted order, the last axis (``fft``/``ifft``) or the last two axes (``fft2``/``ifft2``)
are transformed and every leading axis is a batch.

Functions
---------
``fft2``, ``ifft2``, ``fft``, ``ifft``
    ``np.ndarray`` in -> ``np.ndarray`` out; ``pyopencl.array.Array`` in -> ``Array`` out on the
    same device (no host copies). ``out=`` may be given, also ``out=a`` (in place). Plans are
    kept in a small LRU cache. On a CPU device NumPy arrays are not copied either: the kernels
    read and write them where they lie (host-pointer buffers).
:class:`FFTPlan`
    Built once for a shape, dtype and queue, executed many times without host synchronisation.
    Reads zero-padded windows and writes cropped windows without copies and can fuse a
    pointwise multiply into the first load or the last store (``FFT2 -> x H -> IFFT2`` needs no
    separate pass).
:func:`plan_geometry`
    The passes, windows, launch sizes and work buffers of a transform as a pure function of
    shape, dtype and :class:`DeviceLimits` (no OpenCL calls; pyvkfft's ``calc_transform_axes``
    is the model): :class:`FFTPlan` builds its kernels and launch records from it once, and a
    call only fills in its arrays.
``FFT_PASS_ARGS``, ``FFT_KERNEL_ARGS``
    The kernels' parameters, declared once (:class:`KernelArg`): the C parameter lists are
    ``#define`` lines generated from them (:func:`kernel_arg_macros`) and the host dtypes come from
    the same table, so signature and host cannot drift.
:class:`FFTCallback`
    An OpenCL snippet with extra buffer/scalar arguments that a plan runs on every element as
    its first pass loads it or its last pass stores it (cuFFT/VkFFT-style callbacks), or that a
    round trip runs between its transforms (a mid callback).
:class:`RoundTripPlan`
    A forward and an inverse transform of every row or column in one pass over memory, with a
    pointwise multiply, a crop and a mid callback between them in fast memory: the hologram
    renderer's layer is two of them (columns with the transfer function; rows with the next
    layer's composite). :func:`round_trip_geometry` / :func:`round_trip_fits` plan it.

How it works
------------
A 2D transform is two passes, one along rows and one along columns (their order is chosen per
plan to prune the most work from zero-padded input rows or cropped output rows). Each pass runs
every radix-8/4/2/3/5 Stockham stage of a line in fast memory and touches global memory once for
reading and once for writing; twiddles come from a table computed in double precision on the
host. Two kernel variants exist (``variant=``):

``"cpu"`` (``kernels/fft_cpu.cl``)
    one work-item per strip of 8 (4 for complex128) lines held in explicit vector types, all
    stages without barriers in a per-work-group scratch; fast on PoCL. Two radix-3 stages are
    one radix-9 stage here (fewer passes over the scratch, which lives in L2).
``"gpu"`` (``kernels/fft_gpu.cl``)
    a work-group per few lines in local memory with coalesced loads and a barrier per stage,
    ping-ponging between two buffers within a 32 KiB budget. Longer lines (more than 2048
    complex64 points) are held once, in as much of the device's local memory as they need,
    and every stage runs in place: each work-item reads its butterflies' inputs into
    registers, a barrier, writes their outputs, a barrier (``FFT_INPLACE``). On a 48 KiB
    device (an H100) lines of up to 6144 complex64 points (3072 complex128; less what the
    kernel holds itself) thus stay one launch per axis, the 4K grid's 2187 and 3888 and
    SGD's 2250 included, and a :class:`RoundTripPlan` takes them too. Lines that the local
    memory holds only one component of (7680 and 8192 points of complex64 on 48 KiB) keep
    their values in registers between stages and exchange them through local memory one
    component at a time (``FFT_SPLIT``): still one launch, the in-place plan's bits. Only
    lines beyond that run one global-memory radix stage per launch.

Both are tested on PoCL; the default picks by device type.
"""

from __future__ import annotations

import collections
import dataclasses
import functools
import math
import threading
from dataclasses import dataclass
from typing import Any, Dict, List, Optional, Sequence, Tuple

import numpy as np
import pyopencl as cl
import pyopencl.array as cl_array

from clholo import validate
from clholo._arrays import other_queue_markers, resolve_queue
from clholo.errors import InputError
from clholo.host import runtime
from clholo.host import tuning as host_tuning  # DeviceLimits has a field named tuning

__all__ = ["FFTPlan", "FFTCallback", "fft2", "ifft2", "fft", "ifft", "MAX_SIZE", "clear_plan_cache",
           "is_fft_size", "next_fft_size", "nearest_fft_sizes", "plan_geometry", "PlanGeometry",
           "PassGeometry", "LaunchGeometry", "Window", "DeviceLimits", "KernelArg",
           "FFT_PASS_ARGS", "FFT_KERNEL_ARGS", "kernel_arg_macros", "kernel_arg_dtypes",
           "RoundTripPlan", "RoundTripGeometry", "round_trip_geometry", "round_trip_fits",
           "row_pitch", "plan_reach"]

#: Largest transform length per axis.
MAX_SIZE = 16384

_COMPLEX = (np.dtype(np.complex64), np.dtype(np.complex128))
# The CPU kernel keeps 2 N LANES complex numbers of scratch per work-group (sub + 1 lines'
# worth for column passes that read sub strips' rows together); the bound is PoCL's 1 MiB of
# local memory. It was 512 KiB, to stay within one core's L2, but more strips a column pass
# measured faster though they leave it (Zen 4, 1 MiB L2, PoCL 3.1, the same bits): a
# 12-megapixel render's grid 3072x4050 1.20x, 2160^2 1.07x, 2048^2 1.04x; the SLM's grid
# (1125 columns) had four strips already (docs/benchmarks.md, twenty-fourth session).
_CPU_SCRATCH_BYTES = 1024 * 1024
# Local memory the GPU variant may use per work-group: 32 KiB leaves room for two resident
# work-groups on every current GPU (48-64 KiB of shared memory per block/CU).
_GPU_LOCAL_BYTES = 32 * 1024
# Column passes may take up to this much where it puts two or more columns in a group that 32 KiB
# holds one of (1125 and 1200 points): adjacent columns fill more of each 32-byte sector read.
# On an H200 the 1125-point column round trip of the SLM's grid ran 1.12x faster so, and a
# 1125x1944 FFT 1.25x; lines that fit no pair stay on the in-place plan (2250 columns as two
# 36 KiB buffers were 0.8x). benchmarks/fft_variants.py, 2026-11-26.
_GPU_COLUMN_LOCAL_BYTES = 48 * 1024
_NO_LINE_WRAP = 1 << 30
# The in-place local-memory plan of long lines (fft_gpu.cl, FFT_INPLACE): at most this many
# work-items per group (NVIDIA's H200 driver allows the kernel 256 of the device's 1024, at
# every FFT_INPLACE: CL_KERNEL_WORK_GROUP_SIZE, set by its registers), and at most this many
# butterflies per work-item and stage held in registers (else global stages). A kernel that
# allows fewer work-items still is planned again (DeviceLimits.kernel_threads).
_INPLACE_THREADS = 256
_INPLACE_MAX_PER_ITEM = 8
# The split plan's columns with the in-place plan's stages (the tunable setting split_columns):
# at most this many work-items a group, whatever the setting. 512 hold five columns of 2187 or
# 2250 points within _INPLACE_MAX_PER_ITEM; at 1024 their fused radix-9 and radix-15 butterflies
# took 72 and 93 registers in clang's NVPTX model, and held to the 64 that a group of 1024 allows
# (reqd_work_group_size), 312 and 276 bytes spilled (benchmarks/gpu_registers.py, "held to its
# group"); the two-buffer plan's stages (radices up to 8) fit 64 with no spill.
_SPLIT_INPLACE_COLUMN_THREADS = 512
# ... and at most this many complex values held per work-item at any stage (FFT_INPLACE
# butterflies of its radix; 64 as 8 radix-8 butterflies)
_INPLACE_MAX_HELD = 64
# Largest radix of a stage of the two-buffer fft_lines plan (kernels/fft_gpu.cl, DIRECT_STAGE):
# a stage of radix R1 R2 (each a butterfly radix) runs as one Stockham stage, its R1 R2-point
# DFT in registers (fused_butterfly), so a line takes fewer stages, each one local-memory read
# and write of every element and one barrier (1944 points: 4 stages, not 6); 8 plans the
# butterfly radices alone. On an H200 (benchmarks/fft_variants.py, 2026-11-26), with the load
# and store in their own local-memory passes 16 made the SLM grid's 1125-point column round
# trip 1.34x faster than 8; once the first stage reads the source and the last writes the
# destination (DIRECT_STAGE) 8 was the faster by 1.18x there (12.4 against 14.6 ms per render,
# the render's kernels 24.5 against 27.0 ms, a 1024^2 FFT 1.43x): the fused stages then hold
# too much per work-item. 32 was slower still (1944-point rows 0.64x).
_FUSED_RADIX_MAX = 8
# The same for the in-place plan (lines beyond two buffers; without DIRECT_STAGE). 16 made
# the 4K grid's 3888-point row round trip 1.23x and its 2187-point column round trip 1.10x
# faster than 8, a 2250^2 FFT 1.16x and a 2187x3888 FFT 1.14x; but a 4096^2 FFT 0.93x and an SGD
# iteration at 2048^2 (grid 2250^2) 0.91x.
_INPLACE_FUSED_RADIX_MAX = 16
# The in-place plan with its first stage on the source and its last on the destination too
# (FFT_INPLACE_DIRECT: the load, the round trip's step and the store need no pass through local
# memory of their own). Off until a GPU has measured it: on two-buffer lines the same was worth
# 1.31x with radices up to 8, and lost with radices up to 16 (benchmarks/fft_variants.py,
# variant "inplace-direct"). It is the tunable setting "inplace_direct" (clholo.host.tuning:
# the project's default, off; a device's stored tuning, `clholo tune`, in that device's plans).
# Column passes on the in-place plan where two buffers hold too few adjacent columns per group
# to read a whole 32-byte sector of a row and one buffer holds more: 1125 points five to a group
# in 48 KiB (two buffers: two), 2048 points two (one) (the issue-23 H200 profile: the
# SLM grid's column round trip at 3.2x a copy's time, its rows at 2.7x), with the two-buffer
# plan's stages (radices up to _FUSED_RADIX_MAX), so the same bits: the tunable setting
# "inplace_columns" (clholo.host.tuning), off until a GPU has measured it
# (benchmarks/fft_variants.py, variants "cols-inplace" and "cols-inplace-direct"). The same
# columns on the split plan hold twice as many again (one component at a time; up to 512 or 1024
# work-items a group): the tunable setting "split_columns", off too ("cols-split"); so do the
# in-place plan's columns that it holds fewer than four of (2187 and 2250 points: five, not two).
# Lines that the whole local memory holds one component of but not as complex values take the
# split plan (fft_gpu.cl, FFT_SPLIT: one launch a pass, round trips too) rather than one
# global-memory launch per radix stage. Not measured on a GPU yet: False plans them as before,
# for benchmarks/fft_variants.py's "no-split" (its global stages give other bits, so this is no
# tunable setting).
_GPU_SPLIT = True
# The butterfly radices (fft_common.h DFT2 .. DFT8) a fused radix is the product of two of.
_BUTTERFLY_RADICES = (2, 3, 4, 5, 8)
# 512-bit vectors in the CPU strips where the CPU has AVX-512 (kernels/cpu_wide.h): LLVM
# splits the strips' float16 into two 256-bit halves otherwise. Zen 5 EPYC, PoCL 3.1: SLM-size
# render 1.17x, 1024^2 pad 2 1.07x (2026-11-27); Zen 4 (512-bit ops in two halves): 1.07x,
# 1.03x (2026-11-29); not measured on an Intel Xeon. False builds the strips with
# CLHOLO_CPU_256 (256-bit halves), to compare.
_CPU_WIDE = True
# The CPU strips' first stage on the nonzero half of a zero-padded input (kernels/fft_cpu.cl,
# FFT_PRUNE; the same bits). False builds them with FFT_PRUNE 0 (the zeros read and added), to
# compare.
_CPU_PRUNE = True
# Most strips of 8 columns one CPU work-item reads together (kernels/fft_cpu.cl, MAX_SUB).
_CPU_MAX_SUB = 4  # mul_lmod for 2D plans: the multiply's line index never wraps


def is_fft_size(n: int) -> bool:
    """True when ``n >= 1`` has no prime factor other than 2, 3 and 5 (a size the FFT takes)."""
    n = int(n)
    if n < 1:
        return False
    for f in (2, 3, 5):
        while n % f == 0:
            n //= f
    return n == 1


def _smooth_bases(n: int):
    """Every ``3^b 5^c`` up to the first that reaches ``n`` on each axis (``O(log^2 n)``)."""
    p5 = 1
    while True:
        p35 = p5
        while True:
            yield p35
            if p35 >= n:
                break
            p35 *= 3
        if p5 >= n:
            break
        p5 *= 5


def next_fft_size(n: int) -> int:
    """Smallest size ``2^a 3^b 5^c`` that is ``>= n`` (at least 1).

    Found by enumerating the exponents of 3 and 5 (and the power of two each needs), not by
    counting up: microseconds for any ``n`` (``next_fft_size(10**30)`` included).
    """
    n = max(1, int(n))
    best = None
    for base in _smooth_bases(n):
        # the smallest base * 2^a >= n
        size = base if base >= n else base << ((-(-n // base)) - 1).bit_length()
        if best is None or size < best:
            best = size
    return best


def prev_fft_size(n: int) -> int:
    """Largest size ``2^a 3^b 5^c`` that is ``<= n`` (1 for ``n <= 1``); same enumeration as
    :func:`next_fft_size`."""
    n = int(n)
    if n <= 1:
        return 1
    best = 1
    for base in _smooth_bases(n):
        if base <= n:
            best = max(best, base << ((n // base).bit_length() - 1))
    return best


# Rows of a multiple of 4 KiB put every row of a column strip in the same few cache sets (a
# 2048-element complex64 row: 16 KiB, four of a 1 MiB L2's 1024 sets): on a Zen 5 EPYC under
# PoCL the column round trip of a [1024, 2048] row spectrum took 2.85 us a column, 2.40 at a
# 2064-element pitch (docs/benchmarks.md, 2026-11-27). 128 bytes more keep a CPU strip pair's
# 128-byte rows and a GPU group's 16 adjacent complex64 columns aligned.
_PITCH_ALIAS_BYTES = 4096
_PITCH_PAD_BYTES = 128
# GPUs keep unpadded rows, round trips on GPUs dispatch field by field, and hand a mid callback
# with a four-element form (the composite) its elements one at a time, folded into the first
# transform's last stage, until a GPU session measures the alternatives there: the tunable
# settings "row_pitch", "batch_fast" and "mid_quads" (clholo.host.tuning; `clholo tune`
# measures them on a device and stores its fastest; benchmarks/fft_variants.py's variants).
# The most work-groups a launch's second dimension may have (CUDA's grid y limit, which
# NVIDIA's OpenCL keeps)
_MAX_GROUPS_DIM1 = 65535


def row_pitch(n: int, dtype=np.complex64, *, cpu: bool, gpu_pitch: Optional[bool] = None
              ) -> int:
    """Row stride, in elements, for a work array of rows of ``n`` elements whose columns a
    pass reads (the two-pass layer's row spectrum ``[B, H, Wp]``): ``n``, or ``n`` plus 128
    bytes where a row is a multiple of 4 KiB and the device is a CPU (``cpu=True``), where
    such strides cost the column passes 1.19x. Other devices keep ``n`` unless ``gpu_pitch``.

    Parameters
    ----------
    n : int
        Elements of a row.
    dtype : complex64 or complex128
    cpu : bool
        Whether the device is a CPU (:attr:`DeviceLimits.is_cpu`).
    gpu_pitch : bool, optional
        Pad on other devices too: the tunable setting ``row_pitch``
        (``DeviceLimits.setting("row_pitch")``); default the project's
        (:data:`clholo.host.tuning.SETTINGS`: off until a GPU measures it).
    """
    isz = _check_dtype(dtype).itemsize
    n = int(n)
    if gpu_pitch is None:
        gpu_pitch = host_tuning.value("row_pitch")
    gpu_pitch = bool(gpu_pitch)
    if (cpu or gpu_pitch) and (n * isz) % _PITCH_ALIAS_BYTES == 0:
        return n + _PITCH_PAD_BYTES // isz
    return n


def nearest_fft_sizes(n: int) -> Tuple[int, int]:
    """The accepted sizes just below and just above ``n`` (below is 1 for ``n <= 1``)."""
    n = int(n)
    return prev_fft_size(n - 1), next_fft_size(n + 1 if n >= 1 else 1)


def _radices(n: int) -> List[int]:
    """Stage radices of a length-n line, in the kernels' order (fft_common.h fft_next_radix):
    the odd power-of-two radix 2 or 4 first, radix 8, then every 3, then every 5."""
    n2 = n & -n
    logn2 = _log2(n2)
    radices = []
    if logn2 % 3:
        radices.append(1 << (logn2 % 3))
    radices += [8] * (logn2 // 3)
    rest = n // n2
    for f in (3, 5):
        while rest % f == 0:
            radices.append(f)
            rest //= f
    return radices


def _log2(n: int) -> int:
    return int(n).bit_length() - 1


def _check_dtype(dtype) -> np.dtype:
    try:
        dt = np.dtype(dtype)
    except TypeError:
        raise TypeError(f"dtype={dtype!r} is not a NumPy dtype; use complex64 or complex128") from None
    if dt not in _COMPLEX:
        raise TypeError(f"dtype={dt} is not supported by clholo.fft: use complex64 or complex128 "
                        f"(convert real input with .astype(np.complex64))")
    return dt


_CB_SCALARS = {"char": np.int8, "uchar": np.uint8, "short": np.int16, "ushort": np.uint16,
               "int": np.int32, "uint": np.uint32, "long": np.int64, "ulong": np.uint64,
               "float": np.float32, "double": np.float64}


class FFTCallback:
    """An OpenCL snippet run on every element as a plan's first pass loads it or its last pass
    stores it (cuFFT/VkFFT-style callbacks), with extra buffer and scalar arguments.

    Parameters
    ----------
    source : str
        OpenCL C defining, for a load callback::

            real2 clholo_load(real2 v, long b, int row, int col, <params>)

        returning the value to transform instead of the loaded ``v``; for a store callback::

            void clholo_store(__global real2 *ptr, real2 v, long b, int row, int col, <params>)

        which writes the transformed value ``v`` (or anything else, or nothing) itself; for a
        mid callback of a :class:`RoundTripPlan`::

            real2 clholo_mid(real2 v, long b, int row, int col, <params>)

        returning the value the second transform takes instead of ``v`` (optionally also
        ``clholo_mid4`` / ``clholo_mid_rows8``, see ``kernels/fft_common.h`` and
        ``kernels/composite_store.h``; or, for a callback that adds something up over the
        elements, ``clholo_mid_acc`` and ``clholo_mid_sums_store`` with ``FFT_MID_CB_SUMS``:
        :attr:`RoundTripPlan.mid_parts`, ``kernels/sgd_callbacks.h``).
        ``real2`` is ``float2`` or ``double2`` with the plan's precision; ``b`` is the flattened
        batch index (for 1D plans: the line), ``row``/``col`` the element's position in the
        transform frame (``row`` is 0 for 1D plans). The kernel headers (``-I kernels/``, e.g.
        ``random_phase.h``) may be included.
    params : sequence of str
        OpenCL types of the extra parameters, in order: ``"__global const float *"``,
        ``"uint"``, ``"real"`` (the plan's float or double), ... Values are given to :meth:`FFTPlan.execute` as ``load_args`` /
        ``store_args`` (``pyopencl.array.Array`` or ``cl.Buffer`` for pointers, NumPy scalars
        or Python numbers for scalars).
    defines : mapping, optional
        Extra preprocessor defines for the program (part of the program cache key).

    Notes
    -----
    A load callback sees only the input window (zero padding stays zero and is not passed); it
    runs before a fused ``multiply_at="input"`` and before the inverse's conjugation. A store
    callback sees only the output window, after the inverse's conjugation and ``1/N`` and a fused
    ``multiply_at="output"``. Elements are visited in no particular order, each exactly once.
    """

    def __init__(self, source: str, *, params: Sequence[str] = (), defines=None):
        if not isinstance(source, str) or not source.strip():
            raise ValueError("source must be OpenCL C text defining clholo_load or clholo_store")
        self.source = source
        self.params = tuple(" ".join(str(p).split()) for p in params)
        self.dtypes = []
        for i, p in enumerate(self.params):
            if "*" in p:
                if "__global" not in p and "global" not in p.split():
                    raise ValueError(f"params[{i}] = {p!r}: pointer parameters must be __global")
                self.dtypes.append(None)
            elif p in _CB_SCALARS:
                self.dtypes.append(_CB_SCALARS[p])
            elif p == "real":
                self.dtypes.append("real")  # the plan's real type, known at build
            else:
                raise ValueError(f"params[{i}] = {p!r} is not an OpenCL scalar type "
                                 f"({', '.join(_CB_SCALARS)}, real) or a __global pointer")
        self.defines = dict(defines or {})

    def _prefix(self, kind: str) -> str:
        tag = {"LOAD": "l", "STORE": "s", "MID": "m"}[kind]
        names = [f"cb{tag}{i}" for i in range(len(self.params))]
        decl = "".join(f", {p} {n}" for p, n in zip(self.params, names))
        args = "".join(f", {n}" for n in names)
        return (f"#define FFT_{kind}_CB 1\n#define FFT_{kind}_CB_PARAMS {decl}\n"
                f"#define FFT_{kind}_CB_ARGS {args}\n")

    def _values(self, values, what: str, real) -> list:
        values = list(values or [])
        if len(values) != len(self.params):
            raise ValueError(f"{what} has {len(values)} value(s); the callback declares "
                             f"{len(self.params)} parameter(s): {list(self.params)}")
        out = []
        for i, (v, dt) in enumerate(zip(values, self.dtypes)):
            if dt is None:
                if isinstance(v, cl_array.Array):
                    if v.offset:
                        raise ValueError(f"{what}[{i}] is an array view with an offset; pass a "
                                         f"whole array or a cl.Buffer")
                    v = v.base_data
                if not isinstance(v, cl.MemoryObjectHolder):
                    raise TypeError(f"{what}[{i}] must be a pyopencl array or buffer for "
                                    f"parameter {self.params[i]!r}, got {type(v).__name__}")
                out.append(v)
            else:
                out.append((real if dt == "real" else dt)(v))
        return out


# ---------------------------------------------------------------------- kernel arguments
@dataclass(frozen=True)
class KernelArg:
    """One parameter of the FFT kernels: its name and OpenCL C type. The kernels' signatures
    (macros prepended to their source, :func:`kernel_arg_macros`) and the host's scalar
    dtypes (:func:`kernel_arg_dtypes`) are both derived from these tables, so they cannot
    drift apart (pyopencl's ``VectorArg``/``ScalarArg`` play the same part there).

    Attributes
    ----------
    name : str
        The parameter's name in the kernel.
    ctype : str
        Its OpenCL C type: ``"long"``, ``"int"``, ``"real"`` (the plan's float or double) or a
        pointer type.
    """

    name: str
    ctype: str  # "long", "int", "real" (the plan's float/double) or a pointer type

    @property
    def is_pointer(self) -> bool:
        """Whether the parameter is a buffer (its C type is a pointer)."""
        return "*" in self.ctype

    def dtype(self, real):
        """Host dtype for ``set_scalar_arg_dtypes`` (None for buffers and local memory).

        Parameters
        ----------
        real : numpy.dtype
            The plan's real type (float32 or float64), what ``"real"`` stands for.
        """
        if self.is_pointer:
            return None
        return real if self.ctype == "real" else _CB_SCALARS[self.ctype]

    def decl(self) -> str:
        """The parameter's C declaration, e.g. ``long src_off`` or ``__global const real2 *src``."""
        return f"{self.ctype}{'' if self.is_pointer else ' '}{self.name}"


def _arg_table(spec: str) -> Tuple[KernelArg, ...]:
    """``"long a, __global real2 *b"`` -> KernelArgs (the star belongs to the type)."""
    out = []
    for part in spec.split(","):
        words = part.replace("*", "* ").split()
        out.append(KernelArg(words[-1], " ".join(words[:-1])))
    return tuple(out)


#: The arguments every pass kernel starts with: source and destination geometry, transform
#: length and twiddles, the optional pointwise multiply, conjugations and scale (their meaning:
#: kernels/fft_cpu.cl's header comment).
FFT_PASS_ARGS = _arg_table(
    "__global const real2 *src, long src_off, long src_bs, long src_ls, long src_es, "
    "int src_nl, int src_ne, "
    "__global real2 *dst, long dst_off, long dst_bs, long dst_ls, long dst_es, "
    "int nlines, int nstore, "
    "int N, __global const real2 *tw, "
    "__global const real2 *mul, long mul_off, long mul_bs, int mul_m, long mul_ls, "
    "int mul_lmod, long mul_es, "
    "int mul_mode, int conj_in, int conj_out, real scale, "
    "int mid_n, int mid_conj_a, int mid_conj_b, real mid_scale")

#: Each kernel's own arguments after FFT_PASS_ARGS (callback parameters follow them), and the
#: macro its C signature names them by.
FFT_KERNEL_ARGS = {
    "fft_strip": ("FFT_STRIP_ARGS", _arg_table("int sub, __local vt *buf")),
    "fft_lines": ("FFT_LINES_ARGS", _arg_table("int L, int line_fast, __local real2 *buf")),
    "fft_stage": ("FFT_STAGE_ARGS", _arg_table("int p, int R, int first, int last, "
                                               "int line_fast")),
}
_ARG_INDEX = {a.name: i for i, a in enumerate(FFT_PASS_ARGS)}


def kernel_arg_macros() -> str:
    """The ``#define`` lines of the kernels' parameter lists, prepended to every FFT program."""
    lines = ["#define FFT_PASS_ARGS " + ", ".join(a.decl() for a in FFT_PASS_ARGS)]
    for macro, args in FFT_KERNEL_ARGS.values():
        lines.append(f"#define {macro} " + ", ".join(a.decl() for a in args))
    return "\n".join(lines) + "\n"


def kernel_arg_dtypes(kernel: str, real) -> list:
    """Host dtypes of ``kernel``'s arguments before any callback parameters.

    Parameters
    ----------
    kernel : str
        The kernel's name.
    real : numpy.dtype
        The plan's real type (float32 or float64).
    """
    return [a.dtype(real) for a in FFT_PASS_ARGS + FFT_KERNEL_ARGS[kernel][1]]


# ---------------------------------------------------------------------- plan geometry
@dataclass(frozen=True)
class DeviceLimits:
    """What the plan geometry needs to know of a device (plain numbers: no OpenCL needed).

    Attributes
    ----------
    is_cpu : bool
        A CPU device (the ``"cpu"`` kernel family).
    local_mem_size : int
        Bytes of local memory per work-group.
    max_work_group_size : int
        Largest work-group.
    kernel_local : tuple of (str, int)
        ``(kernel name, bytes)``: local memory a built kernel holds itself
        (``CL_KERNEL_LOCAL_MEM_SIZE`` before any ``__local`` argument), which its ``__local``
        arguments must leave room for; kernels not named are taken to hold none.
    kernel_threads : tuple of (str, int)
        ``(kernel name, work-items)``: the fewest work-items per group a build of the kernel
        allowed (``CL_KERNEL_WORK_GROUP_SIZE``, below the device's where the kernel needs many
        registers); kernels not named are taken to allow the device's maximum.
    tuning : tuple of (str, value)
        The GPU kernels' tunable settings for plans on this device
        (:func:`clholo.host.tuning.settings_for`: a device's stored tuning, or the project's
        defaults); settings not named take the project's default (:meth:`setting`).
    """

    is_cpu: bool
    local_mem_size: int
    max_work_group_size: int
    #: ``(kernel name, bytes)``: local memory a built kernel holds itself
    #: (``CL_KERNEL_LOCAL_MEM_SIZE`` before any ``__local`` argument), which its ``__local``
    #: arguments must leave room for; kernels not named are taken to hold none.
    kernel_local: Tuple[Tuple[str, int], ...] = ()
    #: ``(kernel name, work-items)``: the fewest work-items per group a build of the kernel
    #: allowed (``CL_KERNEL_WORK_GROUP_SIZE``); kernels not named allow the device's maximum.
    kernel_threads: Tuple[Tuple[str, int], ...] = ()
    #: ``(name, value)``: the tunable settings of :mod:`clholo.host.tuning` for this device
    tuning: Tuple[Tuple[str, Any], ...] = ()

    @classmethod
    def of(cls, device: "cl.Device") -> "DeviceLimits":
        """The limits of an OpenCL ``device`` (a ``pyopencl.Device``) and its tunable
        settings now (:func:`clholo.host.tuning.settings_for`); what its kernels hold and
        allow, each plan learns from the kernels it builds (:func:`_learn_kernel_limits`)."""
        return cls(bool(device.type & cl.device_type.CPU), int(device.local_mem_size),
                   int(device.max_work_group_size),
                   tuning=host_tuning.settings_for(device))

    def setting(self, name: str):
        """A tunable setting for plans on this device: the value :attr:`tuning` holds, else
        (limits made by hand) :func:`clholo.host.tuning.value`, an override or the project's
        default.

        Parameters
        ----------
        name : str
            A name of :data:`clholo.host.tuning.SETTINGS` (``"mid_quads"``, ...).
        """
        held = dict(self.tuning)
        return held[name] if name in held else host_tuning.value(name)

    def local_budget(self, kernel: str) -> int:
        """Bytes of ``__local`` arguments ``kernel`` may take on this device: the device's
        local memory less what the kernel holds itself."""
        return self.local_mem_size - dict(self.kernel_local).get(kernel, 0)

    def threads(self, kernel: str) -> int:
        """Work-items a group of ``kernel`` may have on this device."""
        return min(self.max_work_group_size,
                   dict(self.kernel_threads).get(kernel, self.max_work_group_size))


def _learn_kernel_limits(limits: DeviceLimits, device: "cl.Device", built) -> Optional[DeviceLimits]:
    """Check planned launches against what their built kernels allow; ``None`` when every one
    fits, else ``limits`` with what was learnt, to plan again with.

    ``built`` pairs each :class:`PassGeometry` with its built kernel. A kernel's own local
    memory (``CL_KERNEL_LOCAL_MEM_SIZE``) counts against the device's with its ``__local``
    arguments, and a work-group may not exceed ``CL_KERNEL_WORK_GROUP_SIZE``. Where nothing
    new was learnt the result is ``None`` too: the launch check then names what does not fit.
    (What is learnt stays with the plan: a process-wide memory of it would make one plan's
    geometry depend on the plans made before it.)
    """
    held, threads = dict(limits.kernel_local), dict(limits.kernel_threads)
    fits = True
    for p, knl in built:
        own = runtime.kernel_local_bytes(knl, device)
        wg = runtime.kernel_work_group_size(knl, device)
        held[p.kernel] = max(held.get(p.kernel, 0), own)
        for lg in p.launches:
            if lg.local_bytes + own > limits.local_mem_size:
                fits = False
            if lg.lsize is not None and math.prod(lg.lsize) > wg:
                fits = False
                threads[p.kernel] = min(threads.get(p.kernel, limits.max_work_group_size), wg)
    if fits:
        return None
    new = dataclasses.replace(limits, kernel_local=tuple(sorted(held.items())),
                              kernel_threads=tuple(sorted(threads.items())))
    return None if new == limits else new


@dataclass(frozen=True)
class Window:
    """How a launch sees an array: the buffer's role (``"x"``, ``"out"``, ``"tmp"``,
    ``"stage0"``/``"stage1"``) and batch/line/element strides, in elements. For a source,
    ``nl``/``ne`` are the valid lines and elements (the rest reads as zero); for a
    destination, the lines and elements written.

    Attributes
    ----------
    role : str
        The buffer's role (above).
    bs, ls, es : int
        Batch, line and element strides, in elements.
    nl, ne : int
        Valid (source) or written (destination) lines and elements.
    """

    role: str
    bs: int
    ls: int
    es: int
    nl: int = 0
    ne: int = 0


@dataclass(frozen=True)
class LaunchGeometry:
    """One kernel launch of a pass: sizes, windows and the kernel's own argument values
    (``local_bytes``: size of its ``__local`` buffer argument, 0 when it has none).

    Attributes
    ----------
    gsize : tuple of int
        Global size.
    lsize : tuple of int or None
        Local size (None: the driver's choice).
    src, dst : Window
        How the launch reads and writes.
    extra : tuple of int
        The kernel's own scalar arguments.
    local_bytes : int
        Size of its ``__local`` buffer argument (above).
    """

    gsize: Tuple[int, ...]
    lsize: Optional[Tuple[int, ...]]
    src: Window
    dst: Window
    extra: Tuple[int, ...]
    local_bytes: int = 0


@dataclass(frozen=True)
class PassGeometry:
    """One transform along rows or columns (1D plans: rows) of every batch element.

    Attributes
    ----------
    axis : str
        ``"rows"`` or ``"cols"``.
    n : int
        Transform length.
    nlines : int
        Lines transformed per batch element.
    mul_ls, mul_es : int
        The fused multiply's line and element strides in its frame.
    first, last : bool
        Whether this is the plan's first (loading) and last (storing) pass.
    kind : str
        ``"cpu"`` (``fft_strip``), ``"gpu"`` (``fft_lines``) or ``"global"`` (``fft_stage``).
    program, kernel : str
        The kernels file and the kernel's name.
    defines : tuple of (str, int)
        Build defines of the program.
    launches : tuple of LaunchGeometry
        The pass's launches, in order.
    """

    axis: str              # "rows" or "cols"
    n: int                 # transform length
    nlines: int
    mul_ls: int            # the fused multiply's line and element strides in its frame
    mul_es: int
    first: bool
    last: bool
    kind: str              # "cpu" (fft_strip), "gpu" (fft_lines) or "global" (fft_stage)
    program: str           # kernels file
    kernel: str
    defines: Tuple[Tuple[str, int], ...]
    launches: Tuple[LaunchGeometry, ...]


@dataclass(frozen=True)
class PlanGeometry:
    """Everything :class:`FFTPlan` derives from shape, dtype and device limits: a pure
    function of them (:func:`plan_geometry`), testable without a device.

    Attributes
    ----------
    shape : tuple of int
        The transform's shape with its batch axes, as given.
    batch_shape, transform_shape : tuple of int
        ``shape`` split into its leading batch axes and its transformed axes.
    input_shape, output_shape : tuple of int
        The windows read and written (last axes), in elements.
    axes : tuple of int
        ``(-2, -1)`` or ``(-1,)``.
    variant : str
        ``"cpu"``, ``"gpu"`` or ``"gpu-global"`` (``"auto"`` resolved).
    order : str
        ``"rows-first"``, ``"columns-first"`` (2D) or ``"rows"`` (1D).
    batch : int
        The launches' second global dimension.
    mul_frame : int
        Elements of one multiply-factor frame (the batch stride of a fused multiply).
    scale : float
        The inverse's ``1/N``.
    buffers : tuple of (str, int)
        Plan-owned work buffers: ``(role, elements)``.
    passes : tuple of PassGeometry
        The passes, in order.
    """

    shape: Tuple[int, ...]
    batch_shape: Tuple[int, ...]
    transform_shape: Tuple[int, ...]
    input_shape: Tuple[int, ...]
    output_shape: Tuple[int, ...]
    axes: Tuple[int, ...]
    variant: str
    order: str
    batch: int             # the launches' second global dimension
    mul_frame: int         # elements of one multiply factor frame (batch stride of multiply)
    scale: float           # the inverse's 1/N
    buffers: Tuple[Tuple[str, int], ...]  # plan-owned work buffers: (role, elements)
    passes: Tuple[PassGeometry, ...]

    @property
    def in_full_shape(self) -> Tuple[int, ...]:
        """Shape of the arrays :meth:`FFTPlan.execute` reads: ``batch_shape + input_shape``."""
        return self.batch_shape + self.input_shape

    @property
    def out_full_shape(self) -> Tuple[int, ...]:
        """Shape of the arrays :meth:`FFTPlan.execute` writes: ``batch_shape + output_shape``."""
        return self.batch_shape + self.output_shape


def _whole_numbers(value, name: str, what: str) -> Tuple[int, ...]:
    """``value`` as a tuple of ints, each a whole number (``8.5`` and ``True`` are refused: int()
    would plan an 8- or 1-point axis that nobody asked for; a string is not a shape)."""
    try:
        items = () if isinstance(value, (str, bytes)) else tuple(value)
    except TypeError:
        items = ()
    if not items or not all(validate.is_whole(v) for v in items):
        raise InputError(f"{name}={value!r} must be {what} (whole numbers)")
    return tuple(int(v) for v in items)


def _window_shape(value, name: str, transform_shape, *, allow_larger: bool) -> Tuple[int, ...]:
    nd = len(transform_shape)
    if value is None:
        return tuple(transform_shape)
    if isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_)):
        value = (int(value),)
    value = _whole_numbers(value, name, f"a tuple of {nd} ints")
    if len(value) != nd:
        raise ValueError(f"{name}={value!r} must have {nd} entries (the transformed axes)")
    for i, (v, n) in enumerate(zip(value, transform_shape)):
        if v < 1:
            raise ValueError(f"{name}[{i}] = {v} must be positive")
        if v > n and not allow_larger:
            raise ValueError(f"{name}[{i}] = {v} exceeds the transform size {n} on axis "
                             f"{i - nd}")
    return value


def plan_geometry(shape: Sequence[int], dtype=np.complex64, *, device: DeviceLimits,
                  axes: Sequence[int] = (-2, -1), input_shape: Optional[Sequence[int]] = None,
                  output_shape: Optional[Sequence[int]] = None,
                  variant: str = "auto") -> PlanGeometry:
    """The passes, windows, launch sizes and work buffers of a transform (see
    :class:`FFTPlan` for the parameters); raises the same errors for bad shapes. Pure: no
    OpenCL calls, ``device`` gives the limits that matter.

    Parameters
    ----------
    shape, dtype, axes, input_shape, output_shape, variant
        As for :class:`FFTPlan`.
    device : DeviceLimits
        The device's limits.

    Returns
    -------
    PlanGeometry
    """
    dt = _check_dtype(dtype)
    axes = tuple(int(a) for a in axes)
    if axes not in ((-2, -1), (-1,)):
        raise ValueError(f"axes={axes!r}: clholo.fft transforms the last axis (-1,) or the "
                         f"last two axes (-2, -1)")
    nd = len(axes)
    shape = _whole_numbers(shape, "shape", "a sequence of ints")
    if len(shape) < nd:
        raise ValueError(f"shape={shape!r} has fewer than the {nd} transformed axes")
    for i, s in enumerate(shape):
        ax = i - len(shape)
        if ax >= -nd:
            if s < 1:
                raise ValueError(f"shape[{i}] (axis {ax}) = {s} must be >= 1")
            if s > MAX_SIZE:  # the limit first: no search for a size that cannot be taken
                raise ValueError(f"shape[{i}] (axis {ax}) = {s} exceeds the largest "
                                 f"supported size {MAX_SIZE}")
            if not is_fft_size(s):
                lo, hi = nearest_fft_sizes(s)
                raise ValueError(
                    f"shape[{i}] (axis {ax}) = {s} is not a size 2^a 3^b 5^c: clholo.fft "
                    f"supports sizes without other prime factors only; nearest accepted "
                    f"sizes: {lo} and {hi} (zero-pad with input_shape=)")
        elif s < 1:
            raise ValueError(f"shape[{i}] (batch axis) = {s} must be positive")
    if variant not in ("auto", "cpu", "gpu", "gpu-global"):
        raise ValueError(f"variant={variant!r}: use 'auto', 'cpu', 'gpu' or 'gpu-global'")
    if variant == "auto":
        variant = "cpu" if device.is_cpu else "gpu"
    batch_shape, tshape = shape[:-nd], shape[-nd:]
    ishape = _window_shape(input_shape, "input_shape", tshape, allow_larger=True)
    # 1D plans may write rows longer than the transform (a row pitch): the first n elements
    oshape = _window_shape(output_shape, "output_shape", tshape, allow_larger=nd == 1)
    b = int(np.prod(batch_shape, dtype=np.int64)) if batch_shape else 1

    # (axis, n, src window, dst window, nlines, nstore, mul_ls, mul_es) per pass
    if nd == 1:
        (n,), (nx,), (no,) = tshape, ishape, oshape
        # 1D: every line of every batch element is one line of a single pass (batch 1)
        specs = [("rows", n, Window("x", 0, nx, 1, b, min(nx, n)), Window("out", 0, no, 1),
                  b, min(no, n), n, 1)]
        order, nbatch, mul_frame, tmp_elems = "rows", 1, n, 0
    else:
        (hp, wp), (hx, wx), (ho, wo) = tshape, ishape, oshape
        hi, wi = min(hx, hp), min(wx, wp)

        def cost(m):
            return m * (math.log2(m) + 1)

        rows_first = hi * cost(wp) + wo * cost(hp) <= wi * cost(hp) + ho * cost(wp)
        xbs, obs = hx * wx, ho * wo
        if rows_first:
            # pass 1: hi rows (the rest is zero padding), keep the wo columns pass 2 needs
            tmp = ("out", obs, wo) if hi <= ho else ("tmp", hi * wo, wo)
            specs = [("rows", wp, Window("x", xbs, wx, 1, hi, wi), Window(tmp[0], tmp[1], tmp[2], 1),
                      hi, wo, wp, 1),
                     ("cols", hp, Window(tmp[0], tmp[1], 1, tmp[2], wo, hi), Window("out", obs, 1, wo),
                      wo, ho, 1, wp)]
            tmp_elems = b * hi * wo if tmp[0] == "tmp" else 0
        else:
            # pass 1: wi columns (the rest is zero padding), keep the ho rows pass 2 needs
            tmp = ("out", obs, wo) if wi <= wo else ("tmp", ho * wi, wi)
            specs = [("cols", hp, Window("x", xbs, 1, wx, wi, hi), Window(tmp[0], tmp[1], 1, tmp[2]),
                      wi, ho, 1, wp),
                     ("rows", wp, Window(tmp[0], tmp[1], tmp[2], 1, ho, wi), Window("out", obs, wo, 1),
                      ho, wo, wp, 1)]
            tmp_elems = b * ho * wi if tmp[0] == "tmp" else 0
        order = "rows-first" if rows_first else "columns-first"
        nbatch, mul_frame = b, hp * wp
    passes, stage_elems = [], 0
    for i, (axis, n, src, dst, nlines, nstore, mul_ls, mul_es) in enumerate(specs):
        dst = Window(dst.role, dst.bs, dst.ls, dst.es, nlines, nstore)
        p, elems = _pass_geometry(axis, n, src, dst, nlines, mul_ls, mul_es, i == 0,
                                  i == len(specs) - 1, variant, dt.itemsize, nbatch, device)
        passes.append(p)
        stage_elems = max(stage_elems, elems)
    buffers = []
    if tmp_elems:
        buffers.append(("tmp", tmp_elems))
    if stage_elems:
        buffers += [("stage0", stage_elems), ("stage1", stage_elems)]
    return PlanGeometry(shape, batch_shape, tshape, ishape, oshape, axes, variant, order,
                        nbatch, mul_frame, 1.0 / float(np.prod(tshape)), tuple(buffers),
                        tuple(passes))


def _fused_split(r: int) -> Optional[Tuple[int, int]]:
    """``(R1, R2)``, both butterfly radices, with ``R1 R2 == r`` (the larger first), or None."""
    for r1 in sorted(_BUTTERFLY_RADICES, reverse=True):
        if r % r1 == 0 and r // r1 in _BUTTERFLY_RADICES and r // r1 <= r1:
            return r1, r // r1
    return None


@functools.lru_cache(maxsize=None)
def _fused_radices(n: int, radix_max: int, balanced: bool = False
                   ) -> Tuple[Tuple[int, int], ...]:
    """The stages of an ``n``-point line for the GPU's local-memory plans as ``(R1, R2)`` pairs
    (radix ``R1 R2``; ``R2 == 1``: a butterfly radix alone): the fewest stages of radix at most
    ``radix_max``, and among those the smallest largest radix (even work per stage).

    Stockham's autosort gives the natural order for any sequence of radices whose product is
    ``n``, so any grouping is a valid plan. Order: stages of odd radix first, larger first (the
    stage at ``p == 1`` writes with a stride of its radix: an even one conflicts in local-memory
    banks), then the rest, larger first. ``radix_max <= 8`` gives :func:`_radices`' stages.

    ``balanced`` (the split plan's): among those, the largest smallest radix too (8192 points:
    16 8 8 8, not 16 16 16 2, whose radix-2 stage gives each work-item four times the
    butterflies of a radix-8 one).
    The other plans keep their stages as they were: other stages round otherwise.
    """
    if radix_max <= 8 and not balanced:
        return tuple((r, 1) for r in _radices(n))
    radices = sorted({r for r in range(2, radix_max + 1)
                      if r in _BUTTERFLY_RADICES or _fused_split(r)})

    @functools.lru_cache(maxsize=None)
    def best(m):  # (stages, largest radix, -smallest radix, radices) for the rest m
        if m == 1:
            return (0, 0, -m, ())
        found = None
        for r in radices:
            if m % r == 0:
                s, big, _, rs = best(m // r)
                rs = tuple(sorted(rs + (r,), reverse=True))
                cand = (s + 1, max(big, r), -rs[-1], rs)
                if found is None or cand[:keys] < found[:keys]:
                    found = cand
        return found

    keys = 3 if balanced else 2
    chosen = sorted(best(n)[3], key=lambda r: (r % 2 == 0, -r))
    return tuple((r, 1) if r in _BUTTERFLY_RADICES else _fused_split(r) for r in chosen)


def _stage_list(n: int, radix_max: int = 8, balanced: bool = False) -> str:
    """The GPU kernel's Stockham stages of an ``n``-point line as ``FFT_STAGE(R1,R2,p)`` calls
    (no spaces: a compiler option): :func:`_fused_radices`, radix ``R1 R2`` at sub-transform
    size ``p``."""
    out, p = [], 1
    for r1, r2 in _fused_radices(n, radix_max, balanced):
        out.append(f"FFT_STAGE({r1},{r2},{p})")
        p *= r1 * r2
    return "".join(out)


def _fixed_line_defines(n: int, lines: int, line_fast: int, nthr: int,
                        radix_max: int = 8, balanced: bool = False) -> tuple:
    """Defines that fix a ``fft_lines`` build to one geometry (``kernels/fft_gpu.cl``): line
    length, lines per group, their layout, work-group size and stage list (stages of radix up
    to ``radix_max``), so that radices,
    strides and divisors are constants there. Without them (``benchmarks/fft_variants.py``
    times that side by side) one program serves every size, as before 2026-11-26."""
    return (("FFT_N", n), ("FFT_L", lines), ("FFT_LINE_FAST", line_fast), ("FFT_WG", nthr),
            ("FFT_STAGE_LIST", _stage_list(n, radix_max, balanced)))


def _split_stage_defines(n: int, radix_max: int, balanced: bool = True) -> tuple:
    """The split plan's stages (``kernels/fft_gpu.cl``, ``SPLIT_STAGE``): ``FFT_SPLIT_STAGES``,
    ``FFT_SSTAGE(R1,R2,p,PR1,PR2,PP)`` calls, each stage of :func:`_fused_radices` (balanced)
    with the stage before it, whose outputs it takes from registers through local memory (the
    first stage's is the last: a round trip's second transform starts from the first's last
    outputs); and the last stage's ``FFT_SPLIT_LAST_R1``, ``_R2`` and ``_P`` (where the round
    trip's step finds the first transform's outputs). ``balanced=False``: the stages of the
    other plans (the split columns of ``split_columns`` take the two-buffer plan's)."""
    stages, p = [], 1
    for r1, r2 in _fused_radices(n, radix_max, balanced):
        stages.append((r1, r2, p))
        p *= r1 * r2
    calls = "".join(f"FFT_SSTAGE({r1},{r2},{p},{q1},{q2},{pp})"
                    for (r1, r2, p), (q1, q2, pp) in zip(stages, stages[-1:] + stages[:-1]))
    last = stages[-1]
    return (("FFT_SPLIT_STAGES", calls), ("FFT_SPLIT_LAST_R1", last[0]),
            ("FFT_SPLIT_LAST_R2", last[1]), ("FFT_SPLIT_LAST_P", last[2]))


def _inplace_pass(common, fft_double, n, nlines, line_fast, src, dst, isz, nbatch, full,
                  device: DeviceLimits, radix_max: Optional[int] = None, *, split: bool = False,
                  split_stages: str = "balanced", threads: int = _INPLACE_THREADS
                  ) -> Optional[PassGeometry]:
    """The in-place local-memory plan of a pass (``fft_lines`` with ``FFT_INPLACE``: one
    buffer of ``lines`` lines in ``full`` bytes, every stage through registers), or None where
    no number of lines per group keeps a work-item's butterflies within
    ``_INPLACE_MAX_PER_ITEM`` and ``_INPLACE_MAX_HELD``. Stages of radix up to ``radix_max``
    (default ``_INPLACE_FUSED_RADIX_MAX``; the two-buffer plan's, ``_FUSED_RADIX_MAX``, gives
    that plan's stages, so the same bits).

    ``split``: the split plan (``FFT_SPLIT``) for lines that ``full`` bytes hold as one
    component of their values but not as complex values: the values stay in registers
    between stages and pass through local memory one component at a time (the same
    butterflies, so the in-place plan's bits); None where a line is one stage (no exchange:
    a pass in place could not order its reads before its writes). Its stages are the balanced
    ones; ``split_stages="plain"``: :func:`_fused_radices`' first choice, as the two-buffer
    plan takes them with ``radix_max`` its own (the split columns of ``split_columns``: the
    same bits as that plan).

    ``threads``: at most this many work-items per group (the device's and the built kernel's
    limits still apply)."""
    radix_max = _INPLACE_FUSED_RADIX_MAX if radix_max is None else radix_max
    if split_stages not in ("balanced", "plain"):
        raise ValueError(f"split_stages={split_stages!r}: use 'balanced' or 'plain'")
    unit = isz // 2 if split else isz  # bytes of local memory per element of a line
    held_n = n + n % 2 if split else n  # (the split round trip's step: two halves as complex)
    most_lines = 16 if line_fast else 1
    most_lines = max(1, min(most_lines, full // (held_n * unit), 1 << _log2(max(nlines, 1))))
    # the plan's stages, else (where those give a work-item too many butterflies: 8192 points
    # as 16 16 16 2) the balanced ones, whose bits no other plan of these lines had; the split
    # plan takes the balanced ones always
    for balanced in (((split_stages == "balanced"),) if split else (False, True)):
        if balanced and not split and (_fused_radices(n, radix_max, True)
                                       == _fused_radices(n, radix_max)):
            return None
        stage_radices = [r1 * r2 for r1, r2 in _fused_radices(n, radix_max, balanced)]
        if split and len(stage_radices) < 2:
            return None
        lines = most_lines
        while True:
            most = lines * (n // min(stage_radices))  # butterflies of the widest stage
            nthr = int(max(1, min(threads, most, device.threads("fft_lines"))))
            per_item = -(-most // nthr)
            # what a work-item holds in registers at the stage that holds most
            held = max(-(-(lines * n // r) // nthr) * r for r in stage_radices)
            if (per_item <= _INPLACE_MAX_PER_ITEM and held <= _INPLACE_MAX_HELD) or lines == 1:
                break
            lines -= 1  # fewer lines per group: fewer butterflies per work-item
        if per_item <= _INPLACE_MAX_PER_ITEM and held <= _INPLACE_MAX_HELD:
            break
    else:
        return None
    ngroups = -(-nlines // lines)
    launch = LaunchGeometry((ngroups * nthr, nbatch), (nthr, 1), src, dst, (lines, line_fast),
                            lines * held_n * unit)
    fixed = _fixed_line_defines(n, lines, line_fast, nthr, radix_max, balanced)
    if (balanced or split) and not fixed:  # the generic program (fft_variants.py) takes its
        return None             # stages at run time: neither split nor balanced
    if split:
        extra = (("FFT_SPLIT", 1),) + _split_stage_defines(n, radix_max, balanced)
    else:
        extra = (("FFT_INPLACE_DIRECT", 1),) if fixed and device.setting("inplace_direct") else ()
    inplace = (("FFT_INPLACE", per_item),) + (
        (("FFT_INPLACE_R", max(stage_radices)),) if fixed else ()) + extra
    return PassGeometry(**common, kind="gpu", program="fft_gpu.cl", kernel="fft_lines",
                        defines=fft_double + inplace + (fixed or (("FFT_WG", nthr),)),
                        launches=(launch,))


def _pass_geometry(axis, n, src, dst, nlines, mul_ls, mul_es, first, last, variant, isz,
                   nbatch, device: DeviceLimits) -> Tuple[PassGeometry, int]:
    """One pass's kernel and launches; also the stage buffer elements it needs (0: none)."""
    common = dict(axis=axis, n=n, nlines=nlines, mul_ls=mul_ls, mul_es=mul_es, first=first,
                  last=last)
    fft_double = (("FFT_DOUBLE", int(isz == 16)),)
    if variant == "cpu":
        # the kernel's own local memory (CL_KERNEL_LOCAL_MEM_SIZE) counts against the device's
        # too: NVIDIA's fft_strip holds 1 byte, so a scratch of exactly 48 KiB did not fit
        local_bytes = min(_CPU_SCRATCH_BYTES, device.local_budget("fft_strip"))
        lanes = 8 if isz == 8 else 4
        while lanes > 1 and 2 * n * lanes * isz > local_bytes:
            lanes //= 2
        if 2 * n * lanes * isz > local_bytes:
            variant = "gpu-global"  # no room for even one line: global stages still work
        else:
            # column passes: several strips per work-item, read row by row together
            sub = 1
            if axis == "cols":
                for cand in [c for c in (4, 2) if c <= _CPU_MAX_SUB]:
                    if (cand + 1) * n * lanes * isz <= local_bytes and nlines >= cand * lanes:
                        sub = cand
                        break
            nbuf = sub + 1 if sub > 1 else 2
            launch = LaunchGeometry((-(-nlines // (lanes * sub)), nbatch), (1, 1), src, dst,
                                    (sub,), nbuf * n * lanes * isz)
            return PassGeometry(**common, kind="cpu", program="fft_cpu.cl", kernel="fft_strip",
                                defines=fft_double + (("VW", 2 * lanes),)
                                + ((("CLHOLO_CPU_256", 1),) if not _CPU_WIDE else ())
                                + ((("FFT_PRUNE", 0),) if not _CPU_PRUNE else ()),
                                launches=(launch,)), 0
    line_fast = 1 if axis == "cols" else 0
    budget = min(_GPU_LOCAL_BYTES, device.local_budget("fft_lines"))
    if line_fast:
        wide = min(_GPU_COLUMN_LOCAL_BYTES, device.local_budget("fft_lines"))
        if wide // (2 * n * isz) >= 2 > budget // (2 * n * isz):
            budget = wide
    full = device.local_budget("fft_lines")
    # the tunable setting inplace_columns: columns that two buffers hold too few of to read a
    # 32-byte sector of each row (but at least one: the two-buffer plan would run them) try the
    # in-place plan first where it holds more of them per group, with the two-buffer plan's
    # stages, so the same bits (it falls back to two buffers where it cannot be planned)
    two_buffer_lines = budget // (2 * n * isz)
    few_columns = (line_fast and variant == "gpu" and n > 8 and 1 <= two_buffer_lines
                   and two_buffer_lines * isz < 32)
    columns = []  # (columns per group, plan): the settings' plans that hold more than two buffers
    if few_columns and device.setting("inplace_columns") and full // (n * isz) > two_buffer_lines:
        columns.append(_inplace_pass(common, fft_double, n, nlines, line_fast, src, dst, isz,
                                     nbatch, full, device, _FUSED_RADIX_MAX))
    # the tunable setting split_columns: the same columns on the split plan (one component at a
    # time in local memory: twice the columns of one buffer), with the two-buffer plan's stages
    # (the same bits) and up to split_columns work-items a group (0: off), so that a work-item's
    # butterflies stay within _INPLACE_MAX_PER_ITEM for them all: the SLM grid's 1125-point
    # columns ten to a group (80 bytes of each row) at 512 or 1024 work-items, where the
    # in-place plan's 256 hold five. The fewer work-items, the more registers each (in clang's
    # NVPTX model 104 at 512, 63 at 1024): one group an SM either way, the trade the tuner
    # measures. A kernel that allows fewer work-items is planned again (_learn_kernel_limits).
    split_threads = int(device.setting("split_columns"))
    if (few_columns and split_threads and _GPU_SPLIT
            and full // ((n + n % 2) * (isz // 2)) > two_buffer_lines):
        columns.append(_inplace_pass(common, fft_double, n, nlines, line_fast, src, dst, isz,
                                     nbatch, full, device, _FUSED_RADIX_MAX, split=True,
                                     split_stages="plain", threads=split_threads))
    columns = [(p.launches[0].extra[0], i, p) for i, p in enumerate(columns) if p is not None]
    if columns:
        # the plan holding the most columns; the in-place plan at a tie (fewer barriers)
        held, _, plan = max(columns, key=lambda c: (c[0], -c[1]))
        if held > two_buffer_lines:
            return plan, 0
    # lines of at most 8 points are one radix stage: a single global stage could not run in
    # place, so they always take the local-memory kernel (they fit any local memory)
    if (variant == "gpu" and 2 * n * isz <= budget) or n <= 8:
        if line_fast:
            lines = 16  # 16 adjacent columns: 128-byte reads of complex64
        else:
            lines = max(1, 256 // n)  # short rows: several per group to fill the threads
        lines = min(lines, max(1, budget // (2 * n * isz)), 1 << _log2(max(nlines, 1)))
        lines = max(1, lines)
        nthr = int(min(256, max(1, lines * n // 4), device.threads("fft_lines")))
        ngroups = -(-nlines // lines)
        launch = LaunchGeometry((ngroups * nthr, nbatch), (nthr, 1), src, dst,
                                (lines, line_fast), 2 * lines * n * isz)
        return PassGeometry(**common, kind="gpu", program="fft_gpu.cl", kernel="fft_lines",
                            defines=fft_double + _fixed_line_defines(
                                n, lines, line_fast, nthr, _FUSED_RADIX_MAX),
                            launches=(launch,)), 0
    # lines too long for two buffers within the budget: one buffer in the device's whole local
    # memory, every stage in place through registers (fft_lines with FFT_INPLACE), so the pass
    # is still one launch (2250, 2187, 2560, 3888, 4096 points of complex64 in 48 KiB)
    if variant == "gpu" and n * isz <= full:
        inplace = _inplace_pass(common, fft_double, n, nlines, line_fast, src, dst, isz, nbatch,
                                full, device)
        if inplace is not None:
            # split_columns (above) for columns that this plan holds fewer than four of: the
            # split plan with this plan's own stages, so the same bits (the 4K grid's 2187-point
            # columns and SGD 2048's 2250-point ones five to a group; in place: two), with at
            # most _SPLIT_INPLACE_COLUMN_THREADS work-items
            held = inplace.launches[0].extra[0]
            if (line_fast and split_threads and _GPU_SPLIT and held * isz < 32
                    and full // ((n + n % 2) * (isz // 2)) > held):
                split = _inplace_pass(common, fft_double, n, nlines, line_fast, src, dst, isz,
                                      nbatch, full, device, split=True, split_stages="plain",
                                      threads=min(split_threads,
                                                  _SPLIT_INPLACE_COLUMN_THREADS))
                stages = dict(inplace.defines).get("FFT_STAGE_LIST")
                if (split is not None and split.launches[0].extra[0] > held and stages
                        and dict(split.defines).get("FFT_STAGE_LIST") == stages):
                    return split, 0
            return inplace, 0
    # lines that the whole local memory holds one component of but not as complex values
    # (7680 and 8192 points of complex64, about 6000 of complex128, in 48 KiB): the split
    # plan, values in registers between stages (fft_lines with FFT_SPLIT), still one launch
    if variant == "gpu" and _GPU_SPLIT and n * isz > full and (n + n % 2) * (isz // 2) <= full:
        split = _inplace_pass(common, fft_double, n, nlines, line_fast, src, dst, isz, nbatch,
                              full, device, split=True)
        if split is not None:
            return split, 0
    # global-memory stages: odd radix first (no twiddles at p == 1), radix 8, then 3 and 5;
    # they ping-pong through plan buffers laid out (B, lines, N), lines fastest for column
    # passes so that every stage reads adjacent addresses
    radices = _radices(n)
    ls, es = (1, nlines) if line_fast else (n, 1)
    launches, pp = [], 1
    for si, r in enumerate(radices):
        nb = n // r
        gsize = (nlines, nb, nbatch) if line_fast else (nb, nlines, nbatch)
        s = src if si == 0 else Window(f"stage{(si - 1) % 2}", nlines * n, ls, es, nlines, n)
        d = dst if si == len(radices) - 1 else Window(f"stage{si % 2}", nlines * n, ls, es,
                                                      nlines, n)
        launches.append(LaunchGeometry(gsize, None, s, d, (pp, r, int(si == 0),
                                                           int(si == len(radices) - 1),
                                                           line_fast)))
        pp *= r
    elems = nbatch * nlines * n if len(radices) > 1 else 0
    return PassGeometry(**common, kind="global", program="fft_gpu.cl", kernel="fft_stage",
                        defines=fft_double, launches=tuple(launches)), elems


def _pass_program(context, p: PassGeometry, callbacks, layout: int,
                  extra_defines=None) -> "cl.Program":
    """The program of one pass: the parameter lists come from FFT_PASS_ARGS / FFT_KERNEL_ARGS,
    then the callbacks' defines and source go in front of the kernel file (``layout``: the
    callbacks' FFT_CB_LAYOUT)."""
    defines = dict(p.defines)
    defines.update(extra_defines or {})
    text = kernel_arg_macros()
    if callbacks:
        defines["FFT_CB_LAYOUT"] = layout
        for kind, cb in callbacks:
            defines.update(cb.defines)
            text += cb._prefix(kind)
        text += '#include "fft_common.h"\n'
        for kind, cb in callbacks:
            text += f"#line 1 \"{kind.lower()} callback\"\n{cb.source}\n"
    text += '#line 1 "' + p.program + '"\n' + runtime.read_kernel_source(p.program)
    return runtime.build_program(context, p.program, defines=defines, source=text)


def _twiddle_table(context, n: int, dtype) -> "cl.Buffer":
    """exp(-2 pi i m / n), m < n, computed in double, then rounded once to ``dtype``; then, at
    n + m, the pair (-Im w_m, Im w_m): the CPU strips multiply a vector of interleaved complex
    numbers by w_m as ``v Re w_m + swap(v) (-Im w_m, Im w_m)`` with both factors broadcast from
    the table (one load each) instead of building the sign pattern per butterfly (12-17 % of a
    round trip's time on PoCL). The GPU kernels read the first n entries only."""
    m = max(n, 1)
    table = np.exp(-2j * np.pi * np.arange(m, dtype=np.float64) / m)
    table = np.concatenate([table, -table.imag + 1j * table.imag])
    return cl.Buffer(context, cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR,
                     hostbuf=table.astype(dtype))


def _launch_label(kernel: "cl.Kernel", p: "PassGeometry", launches: int) -> str:
    """What the per-kernel profile (``runtime.KernelRecorder``) calls a launch of pass ``p``:
    kernel, axis and length (``"fft_strip rows n=1944"``), ``"stages"`` where a pass takes
    several launches (global-memory radix stages), ``"split"`` for the split plan."""
    stages = " stages" if launches > 1 else ""
    split = " split" if dict(p.defines).get("FFT_SPLIT") else ""
    return f"{kernel.function_name} {p.axis} n={p.n}{stages}{split}"


def _window_bytes(lg: "LaunchGeometry", nbatch: int, itemsize: int) -> int:
    """Bytes a launch must move at least: its source window's valid elements read once and its
    destination window's written once, for every batch element."""
    return nbatch * itemsize * (lg.src.nl * lg.src.ne + lg.dst.nl * lg.dst.ne)


def _same_arg(a, b) -> bool:
    """Whether kernel argument values ``a`` and ``b`` are the same (memory objects by handle,
    ``__local`` sizes by size, scalars by value)."""
    if a is b:
        return True
    mem_a, mem_b = isinstance(a, cl.MemoryObjectHolder), isinstance(b, cl.MemoryObjectHolder)
    if mem_a or mem_b:
        return mem_a and mem_b and a.int_ptr == b.int_ptr
    loc_a, loc_b = isinstance(a, cl.LocalMemory), isinstance(b, cl.LocalMemory)
    if loc_a or loc_b:
        return loc_a and loc_b and a.size == b.size
    return bool(a == b)


# What a plan notes for a kernel argument while it is being set (compares equal to nothing)
_UNKNOWN_ARG = object()


def _set_event(a: "cl_array.Array", evt: "cl.Event") -> None:
    """Make ``evt``, the last kernel that wrote ``a``, its only event.

    The kernel waited for every event ``a`` held (they are in its wait list), so ``evt``
    completes after all of them: the list stays one long. (``Array.add_event`` appends, and
    once the list is 13 long waits on the host for the oldest four: a layer loop that writes
    one array in place dozens of times then blocks in every call, and the host never runs
    ahead of the device.) The list is shared with views of ``a`` made by ``reshape``."""
    a.events[:] = [evt]


@dataclass(frozen=True)
class _Launch:
    """A launch ready to go: the kernel, its sizes and its whole argument list for a forward
    and for an inverse call, with the slots a call fills in (buffers of roles ``x``/``out``,
    the multiply's, the callbacks' values appended)."""

    kernel: "cl.Kernel"
    gsize: Tuple[int, ...]
    lsize: Optional[Tuple[int, ...]]
    forward_args: tuple
    inverse_args: tuple
    src_role: str
    dst_role: str
    pass_index: int
    callbacks: Tuple[str, ...]  # "LOAD"/"STORE" whose values follow the kernel's own
    label: str = ""             # what runtime.KernelRecorder calls the launch
    bytes_moved: int = 0        # its source window read once and its stored window written once


def _same_place(a: "cl_array.Array", b: "cl_array.Array") -> bool:
    """``a`` and ``b`` are the same bytes of one buffer (``out=x``, or two views of them)."""
    return a.base_data == b.base_data and a.offset == b.offset and a.nbytes == b.nbytes


def _overlap(a: "cl_array.Array", b: "cl_array.Array") -> bool:
    """``a`` and ``b`` (C-contiguous views) share a byte of one buffer: two views of one
    buffer that share none (``out=frames[1]`` for ``x=frames[0]``) are separate arrays."""
    return (a.base_data == b.base_data and a.offset < b.offset + b.nbytes
            and b.offset < a.offset + a.nbytes)


class FFTPlan:
    """A reusable FFT of one shape and dtype on one OpenCL queue.

    Parameters
    ----------
    shape : tuple of int
        Transform shape including batch axes, ``(..., Hp, Wp)`` (or ``(..., N)`` with
        ``axes=(-1,)``). Transformed axes must be sizes ``2^a 3^b 5^c`` from 1 to
        :data:`MAX_SIZE` (1080, 1920, 2160, 3840 are; see :func:`next_fft_size`).
    dtype : complex64 or complex128
        complex128 needs a device with fp64.
    queue : pyopencl.CommandQueue, optional
        Default: :func:`clholo.host.runtime.get_queue`. Kernels are enqueued here.
    axes : (-2, -1) or (-1,)
        Transform the last two axes (``fft2``) or the last axis only (``fft``).
    input_shape : tuple of int, optional
        Last axes ``(h, w)`` (or ``(n,)``) of the arrays given to :meth:`execute`; default the
        transform's. Smaller than the transform: the input is read as if zero-padded at the
        bottom/right (no padding copy; rows beyond ``h`` are not transformed). Larger: the
        top-left window is read.
    output_shape : tuple of int, optional
        Last axes of the output arrays, at most the transform's: only that top-left window is
        stored, and work that the window does not need is skipped. A 1D plan's ``(m,)`` may
        exceed ``n``: rows of ``m`` elements of which the first ``n`` are written and the rest
        left as they are (a row pitch, :func:`row_pitch`).
    variant : {"auto", "cpu", "gpu", "gpu-global"}
        Kernel family; ``"auto"`` picks ``"cpu"`` on CPU devices and ``"gpu"`` elsewhere.
        ``"gpu-global"`` is the GPU variant with every line run as global-memory stages (what
        ``"gpu"`` does for lines too long for local memory); it exists for testing.
    load_callback, store_callback : FFTCallback, optional
        Snippets run on each element of the input window as the first pass loads it, and of
        the output window as the last pass stores it; their extra arguments are given to
        :meth:`execute` (``load_args``, ``store_args``).
    share_work_with : FFTPlan, optional
        A plan on the same queue whose work buffers this one uses too, instead of its own
        (every work buffer of this plan must exist there, at least as large). Plans on one
        in-order queue run one after another, so they may share: a propagator keeps a plain
        plan and one with a callback of the same transform, and holds one set of buffers.

    Raises
    ------
    ValueError
        A transformed axis has a prime factor other than 2, 3, 5 (the message names the axis
        and the nearest accepted sizes) or is out of range; bad ``input_shape``/``output_shape``/``axes``;
        a ``share_work_with`` plan on another queue or without the work buffers this one needs.
    TypeError
        ``dtype`` is not complex64/complex128, or complex128 on a device without fp64.

    Attributes
    ----------
    geometry : PlanGeometry
        What :func:`plan_geometry` made of the arguments (passes, windows, launch sizes).

    Notes
    -----
    ``execute`` enqueues and returns at once. A plan owns its scratch buffers and its kernels
    carry their arguments; threads may share a plan (as :func:`fft2` & co. do): each call
    enqueues all its launches before another thread's call begins.
    """

    def __init__(self, shape: Sequence[int], dtype=np.complex64, *,
                 queue: Optional["cl.CommandQueue"] = None, axes: Sequence[int] = (-2, -1),
                 input_shape: Optional[Sequence[int]] = None,
                 output_shape: Optional[Sequence[int]] = None, variant: str = "auto",
                 load_callback: Optional[FFTCallback] = None,
                 store_callback: Optional[FFTCallback] = None,
                 share_work_with: Optional["FFTPlan"] = None):
        self.dtype = _check_dtype(dtype)
        if share_work_with is not None and not isinstance(share_work_with, FFTPlan):
            raise TypeError(f"share_work_with must be a clholo.fft.FFTPlan, got "
                            f"{type(share_work_with).__name__}")
        for name, cb in (("load_callback", load_callback), ("store_callback", store_callback)):
            if cb is not None and not isinstance(cb, FFTCallback):
                raise TypeError(f"{name} must be a clholo.fft.FFTCallback, got "
                                f"{type(cb).__name__}")
        self.load_callback, self.store_callback = load_callback, store_callback
        self.queue = resolve_queue(queue)
        self.context = self.queue.context
        self.device = self.queue.device
        if self.dtype == np.complex128:
            runtime.require_fp64(self.device, "FFTPlan(dtype=complex128)")

        self._itemsize = self.dtype.itemsize
        self._real = np.float64 if self.dtype == np.complex128 else np.float32
        # plan, build, and ask each built kernel how much local memory it holds itself and
        # how many work-items it allows (once per kernel); where a launch would exceed either,
        # plan again with smaller strips, line groups or work-groups
        limits = DeviceLimits.of(self.device)
        for _ in range(4):
            g = plan_geometry(shape, self.dtype, device=limits, axes=axes,
                              input_shape=input_shape, output_shape=output_shape,
                              variant=variant)
            self.geometry = g
            kernels = self._build_kernels(g)
            limits = _learn_kernel_limits(
                limits, self.device, [(p, kernels[self._kernel_key(p)]) for p in g.passes])
            if limits is None:
                break
        self.shape, self.axes, self.variant, self.order = g.shape, g.axes, g.variant, g.order
        self.batch_shape, self.transform_shape = g.batch_shape, g.transform_shape
        self.input_shape, self.output_shape = g.input_shape, g.output_shape
        self.in_full_shape, self.out_full_shape = g.in_full_shape, g.out_full_shape
        # NumPy arrays in and out: a CPU device reads and writes them in place (no copies);
        # other devices go through plan-owned device buffers
        self._host_zero_copy = bool(self.device.type & cl.device_type.CPU)
        self._buffers: Dict[str, "cl.Buffer"] = {}
        if share_work_with is not None:
            other = share_work_with
            have = {name: other._buffers[name].size for name, _ in other.geometry.buffers
                    if name in other._buffers}
            need = {name: max(1, elems) * self._itemsize for name, elems in g.buffers}
            short = {k: v for k, v in need.items() if have.get(k, 0) < v}
            if other.queue != self.queue or short:
                raise ValueError(
                    f"share_work_with: that plan ({other.shape}, {other.dtype}) runs on "
                    f"{'another queue' if other.queue != self.queue else 'its own queue'} and "
                    f"holds work buffers {have or 'none'} (bytes); this plan needs {need}: "
                    f"give a plan of the same transform on the same queue, or none")
            self._buffers = other._buffers  # the same dict: the buffers are made once
        self._twiddles: Dict[int, "cl.Buffer"] = {}
        self._host_lock = threading.Lock()  # execute_host through the plan's own buffers
        self._launches = self._launch_records(kernels)
        self._prepared = None  # set by the first execute (_prime_launches)

    # ------------------------------------------------------------------ construction
    def _twiddle(self, n: int) -> "cl.Buffer":
        tw = self._twiddles.get(n)
        if tw is None:
            tw = self._twiddles[n] = _twiddle_table(self.context, n, self.dtype)
        return tw

    def _pass_callbacks(self, p: PassGeometry) -> List[Tuple[str, FFTCallback]]:
        cbs = []
        if p.first and self.load_callback is not None:
            cbs.append(("LOAD", self.load_callback))
        if p.last and self.store_callback is not None:
            cbs.append(("STORE", self.store_callback))
        return cbs

    def _program(self, p: PassGeometry, callbacks) -> "cl.Program":
        layout = 2 if len(self.geometry.axes) == 1 else (0 if p.axis == "rows" else 1)
        return _pass_program(self.context, p, callbacks, layout)

    def _kernel_key(self, p: PassGeometry) -> tuple:
        return (p.program, p.kernel, p.defines, tuple(k for k, _ in self._pass_callbacks(p)))

    def _build_kernels(self, g: PlanGeometry) -> Dict[tuple, "cl.Kernel"]:
        """The kernels of ``g``'s passes, built (one per program, kernel, defines and
        callbacks) with their scalar argument types; no argument is set yet."""
        kernels = {}
        for p in g.passes:
            key = self._kernel_key(p)
            if key not in kernels:
                callbacks = self._pass_callbacks(p)
                program = self._program(p, callbacks)
                knl = cl.Kernel(program, p.kernel)
                # the program as built (pyopencl's own object, which knows its source): a
                # second kernel object of it for another launch is made from this, not from
                # clGetKernelInfo(PROGRAM), whose wrapper pyopencl probes for '_source' with a
                # clCreateKernel that fails (harmless on drivers, a report under Oclgrind)
                self.__dict__.setdefault("_kernel_programs", {})[id(knl)] = (knl, program)
                knl.set_scalar_arg_dtypes(
                    kernel_arg_dtypes(p.kernel, self._real)
                    + [self._real if dt == "real" else dt
                       for _, cb in callbacks for dt in cb.dtypes])
                kernels[key] = knl
        return kernels

    def _launch_records(self, kernels: Dict[tuple, "cl.Kernel"]) -> Tuple[_Launch, ...]:
        """Every argument that does not depend on the call's arrays set, once per plan: a
        call then only fills in its buffers (and multiply, callbacks)."""
        g, records = self.geometry, []
        for pi, p in enumerate(g.passes):
            callbacks = self._pass_callbacks(p)
            knl = kernels[self._kernel_key(p)]
            tw = self._twiddle(p.n)
            for lg in p.launches:
                base = [None] * len(FFT_PASS_ARGS)
                for prefix, w in (("src", lg.src), ("dst", lg.dst)):
                    buf = None if w.role in ("x", "out") else self._buffer(
                        w.role, dict(g.buffers)[w.role])
                    base[_ARG_INDEX[prefix]] = buf
                    base[_ARG_INDEX[prefix + "_off"]] = 0
                    base[_ARG_INDEX[prefix + "_bs"]] = w.bs
                    base[_ARG_INDEX[prefix + "_ls"]] = w.ls
                    base[_ARG_INDEX[prefix + "_es"]] = w.es
                base[_ARG_INDEX["src_nl"]], base[_ARG_INDEX["src_ne"]] = lg.src.nl, lg.src.ne
                base[_ARG_INDEX["nlines"]], base[_ARG_INDEX["nstore"]] = lg.dst.nl, lg.dst.ne
                for name, value in (("N", p.n), ("tw", tw), ("mul", tw), ("mul_off", 0),
                                    ("mul_bs", 0), ("mul_m", 1), ("mul_ls", p.mul_ls),
                                    ("mul_lmod", _NO_LINE_WRAP), ("mul_es", p.mul_es),
                                    ("mul_mode", 0), ("mid_n", p.n), ("mid_conj_a", 0),
                                    ("mid_conj_b", 0), ("mid_scale", 1.0)):
                    base[_ARG_INDEX[name]] = value
                extra = list(lg.extra)
                if lg.local_bytes:
                    extra.append(cl.LocalMemory(lg.local_bytes))
                args = {}
                for inverse in (False, True):
                    a = list(base)
                    a[_ARG_INDEX["conj_in"]] = int(inverse and p.first)
                    a[_ARG_INDEX["conj_out"]] = int(inverse and p.last)
                    a[_ARG_INDEX["scale"]] = g.scale if (inverse and p.last) else 1.0
                    args[inverse] = tuple(a + extra)
                records.append(_Launch(knl, lg.gsize, lg.lsize, args[False], args[True],
                                       lg.src.role, lg.dst.role, pi,
                                       tuple(k for k, _ in callbacks),
                                       _launch_label(knl, p, len(p.launches)),
                                       _window_bytes(lg, g.batch, self._itemsize)))
        return tuple(records)

    def _prime_launches(self) -> Tuple[tuple, ...]:
        """Check every launch against the device's limits and set every kernel argument, once
        per plan, at the first :meth:`execute` (placeholders where a call gives the value):
        every call then resets only the arguments it changes that differ from what the kernel
        holds, and enqueues.

        Launches of one kernel get a kernel object each (``clSetKernelArg`` of a scalar costs
        about 9 us of host time through pyopencl on PoCL, so passes that shared one object
        would reset their geometry at every call). Returns one ``(record, kernel, indices,
        held, dtypes)`` per launch: the argument indices a call may change (its arrays, the
        multiply, the direction's conjugations and scale, the callbacks' values), the values
        the kernel holds now and the host dtypes to convert scalars with."""
        ix = _ARG_INDEX
        placeholder = cl.Buffer(self.context, cl.mem_flags.READ_WRITE, self._itemsize)
        call_slots = tuple(ix[k] for k in ("src", "src_off", "dst", "dst_off", "mul", "mul_off",
                                           "mul_bs", "mul_m", "mul_lmod", "mul_mode",
                                           "conj_in", "conj_out", "scale"))
        cbs = {"LOAD": self.load_callback, "STORE": self.store_callback}
        prepared, used = [], set()
        for rec in self._launches:
            p = self.geometry.passes[rec.pass_index]
            cb_dtypes = [dt for kind in rec.callbacks for dt in cbs[kind].dtypes]
            dtypes = (kernel_arg_dtypes(p.kernel, self._real)
                      + [self._real if dt == "real" else dt for dt in cb_dtypes])
            knl = rec.kernel
            if id(knl) in used:
                knl = cl.Kernel(self._kernel_programs[id(knl)][1], knl.function_name)
                knl.set_scalar_arg_dtypes(dtypes)
            used.add(id(knl))
            args = [placeholder if a is None else a for a in rec.forward_args]
            args += [placeholder if dt is None else (self._real if dt == "real" else dt)(0)
                     for dt in cb_dtypes]
            runtime.check_launch(self.queue, knl, rec.gsize, rec.lsize, args)
            knl.set_args(*args)
            vary = call_slots + tuple(range(len(rec.forward_args), len(args)))
            prepared.append((rec, knl, vary, args, dtypes))
        return tuple(prepared)

    # ------------------------------------------------------------------ buffers
    def _buffer(self, name: str, nelems: int) -> "cl.Buffer":
        buf = self._buffers.get(name)
        if buf is None:
            buf = cl.Buffer(self.context, cl.mem_flags.READ_WRITE, max(1, nelems) * self._itemsize)
            self._buffers[name] = buf
        return buf

    # ------------------------------------------------------------------ execution
    def _check_array(self, a, name: str, shape: Tuple[int, ...]) -> None:
        if not isinstance(a, cl_array.Array):
            raise TypeError(f"{name} must be a pyopencl.array.Array (got {type(a).__name__}); "
                            f"use clholo.fft.fft2 & co. for NumPy arrays")
        if a.dtype != self.dtype:
            raise TypeError(f"{name}.dtype is {a.dtype}, the plan's is {self.dtype}")
        if tuple(a.shape) != tuple(shape):
            raise ValueError(f"{name}.shape is {tuple(a.shape)}, the plan expects {tuple(shape)}")
        if not a.flags.c_contiguous:
            raise ValueError(f"{name} must be C-contiguous")
        if a.context != self.context:
            raise ValueError(f"{name} lives in another OpenCL context than the plan's queue")

    def execute(self, x: "cl_array.Array", *, out: Optional["cl_array.Array"] = None,
                inverse: bool = False, multiply: Optional["cl_array.Array"] = None,
                multiply_at: str = "output", load_args: Sequence = (),
                store_args: Sequence = (), wait_for=None) -> "cl_array.Array":
        """Enqueue the transform of ``x``; returns ``out`` without waiting.

        Parameters
        ----------
        x : pyopencl.array.Array, shape ``batch + input_shape``, the plan's dtype
        out : pyopencl.array.Array, optional
            Shape ``batch + output_shape``; allocated when absent. ``out=x`` (in place) needs
            ``input_shape == output_shape``.
        inverse : bool
            Inverse transform (with the ``1/N`` of NumPy's ``ifft``/``ifft2``).
        multiply : pyopencl.array.Array, optional
            Pointwise factor fused into the transform, the plan's dtype, shape
            ``transform_shape`` or ``(M,) + transform_shape``; batch element ``b`` (flattened
            leading index; for 1D plans every line) uses ``multiply[b % M]``.
        multiply_at : {"output", "input"}
            ``"output"``: ``out = T(x) * multiply``; ``"input"``: ``out = T(x_padded *
            multiply)`` where the multiply sees the zero-padded input frame.
        load_args, store_args : sequence
            Values of the load/store callbacks' extra parameters (:class:`FFTCallback`).
            Arrays among them are not waited for: give their events in ``wait_for``.
        wait_for : list of pyopencl.Event, optional
            Events the first kernel waits for (``x.events``, ``out.events`` and
            ``multiply.events`` are waited for too).

        Returns
        -------
        pyopencl.array.Array
            ``out``; its ``events`` hold the last kernel's event.
        """
        if inverse is not True and inverse is not False:  # "no" would be an inverse
            inverse = validate.flag(inverse, name="inverse")
        self._check_array(x, "x", self.in_full_shape)
        if out is None:
            out = cl_array.Array(self.queue, self.out_full_shape, self.dtype)
        else:
            self._check_array(out, "out", self.out_full_shape)
        same = _same_place(out, x)
        if (same and self.input_shape != self.output_shape) or (not same and _overlap(out, x)):
            raise ValueError("out overlaps x: in-place transforms need out is x and "
                             "input_shape == output_shape; otherwise give an out that shares "
                             "no bytes with x")
        if multiply_at not in ("output", "input"):
            raise ValueError(f"multiply_at={multiply_at!r}: use 'output' or 'input'")
        mul_mode = 0
        if multiply is not None:
            if not isinstance(multiply, cl_array.Array):
                raise TypeError("multiply must be a pyopencl.array.Array")
            if multiply.dtype != self.dtype:
                raise TypeError(f"multiply.dtype is {multiply.dtype}, the plan's is {self.dtype}")
            ts = tuple(self.transform_shape)
            ms = tuple(multiply.shape)
            if ms == ts:
                m = 1
            elif len(ms) == len(ts) + 1 and ms[1:] == ts and ms[0] >= 1:
                m = ms[0]
            else:
                raise ValueError(f"multiply.shape is {ms}; expected {ts} or (M,) + {ts}")
            if not multiply.flags.c_contiguous:
                raise ValueError("multiply must be C-contiguous")
            if multiply.context != self.context:
                raise ValueError("multiply lives in another OpenCL context than the plan's "
                                 "queue: copy it there, cla.to_device(plan.queue, multiply.get())")
            mul_mode = 1 if multiply_at == "input" else 2

        cb_values = {"LOAD": [], "STORE": []}
        for kind, cb, vals, what in (("LOAD", self.load_callback, load_args, "load_args"),
                                     ("STORE", self.store_callback, store_args, "store_args")):
            if cb is not None:
                cb_values[kind] = cb._values(vals, what, self._real)
            elif vals:
                raise ValueError(f"{what} given but the plan has no "
                                 f"{kind.lower()}_callback")
        waits = list(wait_for or []) + list(x.events) + list(out.events)
        if multiply is not None:
            waits += list(multiply.events)
        waits += other_queue_markers(self.queue, x, out, multiply)

        isz = self._itemsize
        bufs = {"x": (x.base_data, x.offset // isz), "out": (out.base_data, out.offset // isz)}
        mul_pass = -1
        if multiply is not None:
            one_d = len(self.axes) == 1
            mul_pass = 0 if mul_mode == 1 else len(self.geometry.passes) - 1
            mul_vals = (multiply.base_data, multiply.offset // isz,
                        0 if one_d else self.geometry.mul_frame, 1 if one_d else m,
                        m if one_d else _NO_LINE_WRAP, mul_mode)
        ix = _ARG_INDEX
        mul_slots = [ix[k] for k in ("mul", "mul_off", "mul_bs", "mul_m", "mul_lmod", "mul_mode")]
        # every pass enqueued as one step, with no other thread's launch in between: another
        # thread's call of this plan (fft2 & co. share one per shape and queue) would reset
        # these kernels' arguments and write the same work buffers
        with runtime._launch_lock:
            if self._prepared is None:
                self._prepared = self._prime_launches()
            evt = None
            for rec, knl, vary, held, dtypes in self._prepared:
                # the arguments were set and the launch checked once per plan
                # (_prime_launches): reset only what this call changes
                args = list(rec.inverse_args if inverse else rec.forward_args)
                if rec.src_role in bufs:
                    args[ix["src"]], args[ix["src_off"]] = bufs[rec.src_role]
                if rec.dst_role in bufs:
                    args[ix["dst"]], args[ix["dst_off"]] = bufs[rec.dst_role]
                if rec.pass_index == mul_pass:
                    for i, v in zip(mul_slots, mul_vals):
                        args[i] = v
                for kind in rec.callbacks:
                    args += cb_values[kind]
                for i in vary:
                    v = args[i]
                    if v is not held[i] and not _same_arg(v, held[i]):
                        dt = dtypes[i] if i < len(dtypes) else None
                        # not known until set: a Ctrl-C between the set and the note must
                        # not leave a note of the old value (the next call would skip the
                        # reset, and the kernel would read this call's array)
                        held[i] = _UNKNOWN_ARG
                        knl.set_arg(i, v if dt is None else dt(v))
                        held[i] = v
                evt = cl.enqueue_nd_range_kernel(self.queue, knl, rec.gsize, rec.lsize,
                                                 wait_for=waits or None)
                runtime.note_launch(knl, rec.gsize, rec.lsize, evt, label=rec.label,
                                    bytes_moved=rec.bytes_moved)
                waits = []
            _set_event(out, evt)
        return out

    # ------------------------------------------------------------------ host arrays
    def execute_host(self, x: np.ndarray, *, out: Optional[np.ndarray] = None,
                     inverse: bool = False) -> np.ndarray:
        """Transform a NumPy array; blocks until done.

        On a CPU device the kernels read ``x`` and write ``out`` where they lie (host-pointer
        buffers, no copies); on other devices they go through plan-owned device buffers.

        Parameters
        ----------
        x : np.ndarray, shape ``batch + input_shape``
            Converted to the plan's dtype if it is another complex type.
        out : np.ndarray, optional
            Shape ``batch + output_shape``, the plan's dtype, C-contiguous; may be ``x``, but
            must not overlap it otherwise.
        inverse : bool
            The inverse transform (with ``1/N``) instead of the forward.

        Returns
        -------
        np.ndarray
        """
        inverse = validate.flag(inverse, name="inverse")
        x = np.asarray(x)
        if x.dtype not in _COMPLEX:
            raise TypeError(f"x.dtype is {x.dtype}; clholo.fft needs complex64 or complex128")
        if tuple(x.shape) != self.in_full_shape:
            raise ValueError(f"x.shape is {x.shape}, the plan expects {self.in_full_shape}")
        x = np.ascontiguousarray(x, dtype=self.dtype)
        if not np.all(np.isfinite(x)):
            raise ValueError("x contains NaN/inf values; every value must be finite")
        if out is None:
            out = np.empty(self.out_full_shape, self.dtype)
        elif (not isinstance(out, np.ndarray) or out.dtype != self.dtype
              or tuple(out.shape) != self.out_full_shape or not out.flags.c_contiguous):
            raise ValueError(f"out must be a C-contiguous {self.dtype} ndarray of shape "
                             f"{self.out_full_shape}")
        elif not out.flags.writeable:
            raise ValueError("out is a read-only array: give a writeable one, or leave out= "
                             "off to get a new array")
        if self._host_zero_copy:
            return self._execute_host_zero_copy(x, out, inverse)
        nin = int(np.prod(self.in_full_shape))
        nout = int(np.prod(self.out_full_shape))
        # the plan's two buffers hold one call's values from the copy in to the copy out:
        # another thread's call (fft2 & co. share a plan per shape and queue) waits for them
        with self._host_lock:
            dx = cl_array.Array(self.queue, self.in_full_shape, self.dtype,
                                data=self._buffer("host_in", nin))
            dout = cl_array.Array(self.queue, self.out_full_shape, self.dtype,
                                  data=self._buffer("host_out", nout))
            cl.enqueue_copy(self.queue, dx.base_data, x, is_blocking=False)
            self.execute(dx, out=dout, inverse=inverse)
            cl.enqueue_copy(self.queue, out, dout.base_data, is_blocking=True)
        return out

    def _execute_host_zero_copy(self, x: np.ndarray, out: np.ndarray,
                                inverse: bool) -> np.ndarray:
        """A CPU device shares the host's memory: the kernels read ``x`` and write ``out``
        where they lie (``USE_HOST_PTR`` buffers), and mapping ``out`` afterwards is the
        synchronisation OpenCL asks for, without a copy on PoCL."""
        mf = cl.mem_flags
        same = out is x or (out.__array_interface__["data"][0]
                            == x.__array_interface__["data"][0])
        if not same and np.shares_memory(x, out):
            raise ValueError("out overlaps x without being x: give a separate array or out=x")
        # a zero-sized host pointer is not a valid buffer: shapes here are never empty
        dout_buf = cl.Buffer(self.context, mf.READ_WRITE | mf.USE_HOST_PTR, hostbuf=out)
        dx_buf = dout_buf if same else cl.Buffer(self.context, mf.READ_ONLY | mf.USE_HOST_PTR,
                                                  hostbuf=x)
        dx = cl_array.Array(self.queue, self.in_full_shape, self.dtype, data=dx_buf)
        dout = cl_array.Array(self.queue, self.out_full_shape, self.dtype, data=dout_buf)
        self.execute(dx, out=dout, inverse=inverse)
        mapped, _ = cl.enqueue_map_buffer(self.queue, dout_buf, cl.map_flags.READ, 0,
                                          self.out_full_shape, self.dtype, wait_for=dout.events,
                                          is_blocking=True)
        mapped.base.release()
        self.queue.finish()
        return out


# ---------------------------------------------------------------------- round trips
@dataclass(frozen=True)
class RoundTripGeometry:
    """What :class:`RoundTripPlan` derives from shape, length, dtype and device limits (pure:
    :func:`round_trip_geometry`).

    Attributes
    ----------
    shape : tuple of int
        The arrays' shape, batch axes in front: ``(..., rows, cols)``.
    batch : int
        Flattened batch elements.
    n : int
        Transform length.
    axis : {"rows", "cols"}
        What a line is.
    first : {"forward", "inverse"}
        The first transform's direction.
    mid_n : int
        Elements kept between the transforms (the rest is zeroed).
    nlines : int
        Lines per batch element.
    nelems : int
        Elements of a line in the arrays (``<= n``; zero-padded to ``n``).
    pitch : int
        Row stride of the arrays, in elements (``>= cols``; their shape is
        ``batch + (rows, pitch)``).
    mul_frame : (int, int)
        The mid multiply's frame: ``(n, nlines)`` for columns, else ``(nlines, n)``; element
        ``(k, line)`` / ``(line, k)``.
    pass_ : PassGeometry
        The one pass's kernel and launch.
    """

    shape: Tuple[int, ...]
    batch: int
    n: int
    axis: str
    first: str
    mid_n: int
    nlines: int
    nelems: int
    mul_frame: Tuple[int, int]
    pass_: PassGeometry
    pitch: int = 0

    @property
    def array_shape(self) -> Tuple[int, ...]:
        """Shape of the arrays :meth:`RoundTripPlan.execute` reads and writes."""
        return self.shape[:-1] + (self.pitch or self.shape[-1],)


def round_trip_geometry(shape: Sequence[int], n: int, dtype=np.complex64, *,
                        device: DeviceLimits, axis: str, first: str = "forward",
                        mid_n: Optional[int] = None, variant: str = "auto",
                        pitch: Optional[int] = None) -> RoundTripGeometry:
    """The one pass of a :class:`RoundTripPlan`, a pure function of the device's limits.

    Parameters
    ----------
    shape : tuple of int
        ``batch + (rows, cols)`` of the input and output arrays.
    n : int
        Transform length, a size ``2^a 3^b 5^c`` at least the line length.
    dtype : complex64 or complex128
    device : DeviceLimits
        The limits that matter (no OpenCL call is made).
    axis : {"rows", "cols"}
        Lines are rows or columns.
    first : {"forward", "inverse"}
        Direction of the first transform.
    mid_n : int, optional
        Elements kept between the transforms (default ``n``).
    variant : {"auto", "cpu", "gpu"}
        Kernel family (``"auto"``: by the device's type).
    pitch : int, optional
        Row stride of the arrays, in elements, at least ``cols`` (default ``cols``): arrays
        ``batch + (rows, pitch)`` of which the first ``cols`` elements of each row are read
        and written (:func:`row_pitch`).

    Raises
    ------
    ValueError
        Bad arguments, or a line of ``n`` points that does not fit the variant's fast memory
        (the GPU variant's lines beyond its local-memory budget): :func:`round_trip_fits` asks
        first.
    """
    dt = _check_dtype(dtype)
    shape = _whole_numbers(shape, "shape", "a sequence of ints")
    if len(shape) < 2 or min(shape) < 1:
        raise ValueError(f"shape={shape!r}: give (..., rows, cols), every entry >= 1")
    if axis not in ("rows", "cols"):
        raise ValueError(f"axis={axis!r}: use 'rows' (lines are rows) or 'cols' (columns)")
    if first not in ("forward", "inverse"):
        raise ValueError(f"first={first!r}: use 'forward' (then inverse) or 'inverse' "
                         f"(then forward)")
    n = int(n)
    if not is_fft_size(n) or n > MAX_SIZE:
        lo, hi = nearest_fft_sizes(n)
        raise ValueError(f"n={n} is not a size 2^a 3^b 5^c up to {MAX_SIZE}; nearest accepted "
                         f"sizes: {lo} and {hi}")
    if variant not in ("auto", "cpu", "gpu"):
        raise ValueError(f"variant={variant!r}: a round trip runs in fast memory; use 'auto', "
                         f"'cpu' or 'gpu'")
    if variant == "auto":
        variant = "cpu" if device.is_cpu else "gpu"
    rows, cols = shape[-2:]
    nlines, nelems = (rows, cols) if axis == "rows" else (cols, rows)
    if nelems > n:
        raise ValueError(f"lines of {nelems} elements (axis={axis!r} of shape {shape}) are "
                         f"longer than the transform n={n}; give n >= {nelems}")
    mid_n = n if mid_n is None else int(mid_n)
    if not 1 <= mid_n <= n:
        raise ValueError(f"mid_n={mid_n} must lie in [1, n={n}]")
    batch = int(np.prod(shape[:-2], dtype=np.int64)) if len(shape) > 2 else 1
    pitch = cols if pitch is None else int(pitch)
    if pitch < cols:
        raise ValueError(f"pitch={pitch} is shorter than a row of cols={cols} elements; give "
                         f"pitch >= {cols} (or leave it unset)")
    bs = rows * pitch
    if axis == "rows":
        src = Window("x", bs, pitch, 1, nlines, nelems)
        dst = Window("out", bs, pitch, 1, nlines, nelems)
        mul_ls, mul_es, frame = n, 1, (nlines, n)
    else:
        src = Window("x", bs, 1, pitch, nlines, nelems)
        dst = Window("out", bs, 1, pitch, nlines, nelems)
        mul_ls, mul_es, frame = 1, nlines, (n, nlines)
    p, _ = _pass_geometry(axis, n, src, dst, nlines, mul_ls, mul_es, True, True, variant,
                          dt.itemsize, batch, device)
    if p.kind == "global":
        raise ValueError(f"a line of {n} points does not fit the {variant} variant's fast "
                         f"memory, where a round trip runs; use two FFTPlan passes instead "
                         f"(round_trip_fits() tells beforehand)")
    return RoundTripGeometry(shape, batch, n, axis, first, mid_n, nlines, nelems, frame, p,
                             pitch)


def plan_reach(device: DeviceLimits, dtype=np.complex64) -> Dict[str, int]:
    """The longest line each kind of pass takes on a device: the plans an ``n``-point pass of
    ``dtype`` gets for every size ``2^a 3^b 5^c`` up to :data:`MAX_SIZE` (pure geometry: the
    limits a built kernel reports, ``CL_KERNEL_WORK_GROUP_SIZE``, can still move a size to the
    next kind; ``clholo info`` prints it).

    Parameters
    ----------
    device : DeviceLimits
        The device's limits (:meth:`DeviceLimits.of`).
    dtype : complex64 or complex128

    Returns
    -------
    dict
        Kind -> the longest line, in points, of the kinds that take one: ``"cpu strips"``,
        ``"two buffers"``, ``"in place"`` and ``"split"`` (one launch a pass, round trips too),
        ``"global stages"`` (one launch a radix stage, no round trip). A kind's longest line
        says nothing of the sizes below it: a size whose stages give a work-item too many
        butterflies takes the next kind.
    """
    dt = _check_dtype(dtype)
    reach: Dict[str, int] = {}
    for n in range(2, MAX_SIZE + 1):
        if not is_fft_size(n):
            continue
        (p,) = plan_geometry((1, n), dt, device=device, axes=(-1,)).passes
        d = dict(p.defines)
        kind = {"cpu": "cpu strips", "global": "global stages"}.get(p.kind) or (
            "split" if d.get("FFT_SPLIT") else "in place" if d.get("FFT_INPLACE")
            else "two buffers")
        reach[kind] = n
    return reach


def round_trip_fits(shape: Sequence[int], n: int, dtype=np.complex64, *, device: DeviceLimits,
                    axis: str, variant: str = "auto") -> bool:
    """Whether :func:`round_trip_geometry` finds room for the lines in fast memory.

    Parameters
    ----------
    shape, n, dtype, device, axis, variant
        As for :func:`round_trip_geometry`.
    """
    try:
        round_trip_geometry(shape, n, dtype, device=device, axis=axis, variant=variant)
    except ValueError:
        return False
    return True


def even_strip_lanes(geometry: "RoundTripGeometry") -> int:
    """Lines per strip of a round trip's CPU kernel (its ``VW / 2``): the ``lanes`` of the
    :class:`EvenFactors` it reads laid out strip by strip; 0 for the GPU kernels, which read
    the frames' quarter."""
    p = geometry.pass_
    return dict(p.defines)["VW"] // 2 if p.kind == "cpu" else 0


def even_factors_bytes(geometry: "RoundTripGeometry", count: int, dtype=np.complex64) -> int:
    """Device bytes of the strip layout :meth:`RoundTripPlan.even_factors` makes of ``count``
    frames for a round trip of this geometry (0 where the kernels read the frames
    themselves)."""
    lanes = even_strip_lanes(geometry)
    if not lanes:
        return 0
    fr = geometry.mul_frame
    nlines = fr[1] if geometry.axis == "cols" else fr[0]
    return (int(count) * -(-nlines // lanes) * lanes * (geometry.n // 2 + 1)
            * np.dtype(dtype).itemsize)


class EvenFactors:
    """Even multiply frames prepared for the round trips of one geometry
    (:meth:`RoundTripPlan.even_factors`; give it as ``multiply`` to :meth:`RoundTripPlan.execute`).

    On the CPU kernels (strips of ``lanes`` lines) ``data`` holds the frames laid out strip
    by strip (``[M, S, n // 2 + 1, lanes]``, kernel ``fft_even_strips``, reference
    :func:`clholo.reference.even_strip_factors`): each strip reads its factors in order, a
    64-byte vector each, where the quarter of the frame (``multiply_even=True``) is one vector
    per row of the frame at the frame's row stride. It holds no reference to the frames it was
    made from. On the GPU kernels ``data`` is the frames themselves, read in their quarter. The
    products are the same bits either way.

    Attributes
    ----------
    data : pyopencl.array.Array
        What the kernel reads: the strip layout, or the frames ``(M,) + mul_frame``.
    layout : {"strips", "quarter"}
    lanes : int
        Lines per strip (``"strips"``), else 0.
    count : int
        ``M``, the number of frames (batch element ``b`` uses frame ``b % M``).
    key : tuple
        The geometry it fits: ``(mul_frame, n, axis, lanes, dtype)``.
    """

    def __init__(self, data, layout: str, lanes: int, count: int, key: tuple):
        self.data, self.layout, self.lanes, self.count, self.key = (data, layout, int(lanes),
                                                                    int(count), key)

    @property
    def frames(self) -> "cl_array.Array":
        """The frames ``(M,) + mul_frame`` themselves (the ``"quarter"`` layout only)."""
        if self.layout != "quarter":
            raise ValueError("EvenFactors laid out in strips keep no frames: give the frames "
                             "themselves where a plan reads whole frames")
        return self.data

    @property
    def nbytes(self) -> int:
        """Device bytes of ``data`` (what a cache that holds it keeps alive)."""
        return int(self.data.nbytes)


class RoundTripPlan:
    """A forward and an inverse FFT of every line in one pass over memory, with a pointwise
    step between them in fast memory: the kernel of "a layer is two kernels".

    Each line (a row or a column of ``[..., rows, cols]`` arrays; shorter lines read as
    zero-padded to ``n``) is transformed in the ``first`` direction, then, element by element,
    multiplied by a factor (``multiply=`` of :meth:`execute`) and passed through a mid
    callback, elements ``k >= mid_n`` set to zero, transformed in the other direction and its
    first ``nelems`` elements stored (NumPy's conventions: the inverse carries ``1/n``)::

        first="forward":  out = ifft(crop_mid(fft(pad(x)) * f))[:nelems]
        first="inverse":  out = fft(pad_n(mid(ifft(pad(x))[:mid_n])))[:nelems]

    (:func:`clholo.reference.round_trip` is the NumPy reference.) Both kernel variants run it
    (``kernels/fft_cpu.cl`` strips, ``kernels/fft_gpu.cl`` lines in local memory); lines too
    long for local memory raise (see :func:`round_trip_fits`).

    Parameters
    ----------
    shape : tuple of int
        ``batch + (rows, cols)`` of the input and output arrays.
    n : int
        Transform length, a size ``2^a 3^b 5^c`` at least the line length.
    dtype : complex64 or complex128
    axis : {"rows", "cols"}
        Lines are rows (the transform runs along the last axis) or columns (along axis -2).
    first : {"forward", "inverse"}
        Direction of the first transform; the second is the other.
    mid_n : int, optional
        Elements of the first transform's result kept for the second (default ``n``); the mid
        multiply and callback see only those.
    mid_callback : FFTCallback, optional
        Defines ``real2 clholo_mid(real2 v, long b, int row, int col, <params>)`` (and
        optionally ``clholo_mid4``, see ``kernels/fft_common.h``), run on every kept element
        after the multiply; ``row``/``col`` are the element's position in the frame (for
        columns: row = element, col = line), ``b`` the flattened batch index.
    queue : pyopencl.CommandQueue, optional
    variant : {"auto", "cpu", "gpu"}
    pitch : int, optional
        Row stride of the arrays given to :meth:`execute`, in elements, at least ``cols``
        (default ``cols``): they are ``batch + (rows, pitch)``, and only the first ``cols``
        elements of each row are read and written (:func:`row_pitch`).

    Notes
    -----
    Every kernel argument is set once at construction; :meth:`execute` resets only the ones
    that changed since the last call (the arrays, the multiply, the callback's values). Run one
    plan from one host thread at a time. ``out=x`` (in place) is allowed.
    """

    def __init__(self, shape: Sequence[int], n: int, dtype=np.complex64, *, axis: str,
                 first: str = "forward", mid_n: Optional[int] = None,
                 mid_callback: Optional[FFTCallback] = None,
                 queue: Optional["cl.CommandQueue"] = None, variant: str = "auto",
                 pitch: Optional[int] = None):
        self.dtype = _check_dtype(dtype)
        if mid_callback is not None and not isinstance(mid_callback, FFTCallback):
            raise TypeError(f"mid_callback must be a clholo.fft.FFTCallback, got "
                            f"{type(mid_callback).__name__}")
        self.mid_callback = mid_callback
        self.queue = resolve_queue(queue)
        self.context = self.queue.context
        if self.dtype == np.complex128:
            runtime.require_fp64(self.queue.device, "RoundTripPlan(dtype=complex128)")
        callbacks = [("MID", mid_callback)] if mid_callback is not None else []
        # plan, build, and plan again where the built kernel holds local memory itself or
        # allows fewer work-items than planned (as FFTPlan does)
        limits = DeviceLimits.of(self.queue.device)
        for _ in range(4):
            g = round_trip_geometry(shape, n, self.dtype, device=limits, axis=axis,
                                    first=first, mid_n=mid_n, variant=variant, pitch=pitch)
            p = g.pass_
            # CPU strips take the batch element from global dimension 0 (fft_cpu.cl,
            # FFT_BATCH_FAST): a strip's fields run one after the other and share what their
            # multiply and mid callback read; GPUs where _GPU_BATCH_FAST says so
            (lg,) = p.launches
            # work-groups (GPU) or work-items (CPU strips, local size 1) along the lines
            parts = lg.gsize[0] // lg.lsize[0]
            batch_fast = ((p.kind == "cpu" or limits.setting("batch_fast"))
                          and parts <= _MAX_GROUPS_DIM1)
            quads = p.kind != "cpu" and limits.setting("mid_quads")
            program = _pass_program(self.context, p, callbacks, 0 if p.axis == "rows" else 1,
                                    {"FFT_ROUND_TRIP": 1, "FFT_BATCH_FAST": int(batch_fast),
                                     "FFT_MID_QUADS": int(quads)})
            knl = cl.Kernel(program, p.kernel)
            limits = _learn_kernel_limits(limits, self.queue.device, [(p, knl)])
            if limits is None:
                break
        self.geometry = g
        self.shape, self.n, self.axis, self.first, self.mid_n = (g.shape, g.n, g.axis, g.first,
                                                                 g.mid_n)
        self.variant = "cpu" if g.pass_.kind == "cpu" else "gpu"
        self._itemsize = self.dtype.itemsize
        self._real = np.float64 if self.dtype == np.complex128 else np.float32
        self._kernel = knl
        self._dtypes = (kernel_arg_dtypes(p.kernel, self._real)
                        + [self._real if dt == "real" else dt
                           for _, cb in callbacks for dt in cb.dtypes])
        knl.set_scalar_arg_dtypes(self._dtypes)
        self._gsize, self._lsize = lg.gsize, lg.lsize
        self._parts = int(parts)
        if batch_fast:  # FFT_BATCH_FAST: groups (batch, lines)
            self._gsize = (lg.gsize[1] * lg.lsize[0], self._parts)
        self._label = f"{_launch_label(knl, self.geometry.pass_, 1)} round trip"
        self._bytes_moved = _window_bytes(lg, self.geometry.batch, self._itemsize)
        self._twiddles = _twiddle_table(self.context, g.n, self.dtype)
        inv1 = g.first == "inverse"
        scale = 1.0 / g.n
        placeholder = cl.Buffer(self.context, cl.mem_flags.READ_WRITE, self._itemsize)
        values = dict(src=placeholder, src_off=0, src_bs=lg.src.bs, src_ls=lg.src.ls,
                      src_es=lg.src.es, src_nl=lg.src.nl, src_ne=lg.src.ne, dst=placeholder,
                      dst_off=0, dst_bs=lg.dst.bs, dst_ls=lg.dst.ls, dst_es=lg.dst.es,
                      nlines=lg.dst.nl, nstore=lg.dst.ne, N=g.n, tw=self._twiddles,
                      mul=self._twiddles, mul_off=0, mul_bs=0, mul_m=1, mul_ls=p.mul_ls,
                      mul_lmod=_NO_LINE_WRAP, mul_es=p.mul_es, mul_mode=0,
                      conj_in=int(inv1), conj_out=int(not inv1),
                      scale=1.0 if inv1 else scale, mid_n=g.mid_n, mid_conj_a=int(inv1),
                      mid_conj_b=int(not inv1), mid_scale=scale if inv1 else 1.0)
        args = [values[a.name] for a in FFT_PASS_ARGS] + list(lg.extra)
        if lg.local_bytes:
            args.append(cl.LocalMemory(lg.local_bytes))
        self._nfixed = len(args)
        if mid_callback is not None:
            # placeholders of the right kinds until the first execute sets the real values
            args += [placeholder if dt is None else (self._real if dt == "real" else dt)(0)
                     for dt in mid_callback.dtypes]
        runtime.set_launch_args(self.queue, knl, self._gsize, self._lsize, args)
        self._args = list(args)  # what the kernel holds now

    @property
    def mid_parts(self) -> int:
        """How many parts a batch element's lines are summed in by a mid callback that adds
        up (``FFT_MID_CB_SUMS``, ``kernels/fft_common.h``): the GPU kernels' work-groups along
        the lines, or the CPU strips' work-items. ``clholo_mid_sums_store`` gets parts
        ``0 .. mid_parts - 1``."""
        return self._parts

    def _even_key(self) -> tuple:
        # made once: execute compares it on every call with EvenFactors (host time a launch)
        key = getattr(self, "_even_key_value", None)
        if key is None:
            key = self._even_key_value = (tuple(self.geometry.mul_frame), self.n, self.axis,
                                          self._strip_lanes(), self.dtype.str)
        return key

    @property
    def even_key(self) -> tuple:
        """What :class:`EvenFactors` made by :meth:`even_factors` fit (their ``key``): plans
        with the same key take each other's."""
        return self._even_key()

    def _strip_lanes(self) -> int:
        return even_strip_lanes(self.geometry)

    def even_factors(self, multiply: "cl_array.Array") -> EvenFactors:
        """``multiply`` (frames even in both indices, as for ``multiply_even=True``) prepared
        for this plan's kernel: on CPU strips a copy laid out strip by strip, made on the
        device now (``(M, S, n // 2 + 1, lanes)``: half the frames' bytes); on GPUs the
        frames themselves. Make it once per transfer function and pass it as ``multiply``
        to every :meth:`execute` (it does not follow later writes to ``multiply``).

        Parameters
        ----------
        multiply : pyopencl.array.Array, ``mul_frame`` or ``(M,) + mul_frame``
            The plan's dtype and context, C-contiguous; even in both indices (not checked:
            an odd frame gives the mirror image of its quarter's values, as
            ``multiply_even=True`` does).

        Returns
        -------
        EvenFactors
        """
        if not isinstance(multiply, cl_array.Array):
            raise TypeError(f"multiply must be a pyopencl.array.Array (got "
                            f"{type(multiply).__name__})")
        if multiply.dtype != self.dtype:
            raise TypeError(f"multiply.dtype is {multiply.dtype}, the plan's is {self.dtype}")
        fr, ms = tuple(self.geometry.mul_frame), tuple(multiply.shape)
        if not (ms == fr or (len(ms) == 3 and ms[1:] == fr and ms[0] >= 1)):
            raise ValueError(f"multiply.shape is {ms}; expected {fr} or (M,) + {fr}")
        if not multiply.flags.c_contiguous:
            raise ValueError("multiply must be C-contiguous")
        if multiply.context != self.context:
            raise ValueError("multiply lives in another OpenCL context than the plan's queue")
        frames = multiply if len(ms) == 3 else multiply.reshape((1,) + fr)
        lanes = self._strip_lanes()
        if not lanes:
            return EvenFactors(frames, "quarter", 0, frames.shape[0], self._even_key())
        if self.axis == "cols":
            nlines, ls, es = fr[1], 1, fr[1]
        else:
            nlines, ls, es = fr[0], fr[1], 1
        S, K, M = -(-nlines // lanes), self.n // 2 + 1, frames.shape[0]
        data = cl_array.empty(self.queue, (M, S, K, lanes), self.dtype)
        p = self.geometry.pass_
        program = _pass_program(self.context, p, [], 0 if p.axis == "rows" else 1)
        knl = cl.Kernel(program, "fft_even_strips")
        evt = runtime.launch(knl, self.queue, (S * lanes, K, M), None, frames.base_data,
                             np.int64(frames.offset // self._itemsize), np.int64(fr[0] * fr[1]),
                             np.int64(ls), np.int64(es), np.int32(nlines), data.data,
                             wait_for=list(frames.events) or None)
        data.add_event(evt)
        return EvenFactors(data, "strips", lanes, M, self._even_key())

    def _set(self, index: int, value) -> None:
        old = self._args[index]
        if old is value or (not isinstance(value, cl.MemoryObjectHolder)
                            and not isinstance(old, cl.MemoryObjectHolder) and old == value):
            return
        dt = self._dtypes[index] if index < len(self._dtypes) else None
        self._args[index] = _UNKNOWN_ARG  # as in FFTPlan.execute: safe from a Ctrl-C
        self._kernel.set_arg(index, value if dt is None else dt(value))
        self._args[index] = value

    def _check_array(self, a, name: str) -> None:
        if not isinstance(a, cl_array.Array):
            raise TypeError(f"{name} must be a pyopencl.array.Array (got {type(a).__name__})")
        if a.dtype != self.dtype:
            raise TypeError(f"{name}.dtype is {a.dtype}, the plan's is {self.dtype}")
        if tuple(a.shape) != self.geometry.array_shape:
            raise ValueError(f"{name}.shape is {tuple(a.shape)}, the plan expects "
                             f"{self.geometry.array_shape}")
        if not a.flags.c_contiguous:
            raise ValueError(f"{name} must be C-contiguous")
        if a.context != self.context:
            raise ValueError(f"{name} lives in another OpenCL context than the plan's queue")

    def execute(self, x: "cl_array.Array", *, out: Optional["cl_array.Array"] = None,
                multiply: Optional["cl_array.Array"] = None, multiply_even: bool = False,
                mid_args: Sequence = (), wait_for=None) -> "cl_array.Array":
        """Enqueue the round trip of every line of ``x``; returns ``out`` without waiting.

        Parameters
        ----------
        x : pyopencl.array.Array, shape ``geometry.array_shape`` (``shape`` with the last axis
            ``pitch``), the plan's dtype
        out : pyopencl.array.Array, optional
            The same shape; may be ``x`` (in place). Allocated when absent.
        multiply : pyopencl.array.Array, optional
            Factor between the transforms, the plan's dtype, shape ``frame`` or
            ``(M,) + frame`` with ``frame = geometry.mul_frame`` (``(n, lines)`` for columns,
            ``(lines, n)`` for rows: a 2D transfer function ``[Hp, Wp]`` for columns of an
            ``[..., H, Wp]`` array); batch element ``b`` uses ``multiply[b % M]``. Or
            :class:`EvenFactors` from this plan's :meth:`even_factors` (even frames, the
            fastest read on CPUs; ``multiply_even`` is then implied).
        multiply_even : bool
            The caller's word that every frame of ``multiply`` is even in both its indices,
            ``f[l, k] == f[(lines - l) % lines, (n - k) % n]`` (line ``l``, element ``k``), as
            the ASM transfer functions of :func:`clholo.propagation.build_transfer_function`
            are (they depend on ``fx^2`` and ``fy^2``). The kernel then reads only the
            frame's quarter ``l <= lines/2``, ``k <= n/2``: the same products, a quarter of
            the multiply's bytes (the column round trip of a 2048^2 grid waited on its 32 MB
            of ``H``). Not checked: a frame that is not even gives the mirror image of its
            quarter's values.
        mid_args : sequence
            Values of the mid callback's extra parameters (arrays are not waited for: give
            their events in ``wait_for``).
        wait_for : list of pyopencl.Event, optional

        Returns
        -------
        pyopencl.array.Array
            ``out``; its ``events`` hold the kernel's event.
        """
        if multiply_even is not True and multiply_even is not False:
            multiply_even = validate.flag(multiply_even, name="multiply_even")
        self._check_array(x, "x")
        if out is None:
            out = cl_array.Array(self.queue, self.geometry.array_shape, self.dtype)
        else:
            self._check_array(out, "out")
        if _overlap(out, x) and not _same_place(out, x):
            raise ValueError("out overlaps x: give out=x (in place) or an array that shares "
                             "no bytes with x")
        waits = list(wait_for or []) + list(x.events) + list(out.events)
        # EvenFactors hold their frames in .data; other_queue_markers skips non-arrays
        waits += other_queue_markers(self.queue, x, out, multiply,
                                     getattr(multiply, "data", None))
        # the arguments set and the kernel enqueued as one step (another thread's call of
        # this plan would reset them in between: see FFTPlan.execute)
        with runtime._launch_lock:
            ix, isz = _ARG_INDEX, self._itemsize
            self._set(ix["src"], x.base_data)
            self._set(ix["src_off"], x.offset // isz)
            self._set(ix["dst"], out.base_data)
            self._set(ix["dst_off"], out.offset // isz)
            if isinstance(multiply, EvenFactors):
                if multiply.key != self._even_key():
                    raise ValueError(
                        f"multiply is EvenFactors made for {multiply.key[:4]} (mul_frame, n, "
                        f"axis, lanes), this plan's are {self._even_key()[:4]}: make them with "
                        f"this plan's even_factors()")
                ef = multiply
                if ef.data.context != self.context:
                    raise ValueError("multiply (EvenFactors) lives in another OpenCL context "
                                     "than the plan's queue: make it with this plan's "
                                     "even_factors()")
                waits += list(ef.data.events)
                strips = ef.layout == "strips"
                frame = ef.data.size // ef.count  # elements of one frame as the kernel reads it
                for name, v in (("mul", ef.data.base_data), ("mul_off", ef.data.offset // isz),
                                ("mul_bs", frame), ("mul_m", ef.count),
                                ("mul_mode", 5 if strips else 4)):
                    self._set(ix[name], v)
            elif multiply is not None:
                if not isinstance(multiply, cl_array.Array):
                    raise TypeError("multiply must be a pyopencl.array.Array or EvenFactors")
                if multiply.dtype != self.dtype:
                    raise TypeError(f"multiply.dtype is {multiply.dtype}, the plan's is "
                                    f"{self.dtype}")
                fr, ms = tuple(self.geometry.mul_frame), tuple(multiply.shape)
                if ms == fr:
                    m = 1
                elif len(ms) == 3 and ms[1:] == fr and ms[0] >= 1:
                    m = ms[0]
                else:
                    raise ValueError(f"multiply.shape is {ms}; expected {fr} or (M,) + {fr}")
                if not multiply.flags.c_contiguous:
                    raise ValueError("multiply must be C-contiguous")
                if multiply.context != self.context:
                    raise ValueError("multiply lives in another OpenCL context than the "
                                     "plan's queue: copy it there, "
                                     "cla.to_device(plan.queue, multiply.get())")
                waits += list(multiply.events)
                for name, v in (("mul", multiply.base_data), ("mul_off", multiply.offset // isz),
                                ("mul_bs", fr[0] * fr[1]), ("mul_m", m),
                                ("mul_mode", 4 if multiply_even else 3)):
                    self._set(ix[name], v)
            else:
                if multiply_even:
                    raise ValueError("multiply_even=True needs a multiply")
                self._set(ix["mul_mode"], 0)
            if self.mid_callback is not None:
                values = self.mid_callback._values(mid_args, "mid_args", self._real)
                for i, v in enumerate(values):
                    self._set(self._nfixed + i, v)
            elif mid_args:
                raise ValueError("mid_args given but the plan has no mid_callback")
            evt = cl.enqueue_nd_range_kernel(self.queue, self._kernel, self._gsize,
                                             self._lsize, wait_for=waits or None)
            runtime.note_launch(self._kernel, self._gsize, self._lsize, evt,
                                label=self._label, bytes_moved=self._bytes_moved)
            _set_event(out, evt)
        return out


# ---------------------------------------------------------------------- functions
_PLAN_CACHE_SIZE = 16
_plans: "collections.OrderedDict[tuple, FFTPlan]" = collections.OrderedDict()
_plans_lock = threading.Lock()


def clear_plan_cache() -> None:
    """Forget the plans kept by :func:`fft2` & co."""
    with _plans_lock:
        _plans.clear()


def _forget_context(context: "cl.Context") -> None:
    """Drop the kept plans of ``context``'s queues (:func:`clholo.host.runtime.release_context`)."""
    with _plans_lock:
        for key in [k for k, plan in _plans.items() if plan.queue.context == context]:
            del _plans[key]


runtime.on_release_context(_forget_context)


def _plan_for(shape, dtype, queue, axes) -> FFTPlan:
    key = (tuple(shape), np.dtype(dtype).str, queue.int_ptr, axes)
    with _plans_lock:
        plan = _plans.get(key)
        if plan is not None:
            _plans.move_to_end(key)
            return plan
    plan = FFTPlan(shape, dtype, queue=queue, axes=axes)
    with _plans_lock:
        _plans[key] = plan
        while len(_plans) > _PLAN_CACHE_SIZE:
            _plans.popitem(last=False)
    return plan


def _run(a, out, queue, axes, inverse):
    queue = validate.queue(queue)
    if isinstance(a, cl_array.Array):
        _check_dtype(a.dtype)
        plan = _plan_for(a.shape, a.dtype, queue if queue is not None else a.queue, axes)
        return plan.execute(a, out=out, inverse=inverse)
    a = np.asarray(a)
    if a.dtype not in _COMPLEX:
        raise TypeError(f"input dtype is {a.dtype}; clholo.fft needs complex64 or complex128 "
                        f"(convert with .astype(np.complex64))")
    if not np.all(np.isfinite(a)):
        raise ValueError("the input contains NaN/inf values; every value must be finite")
    plan = _plan_for(a.shape, a.dtype, queue if queue is not None else runtime.get_queue(), axes)
    return plan.execute_host(a, out=out, inverse=inverse)


def fft2(a, *, out=None, queue=None):
    """2D forward FFT over the last two axes (NumPy's ``np.fft.fft2``, unnormalised).

    Parameters
    ----------
    a : np.ndarray or pyopencl.array.Array, shape ``(..., H, W)``, complex64/complex128
        H and W sizes ``2^a 3^b 5^c``; leading axes are a batch.
    out : same kind as ``a``, shape ``(..., H, W)``, optional
        Where to write; may be ``a`` (in place).
    queue : pyopencl.CommandQueue, optional
        Default: ``a.queue`` for device arrays, else :func:`clholo.host.runtime.get_queue`.

    Returns
    -------
    np.ndarray or pyopencl.array.Array, shape ``(..., H, W)``
    """
    return _run(a, out, queue, (-2, -1), False)


def ifft2(a, *, out=None, queue=None):
    """2D inverse FFT over the last two axes, with ``1/(H W)`` (``np.fft.ifft2``); see :func:`fft2`.

    Parameters
    ----------
    a : numpy.ndarray or pyopencl.array.Array, shape ``(..., H, W)``, complex64/complex128
        H and W sizes ``2^a 3^b 5^c``; leading axes are a batch.
    out : same kind as ``a``, optional
        Where to write; may be ``a`` (in place).
    queue : pyopencl.CommandQueue, optional
        Default: ``a.queue`` for device arrays, else :func:`clholo.host.runtime.get_queue`.

    Returns
    -------
    numpy.ndarray or pyopencl.array.Array, shape ``(..., H, W)``
    """
    return _run(a, out, queue, (-2, -1), True)


def fft(a, *, out=None, queue=None):
    """1D forward FFT over the last axis (``np.fft.fft``); shape ``(..., N)``; see :func:`fft2`.

    Parameters
    ----------
    a : numpy.ndarray or pyopencl.array.Array, shape ``(..., N)``, complex64/complex128
        N a size ``2^a 3^b 5^c``; leading axes are a batch.
    out : same kind as ``a``, optional
        Where to write; may be ``a`` (in place).
    queue : pyopencl.CommandQueue, optional
        Default: ``a.queue`` for device arrays, else :func:`clholo.host.runtime.get_queue`.

    Returns
    -------
    numpy.ndarray or pyopencl.array.Array, shape ``(..., N)``
    """
    return _run(a, out, queue, (-1,), False)


def ifft(a, *, out=None, queue=None):
    """1D inverse FFT over the last axis, with ``1/N`` (``np.fft.ifft``); see :func:`fft2`.

    Parameters
    ----------
    a : numpy.ndarray or pyopencl.array.Array, shape ``(..., N)``, complex64/complex128
        N a size ``2^a 3^b 5^c``; leading axes are a batch.
    out : same kind as ``a``, optional
        Where to write; may be ``a`` (in place).
    queue : pyopencl.CommandQueue, optional
        Default: ``a.queue`` for device arrays, else :func:`clholo.host.runtime.get_queue`.

    Returns
    -------
    numpy.ndarray or pyopencl.array.Array, shape ``(..., N)``
    """
    return _run(a, out, queue, (-1,), True)
