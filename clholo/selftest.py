"""``clholo selftest``: does clholo work on this OpenCL device?

Every kernel family runs at small, odd, non-square sizes on the chosen device and is compared
with its NumPy reference (:mod:`clholo.reference`) under the tolerances of
:mod:`clholo.tolerances` (the test suite's own table): both FFT kernel variants and the
global-memory stages with every radix (2, 3, 4, 5, 8), in both precisions where the device has
fp64, with load and store callbacks; ASM propagation; random phases (bit for bit); the
elementwise kernels; compositing, alone, fused into the inverse transform's store and between
the row round trip's transforms; the whole MPI hologram (two and four passes per layer); pupil
views and the light field; ray optics; the phase-only encodings (SGD gradient and Adam, DPAC);
8-bit quantisation through lookup tables (bit for bit); random-phase wave splatting; splat
rasterisation. The report also
holds the device's name, vendor, driver and OpenCL versions, its limits and extensions, which
kernels ran, and one speed line.

The same checks run in CI on PoCL and under the Oclgrind simulator
(:mod:`clholo.oclgrind`), which reports out-of-bounds accesses, data races and barrier
divergence that a CPU driver hides. ``docs/selftest.md`` explains how to send the JSON with a
bug report.

Python::

    from clholo.selftest import run_selftest
    report = run_selftest(quick=True)
    print(report.format_text()); report.passed

Command line: ``clholo selftest [--quick] [--json FILE]`` (exit status 1 on any failure).
"""

from __future__ import annotations

import math
import os
import platform
import time
import traceback
from dataclasses import asdict, dataclass, field
from typing import Callable, Dict, List, Optional

import numpy as np

__all__ = ["CheckResult", "SelfTestReport", "run_selftest", "FAMILIES"]


@dataclass
class CheckResult:
    """One comparison: ``error`` of ``metric`` against ``tolerance`` (pass: error <= tolerance)."""

    family: str
    name: str
    metric: str
    error: float
    tolerance: float
    passed: bool
    seconds: float = 0.0
    message: str = ""


@dataclass
class SelfTestReport:
    """What :func:`run_selftest` found: device facts, one :class:`CheckResult` per comparison,
    the kernels that ran and a speed line."""

    device: Dict[str, object]
    checks: List[CheckResult]
    kernels_launched: List[str]
    speed: Dict[str, object]
    quick: bool
    versions: Dict[str, str] = field(default_factory=dict)
    seconds: float = 0.0
    #: where the time went: ``build_seconds`` (OpenCL program builds, counted apart: on a GPU
    #: most of a first run), ``check_seconds`` (the checks without the builds made during
    #: them), ``speed_seconds``, ``programs_built``, ``compiler_cache`` (see
    #: :class:`clholo.host.runtime.BuildCounter`)
    timing: Dict[str, object] = field(default_factory=dict)
    #: GPU vendors' OpenCL libraries found when the device is not a GPU (:mod:`clholo.host.drivers`):
    #: ``libraries`` and ``advice`` (the exact fix, '' when none is needed)
    drivers: Dict[str, object] = field(default_factory=dict)

    @property
    def passed(self) -> bool:
        """True when every check passed (and there was at least one)."""
        return bool(self.checks) and all(c.passed for c in self.checks)

    @property
    def failed_families(self) -> List[str]:
        return sorted({c.family for c in self.checks if not c.passed})

    def to_dict(self) -> dict:
        """Plain JSON-able dict (what ``--json`` writes)."""
        return {
            "clholo_selftest": 1,
            "passed": self.passed,
            "failed_families": self.failed_families,
            "quick": self.quick,
            "seconds": round(self.seconds, 3),
            "versions": dict(self.versions),
            "device": dict(self.device),
            "checks": [asdict(c) for c in self.checks],
            "kernels_launched": list(self.kernels_launched),
            "speed": dict(self.speed),
            "timing": dict(self.timing),
            "drivers": dict(self.drivers),
        }

    def format_text(self) -> str:
        """The human-readable report ``clholo selftest`` prints."""
        d = self.device
        mib = 1024 * 1024
        lines = [
            f"device   {d['platform']} / {d['name']} [{d['type']}]",
            f"vendor   {d['vendor']}; driver {d['driver_version']}; {d['opencl_version']}",
            f"limits   work-group {d['max_work_group_size']} "
            f"(items per dimension {d['max_work_item_sizes']}), local memory "
            f"{d['local_mem_bytes'] // 1024} KiB, global memory {d['global_mem_bytes'] // mib} "
            f"MiB (largest buffer {d['max_mem_alloc_bytes'] // mib} MiB), "
            f"{d['compute_units']} compute units, fp64 {'yes' if d['fp64'] else 'no'}",
            f"extensions {' '.join(d['extensions'])}",
            _tuning_line(d),
            "",
            f"{'family':<13} {'check':<44} {'error':>10} {'tolerance':>10}  result",
        ]
        for c in self.checks:
            err = f"{c.error:.2e}" if math.isfinite(c.error) else str(c.error)
            lines.append(f"{c.family:<13} {c.name:<44} {err:>10} {c.tolerance:>10.1e}  "
                         f"{'pass' if c.passed else 'FAIL'}")
            if c.message:
                lines.extend("    " + m for m in c.message.strip().splitlines()[-6:])
        s = self.speed
        lines.append("")
        if s.get("skipped"):
            lines.append(f"speed    skipped: {s['skipped']}")
        elif s:
            lines.append(f"speed    FFT {s['fft_shape'][0]}x{s['fft_shape'][1]} complex64 "
                         f"{s['fft_ms']:.2f} ms; hologram {s['hologram_shape'][0]}x"
                         f"{s['hologram_shape'][1]}x{s['hologram_colours']} "
                         f"{s['hologram_ms_per_layer']:.2f} ms per layer "
                         f"({s['hologram_layers']} layers, padded grid "
                         f"{s['hologram_padded'][0]}x{s['hologram_padded'][1]}, one frame)")
        tm = self.timing
        if tm:
            cache = tm["compiler_cache"]
            if cache == "partly compiled":
                cache = f"{tm['build']['programs_compiled']} compiled, the others from the cache"
            lines.append(f"time     kernel builds {tm['build_seconds']:.1f} s "
                         f"({tm['programs_built']} programs, {cache}), checks "
                         f"{tm['check_seconds']:.1f} s, speed {tm['speed_seconds']:.1f} s")
        if self.drivers.get("advice"):
            lines.append(f"note     {self.drivers['advice']}")
        n_fail = sum(not c.passed for c in self.checks)
        verdict = ("PASSED: clholo works on this device" if self.passed else
                   f"FAILED: {n_fail} of {len(self.checks)} checks in "
                   f"{', '.join(self.failed_families)}; send the --json report with a bug "
                   f"report (docs/selftest.md)")
        lines.append(f"{verdict} ({len(self.checks)} checks, {self.seconds:.1f} s)")
        return "\n".join(lines)


# ---------------------------------------------------------------------------------------------
def _rel(got, want) -> float:
    from clholo.tolerances import rel_l2

    return rel_l2(got, want)


def _tol(kind: str, dtype=np.float32) -> dict:
    from clholo.tolerances import tol

    return tol(kind, dtype)


def _cplx(rng, shape, dtype=np.complex64):
    """Random complex values, never zeros."""
    return (rng.standard_normal(shape) + 1j * rng.standard_normal(shape)).astype(dtype)


class _Checker:
    """Collects the results of one family; an exception fails the check it happened in."""

    def __init__(self, family: str, out: List[CheckResult]):
        self.family, self.out = family, out

    def add(self, name: str, error: float, kind: str, dtype=np.float32, metric: str = "rel_l2",
            *, tolerance: Optional[float] = None, t0: Optional[float] = None):
        t = float(_tol(kind, dtype)[metric]) if tolerance is None else float(tolerance)
        error = float(error)
        self.out.append(CheckResult(self.family, name, metric, error, t,
                                    bool(np.isfinite(error) and error <= t),
                                    time.perf_counter() - t0 if t0 else 0.0))

    def fail(self, name: str, exc: BaseException) -> None:
        msg = "".join(traceback.format_exception_only(type(exc), exc)).strip()
        self.out.append(CheckResult(self.family, name, "exception", float("nan"), 0.0, False,
                                    message=msg))


