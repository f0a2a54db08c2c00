"""The GPU FFT kernel's build and planning variants side by side in one process (issue 23).

    python benchmarks/fft_variants.py                     # the default device, default sizes
    bash .gpu/run-on-gpu.sh python3 benchmarks/fft_variants.py --shape 1080x1920 \\
        --sizes 1125x1944,2250x2250,2187x3888 --sgd 2048

A GPU is lent rarely: this measures, in one run, the choices that can only be judged there.
Each variant is a set of ``clholo.fft`` settings and tunable settings (:mod:`clholo.tuning`;
``clholo tune`` measures those on a device and stores the fastest), applied while its plans are
built and restored after (programs are cached per set of defines, so the variants do not share kernels):

* ``fixed``: the default. ``fft_lines`` is built per line length (``FFT_N``, ``FFT_L``,
  ``FFT_WG``, ``FFT_STAGE_LIST``): radices, strides and divisors are constants.
* ``unfused``, ``fused32``, ``fused64``: stages of radix at most 8 (the butterfly radices
  alone), 32 or 64 in both local-memory plans. By default the two-buffer plan takes radices
  up to 8 (``_FUSED_RADIX_MAX``) and the in-place plan up to 16
  (``_INPLACE_FUSED_RADIX_MAX``): a stage of radix R1 R2 runs its DFT in registers, so a line
  takes fewer stages through local memory.
* ``fused16``: the two-buffer plan with radices up to 16 too.
* ``inplace8``: the in-place plan (lines beyond two buffers) with radices up to 8.
* ``inplace-direct``, ``inplace-direct8``: the in-place plan with its first stage on the
  source and its last on the destination (the tunable setting ``inplace_direct``, off by default until measured),
  with radices up to 16 or 8.
* ``cols-inplace``, ``cols-inplace-direct``: column passes that two buffers hold fewer than
  four of per group (less than a 32-byte sector of each row: 1125 and 2048 points) on the
  in-place plan, which holds more (five and two on an H100), also with the in-place plan's
  first and last stages on global memory (the tunable setting ``inplace_columns``, off by
  default until measured; with the two-buffer plan's stages, so the same bits).
* ``cols-split``, ``cols-split1024``: the same columns on the split plan (one component at a
  time in local memory, up to 512 or 1024 work-items a group), which holds more still (ten and
  five on an H100; the tunable setting ``split_columns``, off by default until measured; the
  two-buffer plan's stages too), and the in-place plan's columns that it holds two of (2187,
  2250 points: five, with its stages).
* ``row-pitch``: the row spectrum's rows 128 bytes longer where they are a multiple of 4 KiB
  (``clholo.fft.row_pitch``; CPUs do this, GPUs not until measured: the tunable setting ``row_pitch``); the
  render's and SGD's profiles show it at 1024^2 and 2048^2 grids (``--shape 1024x1024``).
* ``batch-fast``: the round trips' work-groups in batch-first order (``FFT_BATCH_FAST``, as
  the CPU strips run: a render's frames and colours of one group of lines one after another,
  sharing the layer's colour, alpha and transfer function in the caches;
  the tunable setting ``batch_fast``, off on GPUs until measured). The render profile shows it (T C fields
  a launch).
* ``mid-quads``: the round trips' mid callback (the render's composite, SGD's Adam step) by
  four elements adjacent along a row of the frame, in a sweep over local memory
  (``FFT_MID_QUADS``, the tunable setting ``mid_quads``, off on GPUs until measured): one Philox block per
  four pixels instead of one per pixel, for a pass over local memory and a barrier more. The
  render profile's row round trips show it.
* ``layer-planes``: the render's layers held as planes (``layer_layout="planes"``,
  the tunable setting ``layer_planes``): ``sqrt(c a)`` ``[H, C, W]`` and
  ``sqrt(1 - a)`` ``[H, W]`` made once, read coalesced, instead of one channel of ``[H*W, C]``
  gathered and two square roots per pixel, colour and frame. ``planes-quads``: both.
* ``launch18``, ``launch20``: 2^18 or 2^20 complex samples per compute unit in a GPU launch
  instead of 2^19 (the tunable setting ``launch_samples``: a render's frames per launch); only
  renders of more frames than a launch takes see it (``--frames 24``).
* ``generic``: one ``fft_lines`` program for every size, the length and lines per group as
  arguments (clholo before 2026-11-26).
* ``local48``: 48 KiB of local memory per work-group for every pass's two buffers (by
  default 32 KiB, and 48 KiB only for columns it puts two to a group: 1125, 1200 points).
* ``inplace``: every line in one local buffer, each stage through registers (the plan of lines
  too long for two buffers): 1125-point columns four to a group.
* ``no-split``: lines that the local memory holds only one component of (7680 and 8192
  points of complex64 in 48 KiB) as before the split plan (``FFT_SPLIT``, 2026-11-27): one
  global-memory launch per radix stage, and no round trip (a 4K render at pad 2 then takes
  four passes a layer). Other bits: compare times and errors, not bits.

For each variant: the per-kernel profile of a render (``clholo.bench.profile_render``: the
layer's two kernels), optionally of an SGD iteration (``--sgd N``), and the device time of
``FFTPlan.execute`` at ``--sizes`` (kernel time from profiling events, median of rounds). Times
are printed with their ratio to the first variant. Runs on any OpenCL device; on PoCL the GPU
kernels run through ``variant="gpu"`` plans only where a test asks, so there it measures
nothing about the default path.
"""

