"""Host loop of SGD phase retrieval (HOLOGRAPHY.md section 8; kernels/encode.cl).

:class:`PhaseRetrieval` holds one batch of ``B`` fields (frames x colours, field ``b`` of colour
``b % C``) on the device and runs Adam iterations with no host round trip:

    forward       y <- crop(IFFT2(FFT2(pad(x)) * H(+z)))   (ASMPropagator: three passes)
    field_sums    per-field partial sums of conj(y) t, |y|^2, |t|^2 inside the ROI
                  (groups per field from the device's compute units: :func:`sum_plan`)
    fit_scale     adds them (one work-group per field): s_b = <y, t> / ||y||^2,
                  w_b = 1 / ||t||^2, loss L_b
    residual      y <- conj(s_b) w_b m (s_b y - t)                 (in place)
    adjoint       g <- crop(IFFT2(FFT2(pad(y)) * H(-z)))           (same grid, same band limit)
    adam          grad = 2 Im(g conj(x)); Adam on P; x <- exp(i P)

With ``fuse="none"`` (CPUs' default where a round trip does not fit) every step above is a
pass of its own; with
``fuse="residual"`` the residual runs where the adjoint's first pass loads ``y``; with
``fuse="all"`` the gradient and Adam step also run where its last pass stores ``g``, which is
never written (:func:`default_fuse`; ``kernels/sgd_callbacks.h``).
The loss buffer ``[B]`` is read back only when the caller asks (every ``k`` iterations).

With ``fuse="round-trips"`` (every device's default where both axes fit a round trip) the
iteration is
four passes over the row spectrum ``S = FFT_rows(pad(x))`` ``[B, H, Wp]``, in place, and
``fit_scale`` (issue 23's two-kernel layer, applied to SGD)::

    columns       S <- IFFT_cols(FFT_cols(S) * H(+z))[:H]          (RoundTripPlan)
    rows          y = IFFT_rows(S)[:W]; the loss sums of y and t added up per part of the
                  lines (FFT_MID_CB_SUMS); S <- FFT_rows(pad(m y))
    fit_scale     adds the parts: s_b, w_b, L_b
    columns       S <- IFFT_cols(FFT_cols(S) * H(-z))[:H]
    rows          u = IFFT_rows(S)[:W] = A^H(m y);
                  g = |s|^2 w u - conj(s) w A^H(m t);  grad = 2 Im(g conj(x));  Adam on P;
                  S <- FFT_rows(pad(exp(i P)))                      (the next iteration's)

The residual is linear in ``y`` once ``s`` is known, and ``A^H(m t)`` (``target_adjoint``) is
the same every iteration: propagated once at construction. So the adjoint carries ``m y``,
which needs no scale, and the sums fall inside the forward's row round trip (``y`` is never
written). Per pixel of the field (Hp, Wp about 1.1 H, W) that is about 114 bytes moved an
iteration against 162 for ``"all"``, in five launches instead of eight. In float32 the
difference of the two terms carries about 1.7 times the rounding of the propagated residual
(the same absolute error at every distance from convergence, since ``y`` itself carries the
FFT's rounding; measured in ``tests/test_encode.py``), well inside the gradient's tolerance.

DPAC's largest ``|u|`` per field (:func:`field_max_abs`) is split over the device the same way
as the loss sums (``field_max_abs2`` then ``field_max_abs``, one :class:`SumPlan`).

Device memory (complex64, bytes): ``8 B Hp Wp`` spectrum + FFT work (up to the same again),
``8 B H W`` each for x, y, target (``"round-trips"``: y, target, ``A^H(m t)``), ``4 B H W``
each for P, Adam m, Adam v, gradient, and the transfer functions ``2 x 8 C Hp Wp``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Sequence, Tuple

import numpy as np
import pyopencl as cl
import pyopencl.array as cla

from clholo.host import runtime

#: Work-group size of the two-stage per-field reductions (``field_sums`` / ``fit_scale``,
#: ``field_max_abs2`` / ``field_max_abs``) on CPUs (measured on PoCL).
SUM_LOCAL = 64

# field_sums on GPUs (issue 23: on an H100, 64 groups of 64 took 446 us of a 2.3 ms SGD step at
# 2048^2, most of its 132 SMs idle). 256 work-items a group and 8 groups per compute unit are
# 2048 resident work-items per unit, what an H100's SM holds, so every unit keeps loads in
# flight; each work-item still reads at least one quad (4 pixels) of a field.
_GPU_SUMS_LOCAL = 256
_GPU_GROUPS_PER_CU = 8
_GPU_MIN_PIXELS = 4
# CPUs: the rule measured on PoCL before issue 23: at most 64 groups, >= 32 pixels per work-item
_CPU_MAX_GROUPS = 64
_CPU_MIN_PIXELS = 32


@dataclass(frozen=True)
class SumPlan:
    """How ``field_sums`` and ``fit_scale`` (``kernels/encode.cl``) split one field's sums.

    ``field_sums`` runs ``groups`` work-groups of ``local`` work-items per field (global size
    ``(groups * local, B)``) and writes ``groups`` partial sums per field; ``fit_scale`` adds
    them on the device with one work-group of ``local`` work-items per field (global size
    ``(local, B)``). ``local`` is the kernels' ``reqd_work_group_size`` (built in, the define
    ``FIELD_SUMS_LOCAL``). The order of every addition is fixed by ``(local, groups, n)``, so
    a field gives the same sums run to run, and whatever other fields share its batch.
    ``field_max_abs2`` and ``field_max_abs`` (:func:`launch_max_abs`) split a field's largest
    ``|u|`` the same way."""

    local: int
    groups: int

    def __post_init__(self):
        local, groups = int(self.local), int(self.groups)
        if local < 1 or local & (local - 1) or groups < 1:
            raise ValueError(f"sums must have a power of two of work-items (local) and at least "
                             f"one group, e.g. SumPlan(64, 64); got {self}")


def sums_local(*, gpu: bool, max_work_group: int, max_items: int, local_mem_bytes: int) -> int:
    """Work-items per group of ``field_sums`` and ``fit_scale`` on a device (a power of two).

    Parameters
    ----------
    gpu : bool
        The device is not a CPU (a GPU or an accelerator).
    max_work_group, max_items : int
        ``CL_DEVICE_MAX_WORK_GROUP_SIZE`` and ``CL_DEVICE_MAX_WORK_ITEM_SIZES[0]``.
    local_mem_bytes : int
        ``CL_DEVICE_LOCAL_MEM_SIZE``: the group's scratch holds 16 bytes per work-item.

    Returns
    -------
    int
        64 on CPUs; on GPUs 256, or the largest power of two the device's limits allow.
    """
    want = _GPU_SUMS_LOCAL if gpu else SUM_LOCAL
    limit = min(want, int(max_work_group), int(max_items), max(1, int(local_mem_bytes) // 16))
    local = 1
    while local * 2 <= limit:
        local *= 2
    return local


def sum_groups(n: int, *, local: int = SUM_LOCAL, compute_units: int = 1,
               gpu: bool = False) -> int:
    """Work-groups per field of ``field_sums`` for fields of ``n`` pixels.

    ``field_sums`` reads pixels in quads (4 a work-item and step). CPUs: at most 64 groups,
    each work-item reading at least 8 quads (the rule measured on PoCL). GPUs:
    ``8 x compute_units`` (a full device for one field; a batch of several fields only adds
    groups, so a field's sums do not depend on its batch), each work-item reading at least one
    quad. Always at least 1; every group but a lone one has quads to read.
    """
    quads = max(0, int(n)) // 4
    if gpu:
        cap, per_item = _GPU_GROUPS_PER_CU * max(1, int(compute_units)), _GPU_MIN_PIXELS // 4
    else:
        cap, per_item = _CPU_MAX_GROUPS, _CPU_MIN_PIXELS // 4
    return int(max(1, min(cap, -(-quads // (int(local) * per_item)))))


def sum_plan(n: int, *, gpu: bool, compute_units: int, max_work_group: int, max_items: int,
             local_mem_bytes: int) -> SumPlan:
    """The :class:`SumPlan` of fields of ``n`` pixels on a device with these limits (a pure
    function: tests give it the limits of devices they do not have)."""
    local = sums_local(gpu=gpu, max_work_group=max_work_group, max_items=max_items,
                       local_mem_bytes=local_mem_bytes)
    return SumPlan(local, sum_groups(n, local=local, compute_units=compute_units, gpu=gpu))


def _device_limits(device: "cl.Device") -> dict:
    lim = runtime._limits_of_device(device)
    return dict(gpu=not bool(int(device.type) & cl.device_type.CPU),
                max_work_group=lim.max_work_group_size, max_items=lim.max_item_sizes[0],
                local_mem_bytes=lim.local_mem_bytes)


def device_sum_plan(device: "cl.Device", n: int) -> SumPlan:
    """:func:`sum_plan` for fields of ``n`` pixels on an OpenCL device."""
    return sum_plan(n, compute_units=int(device.max_compute_units), **_device_limits(device))


def device_sums_local(context: "cl.Context") -> int:
    """``FIELD_SUMS_LOCAL`` of the context's programs: the smallest of its devices'."""
    return min(sums_local(**_device_limits(d)) for d in context.devices)


def encode_kernel(context: "cl.Context", name: str, *,
                  sums_local: Optional[int] = None) -> "cl.Kernel":
    """A kernel of ``kernels/encode.cl`` in float32.

    ``sums_local`` (a power of two) is the work-group size ``field_sums``, ``fit_scale``,
    ``field_max_abs2`` and ``field_max_abs`` are built for; default :func:`device_sums_local`
    (tests and the self-test build other devices' sizes with it)."""
    local = device_sums_local(context) if sums_local is None else int(sums_local)
    return runtime.get_kernel(context, "encode.cl", name,
                              defines={"REAL": "float", "FIELD_SUMS_LOCAL": local})


def quads(n: int) -> int:
    """Work-items of ``phase_to_field`` (``kernels/encode.cl``) for ``n`` elements: four
    each, the last one the ragged end."""
    return max(1, (int(n) + 3) // 4)


def sixteens(n: int) -> int:
    """Work-items of ``phase_gradient_adam`` (``kernels/encode.cl``) for ``n`` elements:
    sixteen each, the last one the ragged end."""
    return max(1, (int(n) + 15) // 16)


def sums_lanes(device: "cl.Device") -> bool:
    """Whether the device adds the loss sums up with ``field_sums_lanes`` (CPUs: a work-group's
    work-items side by side in one work-item, the same bits as ``field_sums``)."""
    return not _device_limits(device)["gpu"]


def launch_sums(queue: "cl.CommandQueue", plan: SumPlan, y, t, mask, n: int, B: int, partial,
                scale, weight, loss, *, kernels=None, lanes: Optional[bool] = None) -> None:
    """Enqueue ``field_sums`` (or ``field_sums_lanes``) then ``fit_scale`` for ``B`` fields
    of ``n`` pixels.

    ``y, t`` complex64 ``[B, n]``, ``mask`` float32 ``[n]`` or None, ``partial`` float32
    ``[B, plan.groups, 4]``; writes ``scale`` complex64 ``[B]``, ``weight`` and ``loss``
    float32 ``[B]`` (buffers). ``kernels`` maps the names to kernels built with
    ``sums_local=plan.local`` (default: built here). ``lanes``: run ``field_sums_lanes``
    (one work-item per group of ``plan.local``, global size ``(plan.groups, B)``), the same
    bits; default :func:`sums_lanes` of the queue's device."""
    lanes = sums_lanes(queue.device) if lanes is None else bool(lanes)
    if lanes and plan.local < 4:
        raise ValueError(f"lanes=True runs field_sums_lanes, built for work-groups of at least "
                         f"4 work-items; plan.local is {plan.local}: use lanes=False")
    first = "field_sums_lanes" if lanes else "field_sums"
    k = kernels or {name: encode_kernel(queue.context, name, sums_local=plan.local)
                    for name in (first, "fit_scale")}
    L, G = plan.local, plan.groups
    runtime.launch(k[first], queue, (G, B) if lanes else (G * L, B), (1, 1) if lanes else (L, 1),
                   y, t, mask if mask is not None else weight, np.uint32(mask is not None),
                   np.uint32(n), partial)
    runtime.launch(k["fit_scale"], queue, (L, B), (L, 1), partial, np.uint32(G), scale,
                   weight, loss)


def launch_max_abs(queue: "cl.CommandQueue", plan: SumPlan, u, n: int, B: int, partial, out, *,
                   kernels=None) -> None:
    """Enqueue ``field_max_abs2`` then ``field_max_abs``: the largest ``|u|`` of each field.

    Parameters
    ----------
    queue : pyopencl.CommandQueue
        Queue to enqueue on.
    plan : SumPlan
        The split: ``plan.groups`` work-groups of ``plan.local`` per field, then one
        work-group per field on the partials.
    u : pyopencl.Buffer
        complex64 ``[B, n]``.
    n, B : int
        Pixels per field and fields.
    partial : pyopencl.Buffer
        float32 ``[B, plan.groups]``: each group's largest ``|u|^2``.
    out : pyopencl.Buffer
        float32 ``[B]``: written with ``sqrt(max |u|^2)`` per field.
    kernels : mapping, optional
        Both names to kernels built with ``sums_local=plan.local`` (default: built here).

    Notes
    -----
    A maximum is exact in any order: the result is the same bits for every split, namely
    ``sqrt`` (once) of the largest ``|u|^2`` as the device's ``cabs2`` rounds it, which is what
    ``dpac_encode`` computes per pixel. NaN pixels are skipped (``fmax``), as before the split;
    a field of NaNs gives 0.
    """
    k = kernels or {name: encode_kernel(queue.context, name, sums_local=plan.local)
                    for name in ("field_max_abs2", "field_max_abs")}
    L, G = plan.local, plan.groups
    runtime.launch(k["field_max_abs2"], queue, (G * L, B), (L, 1), u, np.uint32(n), partial)
    runtime.launch(k["field_max_abs"], queue, (L, B), (L, 1), partial, np.uint32(G), out)


def field_max_abs(field: "cla.Array", *, plan: Optional[SumPlan] = None,
                  queue: Optional["cl.CommandQueue"] = None, allocator=None) -> "cla.Array":
    """The largest ``|u|`` of each field of a batch, on the device (:func:`launch_max_abs`).

    Parameters
    ----------
    field : pyopencl.array.Array
        complex64 ``[B, ...]``: field ``b`` is ``field[b]`` (contiguous).
    plan : SumPlan, optional
        The split (default :func:`device_sum_plan` of the queue's device for the field's size;
        tests and the self-test give a GPU's).
    queue : pyopencl.CommandQueue, optional
        Default: the array's queue.
    allocator : callable, optional
        Where the partial maxima and the result come from (e.g. a
        ``pyopencl.tools.MemoryPool``); default: new buffers.

    Returns
    -------
    pyopencl.array.Array
        float32 ``[B]``, enqueued (nothing is read back).
    """
    queue = queue or field.queue
    if field.dtype != np.complex64 or field.ndim < 1 or not field.flags.c_contiguous:
        raise ValueError(f"field_max_abs takes a contiguous complex64 array [B, ...], got "
                         f"{field.dtype} {field.shape}")
    B = int(field.shape[0])
    n = int(np.prod(field.shape[1:], dtype=np.int64))
    plan = plan if plan is not None else device_sum_plan(queue.device, n)
    partial = cla.empty(queue, (B, plan.groups), np.float32, allocator=allocator)
    out = cla.empty(queue, (B,), np.float32, allocator=allocator)
    launch_max_abs(queue, plan, field.data, n, B, partial.data, out.data)
    return out


def _sgd_callbacks():
    """The residual (load) and Adam (store) callbacks of the fused iteration
    (``kernels/sgd_callbacks.h``)."""
    from clholo.fft import FFTCallback

    load = FFTCallback('#define SGD_RESIDUAL_LOAD 1\n#include "sgd_callbacks.h"\n',
                       params=["__global const real2 *", "__global const real *", "uint",
                               "__global const real2 *", "__global const real *", "uint",
                               "uint"])
    store = FFTCallback('#define SGD_ADAM_STORE 1\n#include "sgd_callbacks.h"\n',
                        params=["__global real2 *"] + ["__global real *"] * 4 + ["real"] * 8
                        + ["uint", "uint"])
    return load, store


SGD_RESIDUAL_LOAD, SGD_ADAM_STORE = _sgd_callbacks()


def _round_trip_callbacks():
    """The mid steps of the four-pass iteration's two row round trips and the masked target's
    load (``kernels/sgd_callbacks.h``)."""
    from clholo.fft import FFTCallback

    forward = FFTCallback('#define SGD_FORWARD_MID 1\n#include "sgd_callbacks.h"\n',
                          params=["__global const real2 *", "__global const real *", "uint",
                                  "__global real4 *", "uint", "uint", "uint"])
    adam = FFTCallback('#define SGD_ADAM_MID 1\n#include "sgd_callbacks.h"\n',
                       params=["__global const real2 *"] + ["__global real *"] * 4
                       + ["__global const real2 *", "__global const real *"] + ["real"] * 8
                       + ["uint", "uint"])
    mask = FFTCallback('#define SGD_MASK_LOAD 1\n#include "sgd_callbacks.h"\n',
                       params=["__global const real *", "uint", "uint"])
    return forward, adam, mask


SGD_FORWARD_MID, SGD_ADAM_MID, SGD_MASK_LOAD = _round_trip_callbacks()


#: What :class:`PhaseRetrieval` can fuse: nothing, the residual into the adjoint's first pass,
#: also the Adam step into its last, or the whole iteration in four round trips.
FUSE_MODES = ("none", "residual", "all", "round-trips")


def round_trips_fit(batch: int, shape: Tuple[int, int], padded: Tuple[int, int],
                    device: "cl.Device", *, variant: str = "auto") -> bool:
    """Whether ``fuse="round-trips"`` can run on ``device``: its columns (``Hp`` points) and
    its rows (``Wp`` points) both fit a round trip in fast memory
    (:func:`clholo.fft.round_trip_fits`)."""
    from clholo.fft import DeviceLimits, round_trip_fits

    limits = DeviceLimits.of(device)
    (H, W), (Hp, Wp) = shape, padded
    rows = (int(batch), int(H), int(Wp))
    return (round_trip_fits(rows, Hp, np.complex64, device=limits, axis="cols", variant=variant)
            and round_trip_fits(rows, Wp, np.complex64, device=limits, axis="rows",
                                variant=variant))


def default_fuse(device: "cl.Device") -> str:
    """What :class:`PhaseRetrieval` fuses on ``device`` (``fuse=None``): ``"round-trips"``
    (where a grid's lines do not fit a round trip, :func:`round_trips_fit`: ``"all"`` on GPUs
    and accelerators, ``"none"`` on CPUs).

    Fusing moves less memory and launches fewer kernels per iteration: ``"round-trips"`` moves
    about 0.7 times the bytes of ``"all"`` in five launches instead of eight (module
    docstring). On CPUs it won once its row round trips' mid steps ran eight rows by eight
    columns with their rows prefetched (``clholo_mid_acc_rows8``, ``SGD_PF``): on PoCL
    (2-core Zen 5 EPYC, the forms side by side in rotated order) 7.32 ms an iteration against
    8.37 for ``"none"``, 8.17 ``"residual"``, 9.97 ``"all"`` at 1024^2 (grid 1200^2), 14.3
    against 15.5 on a 2048^2 grid and 33.7 against 38.5 at 2048^2 (grid 2250^2); a tie at
    512^2 (docs/benchmarks.md, 2026-11-27, eleventh session)."""
    return "round-trips"


def _fallback_fuse(device: "cl.Device", variant: str = "auto") -> str:
    """The default form where ``"round-trips"`` does not fit: ``"none"`` with the CPU FFT
    kernels (``variant``, or a CPU device's ``"auto"``), ``"all"`` with the GPU ones."""
    cpu = variant == "cpu" or (variant == "auto" and int(device.type) & cl.device_type.CPU)
    return "none" if cpu else "all"


class PhaseRetrieval:
    """SGD with Adam for phase-only patterns of one batch of fields, all on the device.

    Parameters
    ----------
    target : pyopencl.array.Array, complex64 ``[B, H, W]``
        Complex target at the hologram plane (``z`` in front of the SLM).
    wavelengths : sequence of C floats, metres
        Field ``b`` uses ``wavelengths[b % C]``.
    pitch, z : float
        Metres; ``z > 0`` propagates the SLM field forward to the target.
    padded : (int, int)
        Power-of-two grid of both propagations.
    mask : pyopencl.array.Array float32 ``[H, W]``, optional
        Region of interest (0/1, or weights) of the loss.
    lr, beta1, beta2, eps : float
        Adam (PyTorch's form).
    sums : SumPlan, optional
        How the loss sums are split (default :func:`device_sum_plan` of the queue's device;
        benchmarks and tests give others).
    fuse : {"none", "residual", "all", "round-trips"}, optional
        Run the residual (``"residual"``), or the residual and the Adam step (``"all"``),
        inside the adjoint propagation's first and last passes (callbacks of
        :class:`clholo.propagation.ASMPropagator`: ``SGD_RESIDUAL_LOAD``, ``SGD_ADAM_STORE``)
        instead of as kernels of their own: a launch and a field's write and read-back fewer
        per step fused, the same arithmetic. ``"round-trips"``: the whole iteration in two
        column and two row round trips (module docstring; the gradient's arithmetic is
        rearranged, equal within ``tests/tolerances.py``), where both axes fit a round trip
        (:func:`round_trips_fit`). Default :func:`default_fuse` of the device.
    three_pass : bool, optional
        The propagations' form (:class:`clholo.propagation.ASMPropagator`); default: three
        passes where the columns fit the device's fast memory. ``"round-trips"`` needs them.
    variant : {"auto", "cpu", "gpu"}
        The FFT kernels' family (:class:`clholo.fft.FFTPlan`); tests run the GPU kernels on a
        CPU device with ``"gpu"``.

    Attributes
    ----------
    phase, adam_m, adam_v, grad : pyopencl.array.Array float32 ``[B, H, W]``
        The phase, Adam's moments and the last step's gradient.
    x : pyopencl.array.Array complex64 ``[B, H, W]`` or None
        ``exp(i P)`` of the phase; None with ``fuse="round-trips"``, which keeps its row
        spectrum instead (``spectrum``, ``[B, H, Wp]`` in rows ``propagator.row_pitch`` apart).
    y : pyopencl.array.Array complex64 ``[B, H, W]``
        The forward field of the phase before the last step (scratch with ``"all"`` and
        ``"round-trips"``; :meth:`evaluate` leaves the current phase's there).
    scale, weight, loss : pyopencl.array.Array ``[B]``
        ``s_b``, ``1 / sum w |t|^2`` and ``L_b`` of the phase before the last step.
    """

    def __init__(self, target: "cla.Array", *, wavelengths: Sequence[float], pitch: float,
                 z: float, padded: Tuple[int, int], mask: Optional["cla.Array"] = None,
                 lr: float = 0.05, beta1: float = 0.9, beta2: float = 0.999, eps: float = 1e-8,
                 band_limit: bool = True, queue: Optional["cl.CommandQueue"] = None,
                 sums: Optional[SumPlan] = None, fuse: Optional[str] = None,
                 three_pass: Optional[bool] = None, variant: str = "auto"):
        from clholo.fft import RoundTripPlan
        from clholo.propagation import ASMPropagator, transfer_function_cache

        self.queue = queue or target.queue
        q = self.queue
        B, H, W = target.shape
        self.B, self.shape, self.n = B, (H, W), H * W
        self.target = target
        self.mask = mask
        cache = transfer_function_cache(q.context)
        self.tf_forward = cache.get(q, padded, z, wavelengths=wavelengths, pitch=pitch,
                                    band_limit=band_limit)
        self.tf_adjoint = cache.get(q, padded, -z, wavelengths=wavelengths, pitch=pitch,
                                    band_limit=band_limit)
        self.fuse = default_fuse(q.device) if fuse is None else fuse
        if self.fuse not in FUSE_MODES:
            raise ValueError(f"fuse must be one of {', '.join(map(repr, FUSE_MODES))} (what "
                             f"runs inside the propagations' passes), or None for the device's "
                             f"default; got {fuse!r}")
        if self.fuse == "round-trips":
            fits = three_pass is not False and round_trips_fit(B, (H, W), padded, q.device,
                                                               variant=variant)
            if not fits and fuse is None:
                # the default falls back where the lines are too long
                self.fuse = _fallback_fuse(q.device, variant)
            elif not fits:
                raise ValueError(
                    f"fuse='round-trips' needs the {padded[0]}-point columns and the "
                    f"{padded[1]}-point rows of the grid {tuple(padded)} to fit a round trip in "
                    f"the device's fast memory" + (" and three_pass not False"
                                                   if three_pass is False else "")
                    + "; use fuse='all' (or leave fuse unset)")
        callbacks = {}
        if self.fuse in ("residual", "all"):
            callbacks["load_callback"] = SGD_RESIDUAL_LOAD
        if self.fuse == "all":
            callbacks["store_callback"] = SGD_ADAM_STORE
        if self.fuse == "round-trips":
            three_pass = True
            if mask is not None:
                callbacks["load_callback"] = SGD_MASK_LOAD
        self.propagator = ASMPropagator(B, (H, W), padded, queue=q, three_pass=three_pass,
                                        variant=variant, **callbacks)
        self._even = {}  # _even_tf's: (propagator, EvenFactors) per transfer function
        self.lr, self.beta1, self.beta2, self.eps = lr, beta1, beta2, eps
        self.y = cla.empty(q, (B, H, W), np.complex64)
        self.x = None
        if self.fuse == "round-trips":
            rows, pitch = (B, H, int(padded[1])), self.propagator.row_pitch
            self._rows_forward = RoundTripPlan(rows, rows[2], axis="rows", first="inverse",
                                               mid_n=W, mid_callback=SGD_FORWARD_MID, queue=q,
                                               variant=variant, pitch=pitch)
            self._rows_adam = RoundTripPlan(rows, rows[2], axis="rows", first="inverse",
                                            mid_n=W, mid_callback=SGD_ADAM_MID, queue=q,
                                            variant=variant, pitch=pitch)
            self.spectrum = self.propagator.row_spectrum
            # A^H(m t): the part of the gradient field that every iteration shares
            self.target_adjoint = cla.empty(q, (B, H, W), np.complex64)
            self.propagator.apply(target, self.tf_adjoint, out=self.target_adjoint,
                                  load_args=None if mask is None else
                                  [mask, np.uint32(1), np.uint32(W)], tf_even=True)
        else:
            self.x = cla.empty(q, (B, H, W), np.complex64)
        self.phase = cla.empty(q, (B, H, W), np.float32)
        self.adam_m = runtime.zeros(q, (B, H, W), np.float32)
        self.adam_v = runtime.zeros(q, (B, H, W), np.float32)
        self.grad = runtime.zeros(q, (B, H, W), np.float32)
        self.sums = sums if sums is not None else device_sum_plan(q.device, self.n)
        self.groups = self.sums.groups
        self.partial = cla.empty(q, (B, self.groups, 4), np.float32)
        self.scale = cla.empty(q, (B,), np.complex64)
        self.weight = cla.empty(q, (B,), np.float32)
        self.loss = cla.empty(q, (B,), np.float32)
        self._mask_arg = (mask.data if mask is not None else self.weight.data)  # unread if none
        self._k = {name: encode_kernel(q.context, name, sums_local=self.sums.local) for name in
                   ("phase_to_field", "field_sums", "fit_scale", "scaled_residual",
                    "phase_gradient_adam")}
        self._preset_launches()
        if self.fuse == "round-trips":
            # the forward's row round trip adds the loss sums up, one partial per part of its
            # lines; fit_scale adds those
            parts = self._rows_forward.mid_parts
            self._rt_partial = cla.empty(q, (B, parts, 4), np.float32)
            L = self.sums.local
            knl = cl.Kernel(runtime.build_program(q.context, "encode.cl", defines={
                "REAL": "float", "FIELD_SUMS_LOCAL": L}), "fit_scale")
            runtime.set_launch_args(q, knl, (L, B), (L, 1), [
                self._rt_partial.data, np.uint32(parts), self.scale.data, self.weight.data,
                self.loss.data])
            self._own["fit_scale_round_trips"] = (knl, (L, B), (L, 1))
            self._forward_mid_args = [self.target, self._mask_arg,
                                      np.uint32(self.mask is not None), self._rt_partial,
                                      np.uint32(parts), np.uint32(H), np.uint32(W)]
        self.step_count = 0

    def _preset_launches(self) -> None:
        """Kernel objects of this engine's own with every argument that does not change set
        once (issue 23: pyopencl's call sets all fifteen of the Adam kernel's arguments, about
        140 us of host time a step on PoCL; a step now resets only Adam's scalars). Kernels
        from :func:`encode_kernel` are shared by every engine of a context, so each engine
        makes its own objects of the same programs."""
        q, n, B = self.queue, self.n, self.B
        L, G = self.sums.local, self.sums.groups
        has_mask = np.uint32(self.mask is not None)

        program = runtime.build_program(q.context, "encode.cl",
                                        defines={"REAL": "float", "FIELD_SUMS_LOCAL": L})

        def own(name, gsize, lsize, args):
            knl = cl.Kernel(program, name)
            runtime.set_launch_args(q, knl, gsize, lsize, args)
            return knl, gsize, lsize

        self._own = {
            # (field_sums_lanes on CPUs: launch_sums)
            "field_sums": own(*(("field_sums_lanes", (G, B), (1, 1)) if sums_lanes(q.device)
                                else ("field_sums", (G * L, B), (L, 1))),
                              [self.y.data, self.target.data, self._mask_arg, has_mask,
                               np.uint32(n), self.partial.data]),
            "fit_scale": own("fit_scale", (L, B), (L, 1),
                             [self.partial.data, np.uint32(G), self.scale.data,
                              self.weight.data, self.loss.data]),
            "scaled_residual": own("scaled_residual", (-(-n // 8), B), None,
                                   [self.y.data, self.target.data, self._mask_arg, has_mask,
                                    self.scale.data, self.weight.data, np.uint32(n)]),
        }
        if self.x is not None:  # (fuse="round-trips" runs Adam inside a row round trip)
            # Adam's scalars (indices 6-13) are set at every step: the step count changes
            # the bias corrections, and lr, betas and eps are attributes a caller may change
            self._own["phase_gradient_adam"] = own(
                "phase_gradient_adam", (sixteens(self.phase.size),), None,
                [self.y.data, self.x.data, self.phase.data, self.adam_m.data,
                 self.adam_v.data, self.grad.data] + [np.float32(0)] * 8
                + [np.uint32(self.phase.size)])

    def _even_tf(self, tf: "cla.Array") -> "EvenFactors":
        """``tf`` as the propagator's passes read it fastest (:meth:`ASMPropagator.even_factors`:
        on CPUs laid out strip by strip for the column round trips), made once per
        propagator (a caller may replace ``self.propagator``)."""
        hit = self._even.get(id(tf))  # tf_forward and tf_adjoint live as long as self
        if hit is None or hit[0] is not self.propagator:
            hit = self._even[id(tf)] = (self.propagator, self.propagator.even_factors(tf))
        return hit[1]

    def _tf_forward(self) -> "EvenFactors":
        return self._even_tf(self.tf_forward)

    def _tf_adjoint(self) -> "EvenFactors":
        return self._even_tf(self.tf_adjoint)

    def _enqueue(self, name: str) -> None:
        knl, gsize, lsize = self._own[name]
        runtime.enqueue_nd_range(self.queue, knl, gsize, lsize)

    def _adam_scalars(self, t: int) -> list:
        """lr, b1, b2, 1 - b1, 1 - b2, eps, and the bias corrections of step ``t`` (1 - b1 and
        1 - b2 formed in double, then rounded)."""
        b1, b2 = self.beta1, self.beta2
        return [self.lr, b1, b2, 1.0 - b1, 1.0 - b2, self.eps, 1.0 - b1 ** t, 1.0 - b2 ** t]

    def set_phase(self, phase: "cla.Array") -> None:
        """Start from ``phase [B, H, W]`` (copied; the caller's array is not written); resets
        Adam.

        Parameters
        ----------
        phase : pyopencl.array.Array float32 or numpy.ndarray (real), ``[B, H, W]``
            Radians. A device array may be a view (e.g. ``phases[2:4]``) of this context.

        Raises
        ------
        TypeError, ValueError
            Not a real array of the engine's shape (a shorter one would leave the rest of the
            phase as it was), a device array of another dtype or context.
        """
        want = (self.B,) + tuple(self.shape)
        if isinstance(phase, cla.Array):
            if phase.dtype != np.float32 or tuple(phase.shape) != want:
                raise ValueError(f"phase must be float32 {want} (radians), got {phase.dtype} "
                                 f"{tuple(phase.shape)}")
            if not phase.flags.c_contiguous:
                raise ValueError("phase must be a C-contiguous device array")
            if phase.context != self.queue.context:
                raise ValueError("phase is a device array of another OpenCL context than the "
                                 "engine's queue: give its values as NumPy (phase.get())")
            from clholo._arrays import other_queue_markers

            waits = list(phase.events) + other_queue_markers(self.queue, phase)
            cl.enqueue_copy(self.queue, self.phase.data, phase.base_data,
                            src_offset=phase.offset, byte_count=phase.nbytes,
                            wait_for=waits or None)
        else:
            arr = np.asarray(phase)
            if arr.dtype.kind not in "fiu" or arr.shape != want:
                raise ValueError(f"phase must be real radians of shape {want}, got "
                                 f"{arr.dtype} {arr.shape}")
            self.phase.set(np.ascontiguousarray(arr, np.float32))
        with runtime.pyopencl_op():  # pyopencl's shared fill kernel: see pyopencl_op
            self.adam_m.fill(0)
            self.adam_v.fill(0)
        self.step_count = 0
        self._phase_to_x()

    def _phase_to_x(self) -> None:
        """``x = exp(i P)`` of the phase; with ``fuse="round-trips"`` its row spectrum (``y``
        holds ``x`` on the way)."""
        x = self.y if self.x is None else self.x
        runtime.launch(self._k["phase_to_field"], self.queue, (quads(self.phase.size),), None,
                       self.phase.data, x.data, np.uint32(self.phase.size))
        if self.x is None:
            self.propagator.row_forward.execute(x, out=self.spectrum)

    def _forward_and_fit(self) -> None:
        """The forward propagation, then ``field_sums`` and ``fit_scale`` (as
        :func:`launch_sums` enqueues them, on this engine's own kernel objects)."""
        if self.x is None:
            # from the row spectrum, which the column round trip overwrites: made again after
            p = self.propagator
            p.columns.execute(self.spectrum, out=self.spectrum, multiply=self._tf_forward())
            p.row_inverse.execute(self.spectrum, out=self.y, inverse=True)
            self._enqueue("field_sums")
            self._enqueue("fit_scale")
            self._phase_to_x()
            return
        self.propagator.apply(self.x, self._tf_forward(), out=self.y)
        self._enqueue("field_sums")
        self._enqueue("fit_scale")

    def gradient(self) -> None:
        """Forward, loss and the residual propagated back: leaves ``g`` in ``self.y`` (not
        with ``fuse="round-trips"``, which never forms ``g``)."""
        if self.x is None:
            raise ValueError("gradient() leaves g in y, which fuse='round-trips' never forms; "
                             "build the engine with fuse='none' for it")
        self._forward_and_fit()
        self._enqueue("scaled_residual")
        self.propagator.apply(self.y, self._tf_adjoint(), out=self.y)

    def step(self) -> None:
        """One iteration; afterwards ``self.loss`` holds the loss of the phase *before* it and
        ``self.grad`` that phase's gradient (``self.y`` is scratch: with ``fuse="all"`` the
        propagated residual is never written; :meth:`gradient` leaves it there)."""
        self.step_count += 1
        H, W = self.shape
        adam = self._adam_scalars(self.step_count)
        if self.fuse == "round-trips":
            self._round_trips_step(adam)
            return
        if self.fuse == "none":
            self.gradient()
        else:
            self._forward_and_fit()
        load_args = [self.target, self._mask_arg, np.uint32(self.mask is not None), self.scale,
                     self.weight, np.uint32(H), np.uint32(W)]
        if self.fuse == "all":
            self.propagator.apply(
                self.y, self._tf_adjoint(), out=self.y, load_args=load_args,
                store_args=[self.x, self.phase, self.adam_m, self.adam_v, self.grad] + adam
                + [np.uint32(H), np.uint32(W)])
            return
        if self.fuse == "residual":
            self.propagator.apply(self.y, self._tf_adjoint(), out=self.y, load_args=load_args)
        knl = self._own["phase_gradient_adam"][0]
        for i, value in enumerate(adam):
            knl.set_arg(6 + i, np.float32(value))
        self._enqueue("phase_gradient_adam")

    def _round_trips_step(self, adam: list) -> None:
        """The iteration in four passes over the row spectrum ``S`` of ``x`` (module
        docstring), all in place: the forward's column round trip, the row round trip that
        adds up the loss sums and passes ``m y`` on, ``fit_scale``, the adjoint's column round
        trip and the row round trip with the gradient and the Adam step, which leaves the next
        iteration's ``S``."""
        H, W = self.shape
        S, cols = self.spectrum, self.propagator.columns
        cols.execute(S, out=S, multiply=self._tf_forward())
        self._rows_forward.execute(S, out=S, mid_args=self._forward_mid_args)
        self._enqueue("fit_scale_round_trips")
        cols.execute(S, out=S, multiply=self._tf_adjoint())
        self._rows_adam.execute(S, out=S, mid_args=[
            self.target_adjoint, self.phase, self.adam_m, self.adam_v, self.grad, self.scale,
            self.weight] + adam + [np.uint32(H), np.uint32(W)])

    def evaluate(self) -> np.ndarray:
        """Loss ``[B]`` of the current phase (forward and fit only), read back."""
        self._forward_and_fit()
        return self.loss.get()

    def run(self, iterations: int, *, check_every: int = 10, tol: float = 0.0,
            progress=None) -> Tuple[list, int]:
        """Up to ``iterations`` steps; every ``check_every`` steps the mean loss is read back
        (the only host synchronisation), shown on ``progress`` (a tqdm bar) and compared with
        the previous reading: a relative decrease below ``tol`` stops the run.

        Returns ``(history, steps)``: ``history`` is a list of ``(step, loss [B])`` with the
        loss of the phase after ``step - 1`` updates."""
        history = []
        previous = None
        done = 0
        for i in range(iterations):
            self.step()
            done += 1
            if (i + 1) % check_every == 0 or i + 1 == iterations:
                loss = self.loss.get()
                history.append((self.step_count, loss))
                mean = float(np.mean(loss))
                if progress is not None:
                    progress.update(done - progress.n)
                    progress.set_postfix(loss=f"{mean:.4g}")
                if previous is not None and tol > 0 and previous - mean < tol * previous:
                    break
                previous = mean
        return history, done
