"""Time clholo.fft against other FFTs, side by side in one run.

Forward 2D complex64 FFTs of 512^2 .. 4096^2 and a batch of 8 x 1024^2. Every contender is timed
once per round and the rounds interleave the contenders, so that the drift of a shared machine
hits all of them alike; the table reports medians, GFLOP/s (5 N log2 N per transform) and each
one's time divided by clholo's device-resident time (> 1: clholo is faster). A "# ran on" line
names each contender's device.

Contenders (the missing ones are skipped):
  clholo dev    plan.execute on device arrays (input and output stay on the device)
  clholo np     clholo.fft.fft2 on NumPy arrays, into the caller's out array (on a CPU device
                the kernels read and write the NumPy arrays in place: no copies)
  numpy         np.fft.fft2
  scipy w2      scipy.fft.fft2(workers=2)
  pyfftw 2thr   pyfftw.builders.fft2(threads=2, FFTW_MEASURE), planning not timed
  torch         torch.fft.fft2 on the CPU, 2 threads ("torch cpu"); on CUDA ("torch cuda",
                input already on the GPU, torch.cuda.synchronize() before and after) when the
                OpenCL device is a GPU and torch.cuda.is_available() (clholo.bench.torch_peer)
  pyvkfft cl    pyvkfft.opencl.VkFFTApp on the same OpenCL queue, device-resident

Usage::

    python benchmarks/bench_fft.py [--sizes 512,1024,2048,4096] [--batch 8x1024] [--rounds 15]
                                   [--variant auto|cpu|gpu] [--skip numpy,torch]
"""

from __future__ import annotations

import argparse
import datetime
import math
import platform
import sys
import time
from pathlib import Path

import numpy as np

if str(Path(__file__).resolve().parent) not in sys.path:  # loaded by path (the tests)
    sys.path.insert(0, str(Path(__file__).resolve().parent))
import _bench_args as _args  # noqa: E402

#: the contenders --skip names (every one but clholo's own)
SKIPPABLE = ("numpy", "scipy", "pyfftw", "torch", "pyvkfft")


def _median_ms(times):
    return 1e3 * float(np.median(times)) if times else float("nan")


def _contenders(shape, a, queue, variant, skip, where=None):
    """(name, callable) pairs; each callable runs one forward FFT and waits for it. ``where``,
    a dict, receives name -> the device it runs on."""
    import pyopencl.array as cla
    from clholo import fft as F

    out = []
    where = {} if where is None else where
    cl_dev = f"{queue.device.platform.name.strip()} / {queue.device.name.strip()}"
    where.update({"clholo dev": cl_dev, "clholo np": cl_dev, "numpy": "CPU (host)",
                  "scipy w2": "CPU (host)", "pyfftw 2thr": "CPU (host)", "pyvkfft cl": cl_dev})
    plan = F.FFTPlan(shape, np.complex64, queue=queue, variant=variant)
    d_in = cla.to_device(queue, a)
    d_out = cla.empty(queue, shape, np.complex64)

    def clholo_dev():
        plan.execute(d_in, out=d_out)
        queue.finish()

    out.append(("clholo dev", clholo_dev))
    np_out = np.empty_like(a)
    out.append(("clholo np", lambda: F.fft2(a, out=np_out, queue=queue)))

    if "numpy" not in skip:
        out.append(("numpy", lambda: np.fft.fft2(a)))
    if "scipy" not in skip:
        try:
            import scipy.fft

            out.append(("scipy w2", lambda: scipy.fft.fft2(a, workers=2)))
        except ImportError:
            pass
    if "pyfftw" not in skip:
        try:
            import pyfftw

            src = pyfftw.empty_aligned(shape, np.complex64)
            src[...] = a
            fw = pyfftw.builders.fft2(src, threads=2, planner_effort="FFTW_MEASURE")
            out.append(("pyfftw 2thr", lambda: fw()))
        except Exception as exc:  # ImportError or a planner failure: report and go on
            print(f"# pyfftw skipped: {exc}", file=sys.stderr)
    if "torch" not in skip:
        try:
            from clholo.bench import torch_peer

            peer = torch_peer(queue.device, threads=2)
            if peer is None:
                raise ImportError("torch is not installed")
            torch = peer.torch
            t = torch.from_numpy(a).to(peer.device)
            name = f"torch {peer.kind}"

            def torch_fft():
                peer.synchronize()
                torch.fft.fft2(t)
                peer.synchronize()

            out.append((name, torch_fft))
            where[name] = f"{peer.label}, {peer.where}"
        except Exception as exc:
            print(f"# torch skipped: {exc}", file=sys.stderr)
    if "pyvkfft" not in skip:
        try:
            from pyvkfft.opencl import VkFFTApp

            app = VkFFTApp(shape, np.complex64, queue, ndim=2, inplace=False)
            v_out = cla.empty(queue, shape, np.complex64)

            def vk():
                app.fft(d_in, v_out)
                queue.finish()

            vk()
            err = np.linalg.norm(v_out.get() - np.fft.fft2(a)) / np.linalg.norm(np.fft.fft2(a))
            if err > 1e-4:
                raise RuntimeError(f"wrong result on this device (rel. error {err:.2g})")
            out.append(("pyvkfft cl", vk))
        except Exception as exc:
            print(f"# pyvkfft skipped: {exc}", file=sys.stderr)
    return out