import argparse
import contextlib
import statistics
import sys
from pathlib import Path

import numpy as np

if str(Path(__file__).resolve().parent) not in sys.path:  # loaded by path (the tests)
    sys.path.insert(0, str(Path(__file__).resolve().parent))
import _bench_args as _args  # noqa: E402

from clholo import fft as F
from clholo import tuning
from clholo.bench import profile_render, profile_sgd
from clholo.host import runtime

VARIANTS = {
    "fixed": {},
    "unfused": {"_FUSED_RADIX_MAX": 8, "_INPLACE_FUSED_RADIX_MAX": 8},
    "fused16": {"_FUSED_RADIX_MAX": 16},
    "fused32": {"_FUSED_RADIX_MAX": 32, "_INPLACE_FUSED_RADIX_MAX": 32},
    "fused64": {"_FUSED_RADIX_MAX": 64, "_INPLACE_FUSED_RADIX_MAX": 64},
    "inplace8": {"_INPLACE_FUSED_RADIX_MAX": 8},
    "inplace-direct": {"tuning.inplace_direct": True},
    "inplace-direct8": {"tuning.inplace_direct": True, "_INPLACE_FUSED_RADIX_MAX": 8},
    "cols-inplace": {"tuning.inplace_columns": True},
    "cols-inplace-direct": {"tuning.inplace_columns": True, "tuning.inplace_direct": True},
    "cols-split": {"tuning.split_columns": 512},
    "cols-split1024": {"tuning.split_columns": 1024},
    "row-pitch": {"tuning.row_pitch": True},
    "batch-fast": {"tuning.batch_fast": True},
    "mid-quads": {"tuning.mid_quads": True},
    "layer-planes": {"tuning.layer_planes": True},
    "planes-quads": {"tuning.mid_quads": True, "tuning.layer_planes": True},
    "launch18": {"tuning.launch_samples": 1 << 18},
    "launch20": {"tuning.launch_samples": 1 << 20},
    "generic": {"_fixed_line_defines": lambda *a: ()},
    "local48": {"_GPU_LOCAL_BYTES": 48 * 1024},
    "inplace": {"_GPU_LOCAL_BYTES": 1},
    "no-split": {"_GPU_SPLIT": False},
}


@contextlib.contextmanager
def variant(name):
    """``clholo.fft`` with the variant's settings, restored on exit; settings named
    ``tuning.*`` are the tunable ones (:func:`clholo.tuning.override`). Plans built inside
    ignore the device's stored tuning (:func:`clholo.tuning.untuned`): the variant says."""
    settings = VARIANTS[name]
    tuned = {k.split(".", 1)[1]: v for k, v in settings.items() if k.startswith("tuning.")}
    module = {k: v for k, v in settings.items() if not k.startswith("tuning.")}
    saved = {k: getattr(F, k) for k in module}
    try:
        for k, v in module.items():
            setattr(F, k, v)
        with tuning.untuned(), tuning.override(**tuned):
            yield
    finally:
        for k, v in saved.items():
            setattr(F, k, v)


def fft_kernel_ms(queue, shape, rounds):
    """Median kernel time (ms) of one ``FFTPlan.execute`` of complex64 ``shape``, and the
    plan's passes with the result's relative L2 error against NumPy's complex128 FFT as text
    (a variant that computes something else shows there, not only in its time)."""
    plan = F.FFTPlan(shape, np.complex64, queue=queue)
    rng = np.random.default_rng(0)
    x = (rng.standard_normal(shape) + 1j * rng.standard_normal(shape)).astype(np.complex64)
    xd = F.cl_array.to_device(queue, x)
    out = F.cl_array.empty_like(xd)
    plan.execute(xd, out=out)
    want = np.fft.fft2(x.astype(np.complex128))
    err = float(np.linalg.norm(out.get() - want) / np.linalg.norm(want))
    times = []
    for _ in range(rounds):
        with runtime.KernelRecorder() as rec:
            plan.execute(xd, out=out)
            queue.finish()
        times.append(sum(float(r["seconds"]) for r in rec.summary()))
    passes = " + ".join(f"{p.axis} {p.kind} {p.launches[0].lsize or ''}"
                        f"{' split' if dict(p.defines).get('FFT_SPLIT') else ' in place' if dict(p.defines).get('FFT_INPLACE') else ''}"
                        for p in plan.geometry.passes)
    return statistics.median(times) * 1e3, f"{passes}; error {err:.1e}"