def _fft(queue, rng, ck: _Checker, quick: bool) -> None:
    from clholo import fft as F

    fp64 = _fp64(queue)
    # every radix: 12 = 4*3, 20 = 4*5, 16 = 2*8, 45 = 3*3*5 (radix 9 in the CPU strips),
    # 40 = 8*5, 30 = 2*3*5
    cases = [((2, 12, 20), (-2, -1), False), ((16, 45), (-2, -1), True),
             ((3, 40), (-1,), False), ((30, 16), (-1,), True)]
    for variant in ("cpu", "gpu", "gpu-global"):
        for shape, axes, inverse in cases:
            name = f"{variant} {'x'.join(map(str, shape))} {'inverse' if inverse else 'forward'}"
            t0 = time.perf_counter()
            try:
                x = _cplx(rng, shape)
                plan = F.FFTPlan(shape, np.complex64, queue=queue, axes=axes, variant=variant)
                got = plan.execute_host(x, inverse=inverse)
                npf = {(False, 2): np.fft.fft2, (True, 2): np.fft.ifft2,
                       (False, 1): np.fft.fft, (True, 1): np.fft.ifft}[(inverse, len(axes))]
                ck.add(name, _rel(got, npf(x.astype(np.complex128))), "fft", t0=t0)
            except Exception as exc:  # noqa: BLE001 - every failure goes into the report
                ck.fail(name, exc)
        if fp64:
            name = f"{variant} 12x20 complex128"
            t0 = time.perf_counter()
            try:
                x = _cplx(rng, (12, 20), np.complex128)
                plan = F.FFTPlan((12, 20), np.complex128, queue=queue, variant=variant)
                ck.add(name, _rel(plan.execute_host(x), np.fft.fft2(x)), "fft", np.float64,
                       t0=t0)
            except Exception as exc:  # noqa: BLE001
                ck.fail(name, exc)
        if variant == "gpu" and not quick:
            # lines too long for two local buffers (2250 > 2048 complex64): the in-place
            # local-memory plan (FFT_INPLACE) that SGD's 2250^2 and the 4K grid run on a GPU
            for inverse in (False, True):
                name = f"gpu 3x2250 rows in place {'inverse' if inverse else 'forward'}"
                t0 = time.perf_counter()
                try:
                    x = _cplx(rng, (3, 2250))
                    plan = F.FFTPlan((3, 2250), np.complex64, queue=queue, axes=(-1,),
                                     variant="gpu")
                    want = (np.fft.ifft if inverse else np.fft.fft)(x.astype(np.complex128))
                    ck.add(name, _rel(plan.execute_host(x, inverse=inverse), want), "fft",
                           t0=t0)
                except Exception as exc:  # noqa: BLE001
                    ck.fail(name, exc)
            # 8192-point lines: on a GPU of 48 or 64 KiB of local memory the split plan
            # (FFT_SPLIT: values in registers between stages, exchanged one component at a
            # time), which a 4K render at pad 2 and 8192^2 grids run; in place where the local
            # memory holds them (PoCL); the name says which ran
            for inverse in (False, True):
                t0 = time.perf_counter()
                kind = "long lines"
                try:
                    x = _cplx(rng, (2, 8192))
                    plan = F.FFTPlan((2, 8192), np.complex64, queue=queue, axes=(-1,),
                                     variant="gpu")
                    d = dict(plan.geometry.passes[0].defines)
                    kind = ("split" if d.get("FFT_SPLIT") else "in place" if d.get("FFT_INPLACE")
                            else "global stages")
                    want = (np.fft.ifft if inverse else np.fft.fft)(x.astype(np.complex128))
                    ck.add(f"gpu 2x8192 rows {kind} {'inverse' if inverse else 'forward'}",
                           _rel(plan.execute_host(x, inverse=inverse), want), "fft", t0=t0)
                except Exception as exc:  # noqa: BLE001
                    ck.fail(f"gpu 2x8192 rows {kind} {'inverse' if inverse else 'forward'}",
                            exc)
        # a column round trip with an even transfer function as EvenFactors (CPU strips: laid
        # out strip by strip, fft_even_strips and mul_mode 5): the plain multiply's bits
        checks = [(f"{variant} callbacks 2x(24x40) in 18x33 out 20x30", _fft_callbacks)]
        if variant in ("cpu", "gpu"):  # (round trips run in fast memory only)
            checks.insert(0, (f"{variant} column round trip 2x(13x30), n 27, even factors: "
                              f"the same bits", _even_factors_check))
        # and load and store callbacks with a zero-padded input and a cropped output window
        for name, check in checks:
            t0 = time.perf_counter()
            try:
                check(queue, rng, variant, ck, name, t0)
            except Exception as exc:  # noqa: BLE001
                ck.fail(name, exc)


_LOAD_CB = """
real2 clholo_load(real2 v, long b, int row, int col, __global const real2 *f, int h, int w)
{
    const real2 g = f[(b * h + row) * w + col];
    return (real2)(v.x * g.x - v.y * g.y, v.x * g.y + v.y * g.x);
}
"""
_STORE_CB = """
void clholo_store(__global real2 *ptr, real2 v, long b, int row, int col, real s,
                  __global const real2 *c, int wo)
{
    *ptr = v * s + c[row * wo + col];
}
"""


def _even_factors_check(queue, rng, variant, ck, name, t0) -> None:
    import pyopencl.array as cla

    from clholo import fft as F
    from clholo import reference as ref

    B, rows, cols, n = 2, 13, 30, 27
    g = _cplx(rng, (2, n, cols))
    ki, li = np.arange(n), np.arange(cols)
    even = np.ascontiguousarray(g[:, np.minimum(ki, (n - ki) % n)[:, None],
                                  np.minimum(li, (cols - li) % cols)[None, :]])
    plan = F.RoundTripPlan((B, rows, cols), n, axis="cols", queue=queue, variant=variant)
    x = cla.to_device(queue, _cplx(rng, (B, rows, cols)))
    ef = plan.even_factors(cla.to_device(queue, even))
    plain = plan.execute(x, multiply=cla.to_device(queue, even)).get()
    err = float(np.max(np.abs(plan.execute(x, multiply=ef).get() - plain)))
    if ef.layout == "strips":
        err = max(err, float(np.max(np.abs(
            ef.data.get() - ref.even_strip_factors(even, ef.lanes, axis="cols")))))
    ck.add(name, err, "same_bits", metric="max_abs", t0=t0)


def _fft_callbacks(queue, rng, variant, ck, name, t0) -> None:
    import pyopencl.array as cla

    from clholo import fft as F

    B, tshape, ishape, oshape = 2, (24, 40), (18, 33), (20, 30)
    load = F.FFTCallback(_LOAD_CB, params=["__global const real2 *", "int", "int"])
    store = F.FFTCallback(_STORE_CB, params=["real", "__global const real2 *", "int"])
    a = _cplx(rng, (B,) + ishape)
    f = _cplx(rng, (B,) + tshape)
    c = _cplx(rng, oshape)
    plan = F.FFTPlan((B,) + tshape, np.complex64, queue=queue, input_shape=ishape,
                     output_shape=oshape, variant=variant, load_callback=load,
                     store_callback=store)
    df, dc = cla.to_device(queue, f), cla.to_device(queue, c)
    out = plan.execute(cla.to_device(queue, a), load_args=[df, np.int32(tshape[0]),
                                                           np.int32(tshape[1])],
                       store_args=[0.75, dc, np.int32(oshape[1])],
                       wait_for=list(df.events) + list(dc.events)).get()
    padded = np.zeros((B,) + tshape, np.complex128)
    padded[..., :ishape[0], :ishape[1]] = a
    want = np.fft.fft2(padded * f)[..., :oshape[0], :oshape[1]] * 0.75 + c
    ck.add(name, _rel(out, want), "fft", t0=t0)


def _fp64(queue) -> bool:
    from clholo.host import runtime

    return runtime.has_fp64(queue.device)