def run(shape, queue, variant, rounds, skip, budget_s, where=None):
    rng = np.random.default_rng(1)
    a = (rng.standard_normal(shape) + 1j * rng.standard_normal(shape)).astype(np.complex64)
    cands = _contenders(shape, a, queue, variant, skip, where)
    # warm-up: builds, plans, caches; and an estimate of each one's cost for the round count
    cost = {}
    for name, f in cands:
        f()
        t0 = time.perf_counter()
        f()
        cost[name] = time.perf_counter() - t0
    per_round = sum(cost.values())
    n_rounds = max(min(rounds, 3), min(rounds, int(budget_s / max(per_round, 1e-9))))
    times = {name: [] for name, _ in cands}
    for r in range(n_rounds):
        order = cands if r % 2 == 0 else cands[::-1]  # alternate order: no fixed neighbour
        for name, f in order:
            t0 = time.perf_counter()
            f()
            times[name].append(time.perf_counter() - t0)
    return {name: _median_ms(t) for name, t in times.items()}, n_rounds


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", type=_args.fft_shapes, default="512,1024,2048,4096",
                    help="N (N x N) or HxW entries, comma-separated (e.g. 1080x1920), sizes "
                         "2^a 3^b 5^c")
    ap.add_argument("--batch", type=_args.batch, default="8x1024",
                    help="BxN for a batch of B NxN transforms; '' for none")
    ap.add_argument("--rounds", type=_args.positive_int, default=15,
                    help="timed rounds per shape (fewer where --budget runs out, but not fewer "
                         "than 3)")
    ap.add_argument("--budget", type=_args.positive_float, default=20.0,
                    help="seconds of timing per shape")
    ap.add_argument("--variant", default="auto", choices=("auto", "cpu", "gpu", "gpu-global"))
    ap.add_argument("--skip", type=_args.names(SKIPPABLE), default="",
                    help=f"comma-separated contenders to leave out, of {', '.join(SKIPPABLE)}")
    a = ap.parse_args(argv)

    skip = set(a.skip)
    shapes = list(a.sizes)
    if a.batch[0]:
        shapes.append(a.batch)
    if not shapes:
        ap.error("--sizes and --batch name no transform to time")

    from clholo.host import runtime

    queue = runtime.get_queue()

    dev = queue.device
    print(f"# clholo.fft benchmark, {datetime.date.today()}, {platform.node()}, "
          f"{dev.platform.name.strip()} / {dev.name.strip()}, variant={a.variant}")
    print(f"# command: python {' '.join(sys.argv)}")
    print("# forward 2D FFT complex64, median ms of interleaved rounds; "
          "ratio = time / clholo dev time; GFLOP/s = 5 N log2 N / time")
    header = f"{'shape':>14} {'contender':>12} {'ms':>9} {'GFLOP/s':>8} {'ratio':>7}"
    print(header)
    print("-" * len(header))
    failed = []
    printed_where = False
    for shape in shapes:
        where = {}
        label = "x".join(str(s) for s in shape)
        try:
            res, n_rounds = run(shape, queue, a.variant, a.rounds, skip, a.budget, where)
        except Exception as exc:  # one shape's failure (a device limit) must not end the run
            failed.append(label)
            print(f"{label:>14} failed: {type(exc).__name__}: {exc}"[:400], flush=True)
            continue
        n = shape[-1] * shape[-2]
        batch = int(np.prod(shape[:-2])) if len(shape) > 2 else 1
        flops = 5.0 * n * math.log2(n) * batch
        ref = res["clholo dev"]
        for name, ms in res.items():
            print(f"{label:>14} {name:>12} {_args.ms(ms):>9} {flops / ms * 1e-6:8.1f} "
                  f"{ms / ref:7.2f}")
        print(f"{'':>14} ({n_rounds} rounds)")
        if not printed_where:
            printed_where = True
            print("# ran on: " + "; ".join(f"{name}: {where[name]}" for name in res))
        sys.stdout.flush()
    if failed:
        sys.exit(f"bench_fft.py: {len(failed)} of {len(shapes)} shapes failed: {', '.join(failed)}")


if __name__ == "__main__":
    main()