def main(argv=None):
    """Exit status 1 when any variant failed (its row says why), after the others ran."""
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--variants", type=_args.names(VARIANTS, allow_empty=False),
                    default="fixed,inplace-direct,inplace-direct8,inplace8,fused16,unfused",
                    help=f"comma-separated, the first is the baseline, from "
                         f"{', '.join(VARIANTS)} (default: %(default)s)")
    ap.add_argument("--shape", type=_args.shape, default="1080x1920",
                    help="HxW of the render profiled")
    ap.add_argument("--layers", type=_args.positive_int, default=32)
    ap.add_argument("--frames", type=_args.positive_int, default=3)
    ap.add_argument("--colours", type=int, default=3, choices=(1, 3))
    ap.add_argument("--pad", type=_args.pad, default="auto",
                    help="padding of the render and of --sgd: 'auto' (default) or a factor >= 1")
    ap.add_argument("--repeats", type=_args.positive_int, default=3,
                    help="renders profiled per variant")
    ap.add_argument("--sizes", type=_args.fft_shapes, default="1125x1944,2250x2250",
                    help="FFT shapes timed per variant (HxW, comma-separated, sizes 2^a 3^b 5^c; "
                         "'' for none)")
    ap.add_argument("--rounds", type=_args.positive_int, default=20,
                    help="FFT executions timed per size")
    ap.add_argument("--sgd", type=_args.positive_int, default=None, metavar="N",
                    help="also profile an SGD iteration of N x N per variant")
    a = ap.parse_args(argv)
    names = a.variants
    (height, width), sizes = a.shape, a.sizes
    queue = runtime.get_queue()
    print(f"device: {queue.device.name.strip()}; render L={a.layers} {height}x{width} "
          f"{'RGB' if a.colours == 3 else 'one colour'} T={a.frames} pad {a.pad}; FFT sizes "
          f"{sizes}")
    rows = []  # (what, variant, ms, note)
    for name in names:
        try:
            with variant(name):
                measure_variant(name, rows, queue, a, height, width, sizes)
        except Exception as exc:  # one variant's failure (a device limit) must not end the run
            rows.append(("error", name, float("nan"), f"{type(exc).__name__}: {exc}"[:300]))
            print(f"{name}: {type(exc).__name__}: {exc}", flush=True)
    base = {what: ms for what, v, ms, _ in rows if v == names[0]}
    print(f"\n| what | variant | ms | speed vs {names[0]} | note |\n|---|---|---|---|---|")
    for what, v, ms, note in sorted(rows, key=lambda r: ([w for w, *_ in rows].index(r[0]),
                                                         names.index(r[1]))):
        ratio = f"{base[what] / ms:.2f}x" if base.get(what) and ms > 0 else ""
        print(f"| {what} | {v} | {_args.ms(ms)} | {ratio} | {note} |")
    failed = [v for what, v, *_ in rows if what == "error"]
    if failed:
        sys.exit(f"fft_variants.py: {len(failed)} of {len(names)} variants failed "
                 f"({', '.join(failed)}): see their error rows")


def measure_variant(name, rows, queue, a, height, width, sizes):
    """Append ``(what, variant, ms, note)`` rows for one variant (its settings applied): the
    render's per-kernel profile, SGD's iteration with ``--sgd``, and the FFT sizes."""
    pad = a.pad
    r = profile_render(height=height, width=width, colours=a.colours, layers=a.layers,
                       frames=a.frames, pad=pad, repeats=a.repeats, queue=queue)
    rows.append(("render: kernels per render", name, r["kernel_s"] * 1e3, r["what"]))
    for k in r["rows"]:
        rows.append((f"  {k['label']}", name, float(k["seconds"]) / r["repeats"] * 1e3,
                     f"{float(k['floor_ratio']):.2f}x copy" if k["floor_ratio"] else ""))
    if a.sgd:
        s = profile_sgd(size=a.sgd, pad=pad, iterations=10, queue=queue)
        rows.append((f"SGD {a.sgd}^2: kernels per iteration", name, s["kernel_s"] * 1e3,
                     s["what"]))
    for shape in sizes:
        ms, passes = fft_kernel_ms(queue, shape, a.rounds)
        rows.append((f"FFT {shape[0]}x{shape[1]}", name, ms, passes))


if __name__ == "__main__":
    main()