def _propagation(queue, rng, ck: _Checker, quick: bool) -> None:
    import clholo
    from clholo import reference as ref
    from clholo.propagation import device_padded_shape

    for shape, dz, pad in (((20, 36), 1.5e-3, "auto"), ((27, 16), -2e-3, 2)):
        name = f"ASM {shape[0]}x{shape[1]} dz {dz * 1e3:+.1f} mm pad {pad}"
        t0 = time.perf_counter()
        try:
            u = _cplx(rng, (2,) + shape)
            got = clholo.propagate(u, dz, wavelength=520e-9, pitch=8e-6, pad=pad, queue=queue)
            padded = device_padded_shape(shape, dz, wavelength=520e-9, pitch=8e-6, pad=pad)
            want = ref.propagate(u, dz, wavelength=520e-9, pitch=8e-6, pad=padded)
            ck.add(name, _rel(got, want), "propagate", t0=t0)
        except Exception as exc:  # noqa: BLE001
            ck.fail(name, exc)
    # Far and on the largest grid, where the phase remainder reaches 1e3 rad: a device without
    # fp64 that computed it in float32 was off by 3e-4 rad at 20 cm and 1.3e-3 rad at 1 m (its
    # transfer functions are built on the host, in float64); 8 rows keep it cheap
    from clholo.propagation import MAX_FFT_SIZE, build_transfer_function

    grid = (8, MAX_FFT_SIZE)
    for dz, lam in ((0.2, 638e-9), (1.0, 450e-9)):
        name = f"ASM transfer function and propagation 8x{grid[1]} dz {dz * 100:g} cm"
        t0 = time.perf_counter()
        try:
            tf = build_transfer_function(queue, grid, dz, wavelengths=[lam], pitch=8e-6).get()
            want_tf = ref.transfer_function(grid, dz, wavelength=lam, pitch=8e-6)
            ck.add(name + " (H)", float(np.max(np.abs(tf[0] - want_tf))), "transfer_function",
                   metric="max_abs", t0=t0)
            t0 = time.perf_counter()
            u = _cplx(rng, grid)
            got = clholo.propagate(u, dz, wavelength=lam, pitch=8e-6, pad=grid, queue=queue)
            want = ref.propagate(u, dz, wavelength=lam, pitch=8e-6, pad=grid)
            ck.add(name, _rel(got, want), "propagate", t0=t0)
        except Exception as exc:  # noqa: BLE001
            ck.fail(name, exc)


def _random(queue, rng, ck: _Checker, quick: bool) -> None:
    from clholo import reference as ref
    from clholo.random import philox4x32_10, random_phases

    name = "Philox4x32-10 raw stream, 37 counters"
    t0 = time.perf_counter()
    try:
        counters = rng.integers(0, 2 ** 32, size=(37, 4), dtype=np.uint64).astype(np.uint32)
        keys = rng.integers(0, 2 ** 32, size=(37, 2), dtype=np.uint64).astype(np.uint32)
        got = philox4x32_10(counters, keys, queue=queue)
        want = np.stack(ref.philox4x32_10(counters.T, keys.T), axis=1)
        ck.add(name, float(np.count_nonzero(got != want)), "random_phase",
               metric="mismatches", tolerance=0.0, t0=t0)
    except Exception as exc:  # noqa: BLE001
        ck.fail(name, exc)
    name = "phases 13x7, 2 frames x 2 colours, bit for bit"
    t0 = time.perf_counter()
    try:
        seed, layer = int(rng.integers(0, 2 ** 63)), int(rng.integers(0, 64))
        got = random_phases((13, 7), seed=seed, layer=layer, frames=2, colours=2, frame0=3,
                            queue=queue).get()
        bad = 0
        for f in range(2):
            for c in range(2):
                want = ref.random_phase((13, 7), seed=seed, frame=3 + f, colour=c, layer=layer)
                bad += int(np.count_nonzero(got[f, c].view(np.uint32) != want.view(np.uint32)))
        ck.add(name, float(bad), "random_phase", metric="mismatches", tolerance=0.0, t0=t0)
    except Exception as exc:  # noqa: BLE001
        ck.fail(name, exc)


def _elementwise(queue, rng, ck: _Checker, quick: bool) -> None:
    import pyopencl.array as cla

    from clholo.elementwise import accumulate_intensity, complex_multiply, complex_scale

    name = "multiply, scale, |u|^2 accumulate 3x(11x17)"
    t0 = time.perf_counter()
    try:
        a, b = _cplx(rng, (3, 11, 17)), _cplx(rng, (11, 17))
        err = _rel(complex_multiply(a, b, queue=queue), a.astype(np.complex128) * b)
        s = complex(0.3, -1.7)
        err = max(err, _rel(complex_scale(a, s, queue=queue), s * a.astype(np.complex128)))
        acc0 = rng.random((11, 17)).astype(np.float32)
        acc = cla.to_device(queue, acc0)
        accumulate_intensity(cla.to_device(queue, a), acc, weight=0.25, queue=queue)
        want = acc0 + 0.25 * np.sum(np.abs(a.astype(np.complex128)) ** 2, axis=0)
        ck.add(name, max(err, _rel(acc.get(), want)), "elementwise", t0=t0)
    except Exception as exc:  # noqa: BLE001
        ck.fail(name, exc)


def _composite(queue, rng, ck: _Checker, quick: bool) -> None:
    import pyopencl.array as cla

    from clholo import reference as ref
    from clholo.host import runtime

    from clholo.host.kernel_args import COMPOSITE_LAYER

    def four_pixels(du, color, alpha, shape, k0, k1, layer, frame0, farthest):
        F_, C, H, W = shape
        kern = runtime.get_kernel(queue.context, "composite.cl", "composite_layer")
        runtime.launch(kern, queue, ((H * W + 3) // 4, C, F_), None, *COMPOSITE_LAYER.args(
            u=du.data, color=color.data, alpha=alpha.data, npix=H * W, n_channels=C,
            layer=layer, frame0=frame0, colour0=0, key_lo=k0, key_hi=k1, farthest=farthest))

    def blocks(du, color, alpha, shape, k0, k1, layer, frame0, farthest):
        F_, C, H, W = shape
        kern = runtime.get_kernel(queue.context, "composite_cpu.cl", "composite_layer_rows8")
        runtime.launch(kern, queue, (-(-W // 8), -(-H // 8), F_ * C), None, du.data,
                       color.data, alpha.data, np.uint32(H), np.uint32(W), np.uint32(C),
                       np.uint32(layer), np.uint32(frame0), np.uint32(k0), np.uint32(k1),
                       np.int32(farthest))

    def rows4(du, color, alpha, shape, k0, k1, layer, frame0, farthest):
        F_, C, H, W = shape
        kern = runtime.get_kernel(queue.context, "composite.cl", "composite_layer_rows4")
        runtime.launch(kern, queue, (-(-W // 4), H, F_ * C), None, du.data,
                       color.data, alpha.data, np.uint32(H), np.uint32(W), np.uint32(C),
                       np.uint32(layer), np.uint32(frame0), np.uint32(k0), np.uint32(k1),
                       np.int32(farthest))

    # composite_layer (four pixels a work-item), its CPU form (8x8 blocks through the row
    # round trip's composite; a transparent block kept as it is, an edge block of 4 rows and
    # 3 columns pixel by pixel), and the four-pixel form of any layout (GPUs' planes; a row's
    # last 3 pixels one by one)
    for kernel, launch, shape in (("composite_layer", four_pixels, (2, 3, 13, 19)),
                                  ("composite_layer_rows8", blocks, (2, 3, 12, 19)),
                                  ("composite_layer_rows4", rows4, (2, 3, 11, 19))):
        for farthest in (False, True):
            F_, C, H, W = shape
            name = f"{kernel} {F_}x{C}x({H}x{W}){' farthest' if farthest else ''}"
            t0 = time.perf_counter()
            try:
                u0 = _cplx(rng, shape)
                color = rng.random((H, W, C)).astype(np.float32)
                alpha = rng.random((H, W)).astype(np.float32)
                alpha[:8, 8:16] = 0.0
                seed, layer, frame0 = int(rng.integers(0, 2 ** 63)), 5, 7
                du = cla.to_device(queue, u0)
                k0, k1 = ref.seed_key(seed)
                launch(du, cla.to_device(queue, color), cla.to_device(queue, alpha), shape, k0,
                       k1, layer, frame0, farthest)
                got = du.get()
                want = np.empty(u0.shape, np.complex128)
                for f in range(F_):
                    for c in range(C):
                        phi = ref.random_phase((H, W), seed=seed, frame=frame0 + f, colour=c,
                                               layer=layer)
                        behind = np.zeros((H, W)) if farthest else u0[f, c]
                        want[f, c] = ref.composite_layer(behind, color[..., c], alpha, phi)
                ck.add(name, _rel(got, want), "composite", t0=t0)
            except Exception as exc:  # noqa: BLE001
                ck.fail(name, exc)
    # the next layer composited in the inverse transform's store, with every FFT variant
    for variant in ("cpu", "gpu", "gpu-global"):
        name = f"composite in the FFT store ({variant}) 3x(17x22) of 24x27"
        t0 = time.perf_counter()
        try:
            _composite_store(queue, rng, variant, ck, name, t0)
        except Exception as exc:  # noqa: BLE001
            ck.fail(name, exc)
    # ... and between the row round trip's inverse and forward FFT (the two-pass layer)
    for variant in ("cpu", "gpu"):
        name = f"composite in the row round trip ({variant}) 3x(17x28) of 17x30"
        t0 = time.perf_counter()
        try:
            _composite_mid(queue, rng, variant, ck, name, t0)
        except Exception as exc:  # noqa: BLE001
            ck.fail(name, exc)
    # the layer as the CPU renderer holds it (kernel layer_blocks: sqrt(c a), sqrt(1 - a),
    # eight rows to a block) and as GPUs' planes (kernel layer_planes, a row to a block)
    # against their reference, and the row round trip's composite from them against the
    # row-major layer's bits, on both kernel variants; the GPU kernels' by quads too
    name = ("layer blocks and planes 3x(17x28) and the row round trip's composite from them "
            "(CPU and GPU kernels, by quads too): the same bits")
    t0 = time.perf_counter()
    try:
        _layer_blocks_check(queue, rng, ck, name, t0)
    except Exception as exc:  # noqa: BLE001
        ck.fail(name, exc)


def _layer_blocks_check(queue, rng, ck, name, t0) -> None:
    import pyopencl.array as cla

    from clholo import fft as F
    from clholo import reference as ref
    from clholo.host import runtime, tuning
    from clholo.host.scheduler import COMPOSITE_STORE_PARAMS

    C, H, W, Wp, layer, frame0 = 3, 17, 28, 30, 4, 6
    color = rng.random((H, W, C)).astype(np.float32)
    alpha = rng.random((H, W)).astype(np.float32)
    alpha[:8, 8:16] = 0.0
    dcol, dal = cla.to_device(queue, color), cla.to_device(queue, alpha)
    err = 0.0
    layouts = [({}, [dcol, dal])]
    for R, filename, kernel in ((8, "composite_cpu.cl", "layer_blocks"),
                                (1, "composite.cl", "layer_planes")):
        S = -(-H // R)
        amp = cla.empty(queue, (S, C, W, R), np.float32)
        keep = cla.empty(queue, (S, W, R), np.float32)
        runtime.launch(runtime.get_kernel(queue.context, filename, kernel), queue, (W, S), None,
                       dcol.data, dal.data, amp.data, keep.data, np.uint32(H), np.uint32(W),
                       np.uint32(C))
        want_amp, want_keep = ref.layer_blocks(color, alpha, rows=R)
        err = max(err, float(np.max(np.abs(amp.get() - want_amp))),
                  float(np.max(np.abs(keep.get() - want_keep))))
        layouts.append(({"CLHOLO_LAYER_BLOCKS": True, "CLHOLO_LAYER_ROWS": R}, [amp, keep]))
    spec = cla.to_device(queue, _cplx(rng, (C, H, Wp)))
    k0, k1 = ref.seed_key(int(rng.integers(0, 2 ** 63)))
    tail = [np.uint32(W), np.uint32(C), np.uint32(layer), np.uint32(frame0), k0, k1]
    for variant, quads in (("cpu", False), ("gpu", False), ("gpu", True)):
        got = []
        for defines, arrays in layouts:
            mid = F.FFTCallback('#include "composite_store.h"\n',
                                params=COMPOSITE_STORE_PARAMS, defines=defines)
            with tuning.override(mid_quads=quads):
                plan = F.RoundTripPlan((C, H, Wp), Wp, axis="rows", first="inverse", mid_n=W,
                                       mid_callback=mid, queue=queue, variant=variant)
            got.append(plan.execute(spec, mid_args=arrays + tail).get())
        if variant == "gpu" and not quads:
            by_elements = got[0]
        elif quads:
            got.append(by_elements)
        err = max(err, max(float(np.max(np.abs(g - got[0]))) for g in got[1:]))
    ck.add(name, err, "same_bits", metric="max_abs", t0=t0)


def _composite_mid(queue, rng, variant, ck, name, t0) -> None:
    """The two-pass layer's row kernel: inverse row FFT, crop, composite, forward row FFT."""
    import pyopencl.array as cla

    from clholo import fft as F
    from clholo import reference as ref
    from clholo.host.scheduler import COMPOSITE_STORE_PARAMS

    # W = 28: eight rows by eight columns three times, then four columns pixel by pixel
    C, H, W, Wp, seed, layer, frame0 = 3, 17, 28, 30, 11, 2, 5
    spec = _cplx(rng, (C, H, Wp))
    color = rng.random((H, W, C)).astype(np.float32)
    alpha = rng.random((H, W)).astype(np.float32)
    mid = F.FFTCallback('#include "composite_store.h"\n', params=COMPOSITE_STORE_PARAMS)
    plan = F.RoundTripPlan((C, H, Wp), Wp, axis="rows", first="inverse", mid_n=W,
                           mid_callback=mid, queue=queue, variant=variant)
    k0, k1 = ref.seed_key(seed)
    dcol, dal = cla.to_device(queue, color), cla.to_device(queue, alpha)
    got = plan.execute(cla.to_device(queue, spec),
                       mid_args=[dcol, dal, np.uint32(W), np.uint32(C), np.uint32(layer),
                                 np.uint32(frame0), k0, k1],
                       wait_for=list(dcol.events) + list(dal.events)).get()

    def over(v):
        return np.stack([ref.composite_layer(v[c], color[..., c], alpha, ref.random_phase(
            (H, W), seed=seed, frame=frame0, colour=c, layer=layer)) for c in range(C)])

    want = ref.round_trip(spec, Wp, axis="rows", first="inverse", mid_n=W, mid=over)
    ck.add(name, _rel(got, want), "composite", t0=t0)


def _composite_store(queue, rng, variant, ck, name, t0) -> None:
    import pyopencl.array as cla

    from clholo import fft as F
    from clholo import reference as ref
    from clholo.host.scheduler import COMPOSITE_STORE_PARAMS

    frames, C, H, W, padded = 1, 3, 17, 22, (24, 27)
    store = F.FFTCallback('#include "composite_store.h"\n', params=COMPOSITE_STORE_PARAMS)
    plan = F.FFTPlan((frames * C,) + padded, np.complex64, queue=queue, output_shape=(H, W),
                     variant=variant, store_callback=store)
    spec = _cplx(rng, (frames * C,) + padded)
    color = rng.random((H, W, C)).astype(np.float32)
    alpha = rng.random((H, W)).astype(np.float32)
    seed, layer, frame0 = int(rng.integers(0, 2 ** 63)), 2, 4
    k0, k1 = ref.seed_key(seed)
    dcol, dal = cla.to_device(queue, color), cla.to_device(queue, alpha)
    got = plan.execute(cla.to_device(queue, spec), inverse=True,
                       store_args=[dcol, dal, np.uint32(W), np.uint32(C), np.uint32(layer),
                                   np.uint32(frame0), k0, k1],
                       wait_for=list(dcol.events) + list(dal.events)).get()
    behind = np.fft.ifft2(spec.astype(np.complex128))[..., :H, :W]
    want = np.empty(got.shape, np.complex128)
    for c in range(C):
        phi = ref.random_phase((H, W), seed=seed, frame=frame0, colour=c, layer=layer)
        want[c] = ref.composite_layer(behind[c], color[..., c], alpha, phi)
    ck.add(name, _rel(got, want), "composite", t0=t0)


def _hologram(queue, rng, ck: _Checker, quick: bool) -> None:
    import clholo
    from clholo import reference as ref
    from clholo.host.scheduler import HologramRenderer

    L, C = 3, 2
    optics = clholo.Optics(wavelengths=(638e-9, 450e-9))
    # the two-pass layer (column and row round trips) with both FFT variants, the four-pass
    # layer with the composite separate and fused into the store, the layer sum; and the
    # CPU strips' two-pass layer at pad 2 on a 32x40 grid, where every line transform skips
    # its zero half in or its unread half out (kernels/fft_cpu.cl, FFT_PRUNE)
    for two_pass, variant, fused, occlusion, pad, (H, W) in (
            (True, "cpu", False, True, "auto", (14, 22)),
            (True, "cpu", False, True, 2, (16, 20)),
            (True, "gpu", False, True, "auto", (14, 22)),
            (False, "auto", False, True, "auto", (14, 22)),
            (False, "auto", True, True, "auto", (14, 22)),
            (False, "auto", True, False, "auto", (14, 22))):
        name = (f"{'RGB-D layer sum' if not occlusion else 'MPI'} {L}x{H}x{W}x{C}, 2 frames"
                + (f", two passes per layer ({variant})" if two_pass else ", four passes")
                + (", composite fused" if fused else "") + (f", pad {pad}" if pad != "auto"
                                                             else ""))
        t0 = time.perf_counter()
        try:
            mpi = clholo.MPI(rng.random((L, H, W, C)), rng.random((L, H, W)),
                             np.linspace(1e-3, 3e-3, L))
            seed = int(rng.integers(0, 2 ** 40))
            r = HologramRenderer(mpi, optics, seed=seed, queue=queue, fuse_composite=fused,
                                 occlusion=occlusion, two_pass=two_pass if occlusion else None,
                                 variant=variant, pad=pad)
            got = r.render(2).get()
            fn = ref.mpi_hologram if occlusion else ref.rgbd_hologram
            want = fn(mpi.color, mpi.alpha, mpi.depths, wavelengths=optics.wavelengths,
                      pitch=optics.pitch, frames=2, seed=seed, pad=r.padded)
            ck.add(name, _rel(got, want), "hologram", t0=t0)
        except Exception as exc:  # noqa: BLE001
            ck.fail(name, exc)


def _views(queue, rng, ck: _Checker, quick: bool) -> None:
    import clholo
    from clholo import reference as ref
    from clholo import views

    optics = clholo.Optics(wavelengths=(638e-9, 450e-9))
    for square in (False, True):
        name = f"pupil views 3x2x(15x21), {'square' if square else 'disc'} pupil"
        t0 = time.perf_counter()
        try:
            holo = _cplx(rng, (3, 2, 15, 21))
            angles = [(0.0, 0.0), (0.013, -0.007)]
            got = views.pupil_view(holo, optics, focus_depth=1e-3, angles_rad=angles,
                                   pupil_angle_rad=0.01, pupil="square" if square else "disc",
                                   pad=(32, 40), queue=queue)
            want = ref.pupil_view(holo, 1e-3, wavelengths=optics.wavelengths,
                                  pitch=optics.pitch, angles_rad=angles, pupil_angle_rad=0.01,
                                  square=square, pad=(32, 40))
            ck.add(name, _rel(got, want), "pupil_view", t0=t0)
        except Exception as exc:  # noqa: BLE001
            ck.fail(name, exc)
    name = "light field 2x2x(21x27), window 4, hop 3, hann"
    t0 = time.perf_counter()
    try:
        holo = _cplx(rng, (2, 2, 21, 27))
        lf = views.light_field(holo, optics, window=4, hop=3, taper="hann", queue=queue)
        want = ref.light_field(holo, window=4, hop=3, taper="hann")
        ck.add(name, _rel(lf.intensity, want), "light_field", t0=t0)
    except Exception as exc:  # noqa: BLE001
        ck.fail(name, exc)


def _rayoptics(queue, rng, ck: _Checker, quick: bool) -> None:
    import clholo
    from clholo import reference as ref
    from clholo.rayoptics import warp_over

    L, H, W, C, V = 3, 13, 18, 2, 2
    for premultiplied in (True, False):
        name = f"warp and over {L}x{H}x{W}x{C}, {V} views{', premultiplied' if premultiplied else ''}"
        t0 = time.perf_counter()
        try:
            mpi = clholo.MPI(rng.random((L, H, W, C)), rng.random((L, H, W)),
                             np.sort(rng.uniform(1e-3, 6e-3, L)))
            hom = np.zeros((C, V, L, 3, 3))
            hom[..., 0, 0] = rng.uniform(0.8, 1.25, (C, V, L))
            hom[..., 1, 1] = rng.uniform(0.8, 1.25, (C, V, L))
            hom[..., 0, 1] = rng.uniform(-0.1, 0.1, (C, V, L))
            hom[..., 1, 0] = rng.uniform(-0.1, 0.1, (C, V, L))
            hom[..., 0, 2] = rng.uniform(-0.4 * W, 0.4 * W, (C, V, L))
            hom[..., 1, 2] = rng.uniform(-0.4 * H, 0.4 * H, (C, V, L))
            hom[..., 2, 2] = 1.0
            got = warp_over(mpi, hom, premultiplied=premultiplied, queue=queue)
            want = ref.warp_over_mean(mpi.color, mpi.alpha, hom, premultiplied=premultiplied)
            ck.add(name, _rel(got, want), "rayoptics", t0=t0)
        except Exception as exc:  # noqa: BLE001
            ck.fail(name, exc)


def _sgd_iteration(queue, rng, ck: _Checker, B, H, W, z, P, wl, fuse: str,
                   variant: str = "auto") -> None:
    import pyopencl.array as cla

    from clholo import reference as ref
    from clholo.host.phase_retrieval import (SGD_ADAM_STORE, SGD_RESIDUAL_LOAD,
                                             PhaseRetrieval)
    from clholo.propagation import ASMPropagator, device_padded_shape

    name = (f"SGD loss, gradient and Adam {B}x({H}x{W}) with a mask, fuse {fuse}"
            + ("" if variant == "auto" else f", {variant} FFT kernels"))
    t0 = time.perf_counter()
    try:
        padded = device_padded_shape((H, W), z, wavelength=wl, pitch=P)
        target = _cplx(rng, (B, H, W))
        mask = (rng.uniform(size=(H, W)) > 0.25).astype(np.float32)
        eng = PhaseRetrieval(cla.to_device(queue, target), wavelengths=wl, pitch=P, z=z,
                             padded=padded, mask=cla.to_device(queue, mask), lr=0.05,
                             queue=queue, fuse=fuse,
                             variant=variant if fuse == "round-trips" else "auto")
        if variant != "auto" and fuse != "round-trips":
            callbacks = {"none": {}, "residual": dict(load_callback=SGD_RESIDUAL_LOAD),
                         "all": dict(load_callback=SGD_RESIDUAL_LOAD,
                                     store_callback=SGD_ADAM_STORE)}[fuse]
            eng.propagator = ASMPropagator(B, (H, W), padded, queue=queue, variant=variant,
                                           **callbacks)
        phase = rng.uniform(0, 2 * np.pi, (B, H, W)).astype(np.float32)
        eng.set_phase(cla.to_device(queue, phase))
        A, AH = ref.asm_operator((H, W), z, wavelengths=wl, pitch=P, padded=padded)
        eng.step()
        loss, grad, s = ref.sgd_loss_and_gradient(phase, target, A, AH, mask=mask)
        err = max(_rel(eng.grad.get(), grad), _rel(eng.loss.get(), loss),
                  _rel(eng.scale.get(), s))
        ck.add(name + ": gradient", err, "encode_gradient", t0=t0)
        # the second Adam step from the device's own state and gradient
        p0, m0, v0 = eng.phase.get(), eng.adam_m.get(), eng.adam_v.get()
        eng.step()
        p_want, _, _ = ref.adam_step(p0.astype(np.float64), eng.grad.get().astype(np.float64),
                                     m0, v0, 2, lr=0.05)
        ck.add(name + ": Adam step", float(np.max(np.abs(eng.phase.get() - p_want))),
               "encode_adam", metric="max_abs")
    except Exception as exc:  # noqa: BLE001
        ck.fail(name, exc)


def _encode(queue, rng, ck: _Checker, quick: bool) -> None:
    import pyopencl.array as cla

    from clholo import reference as ref
    from clholo.host import runtime
    from clholo.host.phase_retrieval import (PhaseRetrieval, SumPlan, device_sum_plan,
                                             encode_kernel, field_max_abs, launch_sums, quads,
                                             sum_plan)
    from clholo.propagation import device_padded_shape

    B, H, W, z, P, wl = 2, 11, 26, 2e-3, 8e-6, (638e-9, 450e-9)
    # every form of the iteration: the residual and Adam step as kernels of their own (CPUs'
    # default), the residual fused into the adjoint propagation's first pass, both fused
    # into its first and last passes (kernels/sgd_callbacks.h), the whole iteration in two
    # column and two row round trips (every device's default)
    for fuse in ("none", "residual", "all", "round-trips"):
        _sgd_iteration(queue, rng, ck, B, H, W, z, P, wl, fuse)
    # rows of 32 pixels: the CPU strips' eight-pixel callbacks (clholo_load8/clholo_store8,
    # clholo_mid_rows8); and the GPU FFT kernels' one-pixel callbacks, whatever this device is
    _sgd_iteration(queue, rng, ck, B, H, 32, z, P, wl, "all")
    _sgd_iteration(queue, rng, ck, B, 16, 32, z, P, wl, "round-trips")
    _sgd_iteration(queue, rng, ck, B, H, W, z, P, wl, "all", variant="gpu")
    _sgd_iteration(queue, rng, ck, B, H, W, z, P, wl, "round-trips", variant="gpu")
    # the loss sums split as on a GPU (256 work-items a group, 8 groups per compute unit,
    # sum_plan) whatever this device is: Oclgrind checks that variant too
    n = 3001
    lim = runtime._limits_of_device(queue.device)  # an H100's units, this device's limits
    plan = sum_plan(n, gpu=True, compute_units=132, max_work_group=lim.max_work_group_size,
                    max_items=lim.max_item_sizes[0], local_mem_bytes=lim.local_mem_bytes)
    name = f"SGD loss sums split as on a GPU ({plan.local} x {plan.groups}) {B}x{n}"
    t0 = time.perf_counter()
    try:
        y, t = _cplx(rng, (B, n)), _cplx(rng, (B, n))
        w = rng.uniform(0.2, 1, n).astype(np.float32)
        part = cla.empty(queue, (B, plan.groups, 4), np.float32)
        out = [cla.empty(queue, (B,), dt) for dt in (np.complex64, np.float32, np.float32)]
        launch_sums(queue, plan, cla.to_device(queue, y).data, cla.to_device(queue, t).data,
                    cla.to_device(queue, w).data, n, B, part.data, *(o.data for o in out))
        want = ref.sgd_fit(y[:, None], t[:, None], mask=w[None])
        ck.add(name, max(_rel(o.get(), v) for o, v in zip(out, want)), "encode_gradient",
               t0=t0)
    except Exception as exc:  # noqa: BLE001
        ck.fail(name, exc)
    # the loss sums' CPU form (field_sums_lanes: a group's work-items side by side in one
    # work-item) against field_sums with the device's split: the same bits
    plan = device_sum_plan(queue.device, n)
    name = f"SGD loss sums, CPU form field_sums_lanes ({plan.local} x {plan.groups}) {B}x{n}"
    t0 = time.perf_counter()
    try:
        y, t = cla.to_device(queue, _cplx(rng, (B, n))), cla.to_device(queue, _cplx(rng, (B, n)))
        w = cla.to_device(queue, rng.uniform(0.2, 1, n).astype(np.float32))
        got = []
        for lanes in (False, True):
            part = cla.empty(queue, (B, plan.groups, 4), np.float32)
            out = [cla.empty(queue, (B,), dt) for dt in (np.complex64, np.float32, np.float32)]
            launch_sums(queue, plan, y.data, t.data, w.data, n, B, part.data,
                        *(o.data for o in out), lanes=lanes)
            got.append([part.get()] + [o.get() for o in out])
        ck.add(name + ": the same bits as field_sums",
               max(float(np.max(np.abs(a - b))) for a, b in zip(*got)), "same_bits",
               metric="max_abs", t0=t0)
    except Exception as exc:  # noqa: BLE001
        ck.fail(name, exc)
    # DPAC's largest |u| per field with that split, the device's and one group: a maximum is
    # exact in any order, so all three are the same bits (and NumPy's |u| to a few ulps)
    name = f"max |u| split as on a GPU ({plan.local} x {plan.groups}) {B}x{n}"
    t0 = time.perf_counter()
    try:
        du = cla.to_device(queue, _cplx(rng, (B, n)))
        got = [field_max_abs(du, plan=p).get()
               for p in (plan, device_sum_plan(queue.device, n), SumPlan(plan.local, 1))]
        ck.add(name + ": the same bits with every split",
               max(float(np.max(np.abs(g - got[0]))) for g in got), "encode_max",
               metric="max_abs")
        ck.add(name, float(np.max(np.abs(got[0] - np.abs(du.get()).max(axis=-1)))),
               "encode_elementwise", metric="max_abs", t0=t0)
    except Exception as exc:  # noqa: BLE001
        ck.fail(name, exc)
    name = f"exp(iP), arg u, max |u|, DPAC {B + 1}x({H}x{W})"
    t0 = time.perf_counter()
    try:
        B3 = B + 1
        u = _cplx(rng, (B3, H, W))
        du = cla.to_device(queue, u)
        ph = rng.uniform(-10, 10, (B3, H, W)).astype(np.float32)
        x = cla.empty(queue, u.shape, np.complex64)
        runtime.launch(encode_kernel(queue.context, "phase_to_field"), queue, (quads(u.size),),
                       None, cla.to_device(queue, ph).data, x.data, np.uint32(u.size))
        err = float(np.max(np.abs(x.get() - ref.phase_to_field(ph))))
        ang = cla.empty(queue, u.shape, np.float32)
        runtime.launch(encode_kernel(queue.context, "field_angle"), queue, (u.size,), None,
                       du.data, ang.data)
        err = max(err, float(np.max(np.abs(np.angle(np.exp(1j * (ang.get() - np.angle(u))))))))
        amax = field_max_abs(du)
        err = max(err, float(np.max(np.abs(amax.get() - np.abs(u).max(axis=(-2, -1))))))
        am = (0.7 * np.abs(u).max(axis=(-2, -1))).astype(np.float32)
        out = cla.empty(queue, (B3, H, W), np.float32)
        runtime.launch(encode_kernel(queue.context, "dpac_encode"), queue, (W, H, B3), None,
                       du.data, cla.to_device(queue, am).data, out.data)
        ck.add(name.replace(", DPAC", ""), err, "encode_elementwise", metric="max_abs", t0=t0)
        # DPAC's acos near |u| = amax loses digits: the test suite allows it 10x
        want = ref.dpac_phase(u, am)
        ck.add(f"DPAC {B3}x({H}x{W})",
               float(np.max(np.abs(np.angle(np.exp(1j * (out.get() - want)))))),
               "encode_elementwise", metric="max_abs",
               tolerance=10 * _tol("encode_elementwise")["max_abs"])
    except Exception as exc:  # noqa: BLE001
        ck.fail(name, exc)


def _quantize(queue, rng, ck: _Checker, quick: bool) -> None:
    import pyopencl.array as cla

    from clholo import reference as ref
    from clholo.encode.quantize import DeviceQuantizer, PhaseLUT, device_table, quantize

    T, C, H, W = 2, 3, 11, 26
    name = f"8-bit LUT quantisation {T}x{C}x({H}x{W}) + every breakpoint"
    t0 = time.perf_counter()
    try:
        steps = rng.uniform(0.2, 1.8, 255)
        measured = PhaseLUT(np.concatenate([[0.0], np.cumsum(steps) / steps.sum() * 2.1 * np.pi]),
                            name="random measured")
        luts = [PhaseLUT.linear(255), PhaseLUT.linear(200), measured]
        dq = DeviceQuantizer(luts, C)
        lo, hi = (np.float32(v) for v in dq.phase_range)
        tables = [device_table(lut, dq.phase_range) + (lo, hi) for lut in luts]
        # random phases, and one row per colour holding every breakpoint of its table, the
        # float32 on each side of it and both ends of the range
        edges = []
        for bp, _, _, _ in tables:
            pts = np.concatenate([bp, np.nextafter(bp, np.float32(-np.inf)),
                                  np.nextafter(bp, np.float32(np.inf)), [lo, hi]])
            edges.append(pts[(pts >= lo) & (pts <= hi)].astype(np.float32))
        n = max(len(e) for e in edges)
        adversarial = rng.uniform(lo, hi, (1, C, 1, n)).astype(np.float32)
        for c, e in enumerate(edges):
            adversarial[0, c, 0, :len(e)] = e
        err = 0
        for phase in (rng.uniform(lo, hi, (T, C, H, W)).astype(np.float32), adversarial):
            gray, flags = dq.enqueue(cla.to_device(queue, phase))
            got = gray.get().astype(np.int64)
            want, want_flags = ref.quantize_phase(phase, tables)
            host = quantize(phase, luts)
            err = max(err, int(np.abs(got - want).max()), int(np.abs(got - host).max()),
                      int(np.any(flags.get() != want_flags)))
        ck.add(name, err, "quantize", metric="max_abs", t0=t0)
    except Exception as exc:  # noqa: BLE001
        ck.fail(name, exc)
    name = "quantisation flags NaN, inf, out of range"
    t0 = time.perf_counter()
    try:
        phase = rng.uniform(-3, 3, (1, C, 5, 7)).astype(np.float32)
        phase[0, 0, 1, 2] = np.nan
        phase[0, 1, 4, 6] = np.inf
        phase[0, 2, 0, 0] = 20.0
        gray, flags = dq.enqueue(cla.to_device(queue, phase))
        want, want_flags = ref.quantize_phase(phase, tables)
        err = max(int(np.any(flags.get() != want_flags)), int(not want_flags.all()),
                  int(np.abs(gray.get().astype(np.int64) - want).max()))
        ck.add(name, err, "quantize", metric="max_abs", t0=t0)
    except Exception as exc:  # noqa: BLE001
        ck.fail(name, exc)


def _rpws(queue, rng, ck: _Checker, quick: bool) -> None:
    import clholo
    from clholo import reference as ref
    from clholo.baselines import rpws

    K, H, W = 5, 19, 26
    name = f"RPWS {K} Gaussians {H}x{W}x2, 2 frames"
    t0 = time.perf_counter()
    try:
        xy = np.stack([rng.uniform(-3, W + 3, K), rng.uniform(-3, H + 3, K)], 1)
        sx, sy = rng.uniform(1.5, 5.0, K), rng.uniform(1.5, 5.0, K)
        rho = rng.uniform(-0.6, 0.6, K)
        cov = np.stack([[sx * sx, rho * sx * sy], [rho * sx * sy, sy * sy]]).transpose(2, 0, 1)
        inv = np.linalg.inv(cov)
        conic = np.stack([inv[:, 0, 0], inv[:, 0, 1], inv[:, 1, 1]], 1)
        radius = np.ceil(3 * np.sqrt(np.linalg.eigvalsh(cov)[:, 1]))
        depths = np.sort(rng.uniform(1e-3, 3e-3, K))
        p = rpws.Primitives(xy, conic, rng.uniform(0.2, 1.0, K),
                            rng.uniform(0.05, 1.0, (K, 2)), depths, radius, (H, W))
        optics = clholo.Optics(wavelengths=(638e-9, 450e-9))
        seed = int(rng.integers(0, 2 ** 40))
        got = rpws.render_rpws(p, optics, frames=2, seed=seed, queue=queue)
        padded = rpws.rpws_padded_shape(p, optics)
        want = ref.rpws_hologram(p.xy, p.conic, p.opacity, p.color, p.depths, p.boxes(),
                                 p.shape, wavelengths=optics.wavelengths, pitch=optics.pitch,
                                 frames=2, seed=seed, pad=padded)
        ck.add(name, _rel(got, want), "rpws", t0=t0)
    except Exception as exc:  # noqa: BLE001
        ck.fail(name, exc)


def _splats(queue, rng, ck: _Checker, quick: bool) -> None:
    from clholo.io.splats import (Camera, Gaussians, project, rasterize_slabs,
                                  rasterize_slabs_reference, slab_edges)

    n, W, H, slabs = 60, 37, 23, 3
    name = f"rasterise {n} splats into {slabs} slabs {H}x{W}"
    t0 = time.perf_counter()
    try:
        z = rng.uniform(2.0, 8.0, n)
        means = np.stack([rng.uniform(-0.35, 0.35, n) * z, rng.uniform(-0.35, 0.35, n) * z, z], 1)
        g = Gaussians(means, np.exp(rng.uniform(np.log(0.02), np.log(0.3), (n, 3))),
                      rng.standard_normal((n, 4)), rng.uniform(0.05, 0.99, n),
                      rng.uniform(0.02, 1.0, (n, 3)))
        proj = project(g, Camera(W, H, 0.9 * W, 0.9 * W))
        slab, _ = slab_edges(proj.depth, slabs, spacing="depth")
        want_a, want_c = rasterize_slabs_reference(proj, slab, slabs, W, H)
        got_a, got_c = rasterize_slabs(proj, slab, slabs, W, H, queue=queue)
        ck.add(name, max(_rel(got_a, want_a), _rel(got_c, want_c)), "raster", t0=t0)
    except Exception as exc:  # noqa: BLE001
        ck.fail(name, exc)


#: The kernel families in the order they run: (name, check function, kernels/ files covered)
FAMILIES = [
    ("fft", _fft, ("fft_cpu.cl", "fft_gpu.cl")),
    ("propagation", _propagation, ("asm.cl",)),
    ("random", _random, ("random_phase.cl",)),
    ("elementwise", _elementwise, ("elementwise.cl",)),
    ("composite", _composite, ("composite.cl", "composite_store.h", "composite_cpu.cl")),
    ("hologram", _hologram, ("composite.cl", "asm.cl")),
    ("views", _views, ("views.cl",)),
    ("rayoptics", _rayoptics, ("rayoptics.cl",)),
    ("encode", _encode, ("encode.cl", "sgd_step.h", "sgd_callbacks.h")),
    ("quantize", _quantize, ("quantize.cl",)),
    ("rpws", _rpws, ("rpws.cl",)),
    ("splats", _splats, ("splat_raster.cl",)),
]


def is_simulator(device) -> bool:
    """True for the Oclgrind simulator (speed means nothing there)."""
    return "oclgrind" in f"{device.platform.name} {device.name}".lower()


def _tuning_line(d: Dict[str, object]) -> str:
    """The report's line on the GPU kernels' tunable settings (reports without them: older)."""
    settings = d.get("tuning")
    if not settings:
        return "tuning   (not recorded)"
    from clholo.host.tuning import SETTINGS

    changed = [f"{k}={v}" for k, v in settings.items() if k in SETTINGS
               and SETTINGS[k].default != v]
    where = "stored for this device (clholo tune --show)" if d.get("tuning_stored") else \
        "none stored for this device (clholo tune)"
    return f"tuning   {', '.join(changed) if changed else 'the defaults'}; {where}"


def device_facts(device) -> Dict[str, object]:
    """Name, vendor, driver, OpenCL version, limits and extensions of ``device``, and the
    tunable settings its plans take (:mod:`clholo.host.tuning`)."""
    import pyopencl as cl

    from clholo.host import runtime, tuning

    def get(attr, default=None):
        try:
            return getattr(device, attr)
        except (cl.Error, AttributeError):
            return default

    return {
        "platform": device.platform.name.strip(),
        "platform_version": device.platform.version.strip(),
        "name": device.name.strip(),
        "vendor": device.vendor.strip(),
        "type": runtime._type_name(device),
        "driver_version": device.driver_version.strip(),
        "opencl_version": device.version.strip(),
        "opencl_c_version": str(get("opencl_c_version", "")).strip(),
        "compute_units": int(device.max_compute_units),
        "max_clock_mhz": int(get("max_clock_frequency", 0) or 0),
        "max_work_group_size": int(device.max_work_group_size),
        "max_work_item_sizes": [int(s) for s in device.max_work_item_sizes],
        "local_mem_bytes": int(device.local_mem_size),
        "global_mem_bytes": int(device.global_mem_size),
        "max_mem_alloc_bytes": int(device.max_mem_alloc_size),
        "fp64": bool(runtime.has_fp64(device)),
        "extensions": sorted(device.extensions.split()),
        # the GPU kernels' forms every check below ran with (clholo.host.tuning: a stored
        # tuning of this device, `clholo tune`, or the defaults)
        "tuning": {name: value for name, value in tuning.settings_for(device)},
        "tuning_stored": tuning.stored_entry(device) is not None
        if tuning.tuning_file() is not None else False,
    }


def _speed(queue, quick: bool) -> Dict[str, object]:
    """FFT and hologram timings (wall clock of the finished work, median of 3 after a warm-up)."""
    import pyopencl.array as cla

    import clholo
    from clholo import fft as F
    from clholo.host.scheduler import HologramRenderer

    def median_ms(fn, repeats=3) -> float:
        fn()
        queue.finish()
        times = []
        for _ in range(repeats):
            t = time.perf_counter()
            fn()
            queue.finish()
            times.append((time.perf_counter() - t) * 1e3)
        return float(np.median(times))

    n = 256 if quick else 1024
    rng = np.random.default_rng(0)
    x = cla.to_device(queue, _cplx(rng, (n, n)))
    plan = F.FFTPlan((n, n), np.complex64, queue=queue)
    out = cla.empty_like(x)
    fft_ms = median_ms(lambda: plan.execute(x, out=out))
    h, L = (128, 4) if quick else (512, 8)
    mpi = clholo.MPI(rng.random((L, h, h, 3)), rng.random((L, h, h)),
                     np.linspace(1e-3, 4e-3, L))
    r = HologramRenderer(mpi, clholo.Optics(), pad="auto", queue=queue, frames_per_batch=1)
    field_ = cla.empty(queue, (1, 3, h, h), np.complex64)
    holo_ms = median_ms(lambda: r.enqueue_batch(0, 1, field_))
    return {"fft_shape": [n, n], "fft_ms": round(fft_ms, 3), "hologram_shape": [h, h],
            "hologram_colours": 3, "hologram_layers": L, "hologram_padded": list(r.padded),
            "hologram_ms_per_layer": round(holo_ms / L, 3)}


def run_selftest(*, quick: bool = False, queue=None,
                 progress: Optional[Callable[[str], None]] = None,
                 families: Optional[List[str]] = None, speed: Optional[bool] = None,
                 seed: Optional[int] = None) -> SelfTestReport:
    """Run every kernel family against its NumPy reference on one device.

    Parameters
    ----------
    quick : bool
        Smaller speed measurement (FFT 256^2 and a 128 x 128 hologram instead of 1024^2 and
        512 x 512); the correctness checks are small either way.
    queue : pyopencl.CommandQueue, optional
        Default: :func:`clholo.host.runtime.get_queue` (``CLHOLO_DEVICE`` picks the device).
    progress : callable, optional
        Called with one line of text as each family starts.
    families : list of str, optional
        Only these families (names of :data:`FAMILIES`); default all.
    speed : bool, optional
        Measure the speed line; default yes except on the Oclgrind simulator.
    seed : int, optional
        Seed of the random inputs (default: fresh ones each run; the report records it).

    Returns
    -------
    SelfTestReport
        ``.passed``, ``.to_dict()``, ``.format_text()``. Failures (wrong results, or an
        exception such as a build error or a launch-limit error) are in the report; nothing is
        raised for them.

    Raises
    ------
    clholo.errors.EnvironmentProblem
        The device cannot compile even a one-line kernel (its compiler does not work here,
        e.g. PyPI's PoCL on a CPU newer than its LLVM): no check could run, so none is run;
        the message names the device and how to choose another.
    """
    import pyopencl as cl

    from clholo.host import runtime

    t_start = time.perf_counter()
    # probe first: on a device whose compiler does not work every family would fail with its
    # build log (some 60 of them) and the verdict would read as a bug in clholo
    problem = cannot_compile(queue.device if queue is not None else runtime.choose_device(),
                             given=queue is not None)
    if problem is not None:
        from clholo.errors import EnvironmentProblem

        raise EnvironmentProblem(problem)
    if queue is None:
        queue = runtime.get_queue()
    known = [f[0] for f in FAMILIES]
    if families is not None:
        unknown = sorted(set(families) - set(known))
        if unknown:
            raise ValueError(f"families={unknown} are not self-test families; choose from "
                             f"{known}")
    if seed is None:
        seed = int.from_bytes(os.urandom(4), "little")
    rng = np.random.default_rng(seed)
    device = queue.device
    checks: List[CheckResult] = []
    # program builds are counted apart from the checks: a first run on a GPU spends most of
    # its time compiling (39 s on an H100, issue 22)
    builds = runtime.BuildCounter(device)
    t_checks = time.perf_counter()
    with builds:
        for name, fn, _files in FAMILIES:
            if families is not None and name not in families:
                continue
            if progress is not None:
                progress(f"checking {name} ...")
            ck = _Checker(name, checks)
            try:
                fn(queue, rng, ck, quick)
            except Exception as exc:  # noqa: BLE001 - a family that cannot even start
                ck.fail(name, exc)
        t_checks = time.perf_counter() - t_checks
        if speed is None:
            speed = not is_simulator(device)
        t_speed = time.perf_counter()
        with runtime.BuildCounter() as speed_builds:
            if speed:
                if progress is not None:
                    progress("measuring speed ...")
                try:
                    speed_line = _speed(queue, quick)
                except Exception as exc:  # noqa: BLE001
                    speed_line = {"skipped": f"the measurement failed: {exc}"}
            else:
                speed_line = {"skipped": "on the Oclgrind simulator" if is_simulator(device)
                              else "not asked for"}
        t_speed = time.perf_counter() - t_speed
    timing = {"build_seconds": round(builds.seconds, 4),
              "check_seconds": round(t_checks - (builds.seconds - speed_builds.seconds), 4),
              "speed_seconds": round(t_speed - speed_builds.seconds, 4),
              "programs_built": builds.programs, "compiler_cache": builds.cache,
              "build": builds.to_dict()}
    drivers_found: Dict[str, object] = {}
    if not device.type & cl.device_type.GPU:
        from clholo.host import drivers

        libs = drivers.find_vendor_libraries()
        drivers_found = {"libraries": [lib.to_dict() for lib in libs],
                         "advice": drivers.driver_advice(
                             libs, situation="The device is not a GPU")}
    versions = {"clholo": _clholo_version(), "python": platform.python_version(),
                "numpy": np.__version__, "pyopencl": cl.VERSION_TEXT,
                "os": f"{platform.system()} {platform.release()} {platform.machine()}",
                "input_seed": str(seed)}
    return SelfTestReport(device=device_facts(device), checks=checks,
                          kernels_launched=runtime.launched_kernels(), speed=speed_line,
                          quick=bool(quick), versions=versions,
                          seconds=time.perf_counter() - t_start, timing=timing,
                          drivers=drivers_found)


def cannot_compile(device, *, given: bool = False) -> Optional[str]:
    """``None`` when ``device`` (a ``pyopencl.Device``) compiles a one-line kernel
    (:func:`clholo.host.runtime.device_build_problem`), else one line saying that it cannot,
    how it was chosen and how to choose another.

    Parameters
    ----------
    device : pyopencl.Device
        The device the checks would run on.
    given : bool
        The caller gave its queue (the device was not chosen by clholo's rule).
    """
    from clholo.host import runtime

    problem = runtime.device_build_problem(device)
    if problem is None:
        return None
    try:
        selector = next(d.selector for d in runtime.list_devices()
                        if runtime.choose_device(d.selector) == device)
    except (StopIteration, runtime.NoDeviceError):
        selector = "?"
    what = f"{selector} ({device.platform.name.strip()} / {device.name.strip()})"
    fix = ("choose another device with CLHOLO_DEVICE=P:D (`clholo info` lists the devices and "
           "says which cannot compile)")
    variable = next((v for v in ("CLHOLO_DEVICE", "PYOPENCL_CTX") if os.environ.get(v)), None)
    if given:
        chosen = f"the queue's device {what}"
        fix = "give a queue on another device, or " + fix
    elif variable is not None:
        chosen = f"{variable}={os.environ[variable]!r} picks device {what}, which"
    else:
        chosen = f"this machine's OpenCL device {what}"
        if runtime.UNKNOWN_CPU in problem:
            fix = ("install a PoCL whose LLVM knows this CPU (e.g. Debian/Ubuntu `apt-get "
                   "install pocl-opencl-icd`; PyPI's pocl-binary-distribution 3.0 has LLVM 14), "
                   "then " + fix)
        else:
            fix = "install a working OpenCL driver for it (docs/selftest.md), or " + fix
    return (f"{chosen} cannot compile OpenCL kernels here ({problem}): no check can run on "
            f"it; {fix}")


def _clholo_version() -> str:
    import clholo

    return getattr(clholo, "__version__", "?")


# ---------------------------------------------------------------------------------------------
