"""Soak test of the display loop (outside CI): run ``clholo.host.display_loop.DisplayLoop`` on a
memory display for a while and sample, every few seconds, the process's resident memory and the
OpenCL buffers alive (every ``pyopencl`` memory object referenced from a Python object: device
arrays, FFT plan buffers, transfer-function caches). Flat lines = no leak.

    python benchmarks/soak_display.py --seconds 150 --size 128 --layers 8 --interval 10

Prints one row per sample and a summary; ``--csv`` also writes the samples.
"""

from __future__ import annotations

import argparse
import gc
import os
import sys
import threading
import time
from pathlib import Path

import numpy as np

if str(Path(__file__).resolve().parent) not in sys.path:  # loaded by path (the tests)
    sys.path.insert(0, str(Path(__file__).resolve().parent))
import _bench_args as _args  # noqa: E402


def rss_bytes() -> int:
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


def live_cl_buffers():
    """(count, bytes) of distinct OpenCL memory objects referenced from Python objects."""
    import pyopencl as cl

    seen = {}
    for obj in gc.get_objects():
        for ref in gc.get_referents(obj):
            if isinstance(ref, cl.MemoryObject):
                try:
                    seen[ref.int_ptr] = ref.size
                except cl.LogicError:
                    pass
    return len(seen), sum(seen.values())


def main() -> None:
    from clholo.host.display_loop import (DisplayLoop, dpac_encoder, phase_quantize_encoder,
                                          summarize)
    from clholo.scene import MPI, Optics
    from clholo.tools.slm import MemoryDisplay

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=_args.positive_float, default=150.0)
    ap.add_argument("--size", type=_args.positive_int, default=128, help="render size N (N x N)")
    ap.add_argument("--layers", type=_args.positive_int, default=8)
    ap.add_argument("--frames", type=_args.positive_int, default=2, help="frames per batch")
    ap.add_argument("--interval", type=_args.positive_float, default=10.0,
                    help="seconds between samples")
    ap.add_argument("--swap-every", type=_args.positive_float, default=30.0,
                    help="swap to a new random scene every this many seconds")
    ap.add_argument("--csv", type=_args.output_file, default=None,
                    help="write the memory samples here")
    ap.add_argument("--log", type=_args.output_file, default=None,
                    help="stream the loop's pattern log here (CSV)")
    ap.add_argument("--encoding", choices=["phase", "dpac"], default="phase",
                    help="the loop's encoder (dpac: double-phase coding at 4 cm, linear LUT)")
    ap.add_argument("--keep", type=_args.at_least(0), default=2000,
                    help="records the loop keeps in memory (the rest only in --log)")
    args = ap.parse_args()

    rng = np.random.default_rng(0)
    optics = Optics(pitch=8e-6, wavelengths=(638e-9, 520e-9, 450e-9))

    def scene():
        L, N = args.layers, args.size
        return MPI(color=rng.uniform(0, 1, (L, N, N, 3)), alpha=rng.uniform(0, 1, (L, N, N)),
                   depths=1e-3 + 1e-3 * np.arange(L))

    display = MemoryDisplay(480, 270, pace=True, refresh_hz=60.0)   # reduced-size SLM
    encode = (dpac_encoder(optics, z_slm=0.04) if args.encoding == "dpac"
              else phase_quantize_encoder())
    loop = DisplayLoop(scene(), optics, display, encode,
                       frames_per_batch=args.frames, log_path=args.log, keep_records=args.keep)
    shown = [0]
    samples = []
    done = threading.Event()

    def sampler():
        t0 = time.monotonic()
        next_swap = args.swap_every
        while not done.wait(args.interval):
            el = time.monotonic() - t0
            if el >= next_swap:
                loop.set_scene(scene())
                next_swap += args.swap_every
            n, b = live_cl_buffers()
            samples.append((el, rss_bytes(), n, b, shown[0], loop.batches_rendered))
            print(f"{el:7.1f} s  RSS {samples[-1][1] / 2**20:8.1f} MiB  CL buffers {n:4d} "
                  f"{b / 2**20:8.2f} MiB  patterns {samples[-1][4]:6d}  batches "
                  f"{samples[-1][5]:5d}", flush=True)

    n, b = live_cl_buffers()
    print(f"    0.0 s  RSS {rss_bytes() / 2**20:8.1f} MiB  CL buffers {n:4d} {b / 2**20:8.2f} MiB "
          f"(before start)", flush=True)
    th = threading.Thread(target=sampler, daemon=True)
    th.start()
    def count(_rec):
        shown[0] += 1

    records = loop.run(seconds=args.seconds, on_pattern=count)
    done.set()
    th.join()
    s = summarize(records, 3)
    print(f"last {len(records)} records of {shown[0]} patterns:")
    print("summary:", {k: (round(v, 4) if isinstance(v, float) else v) for k, v in s.items()})
    if len(samples) >= 3:
        warm = samples[1:]
        rss = [x[1] for x in warm]
        cl_b = [x[3] for x in warm]
        print(f"after the first sample: RSS {min(rss) / 2**20:.1f}..{max(rss) / 2**20:.1f} MiB, "
              f"CL buffers {min(cl_b) / 2**20:.2f}..{max(cl_b) / 2**20:.2f} MiB")
    if args.csv:
        with open(args.csv, "w") as fh:
            fh.write("elapsed_s,rss_bytes,cl_buffers,cl_bytes,patterns,batches\n")
            for row in samples:
                fh.write(",".join(f"{v:.3f}" if isinstance(v, float) else str(v)
                                  for v in row) + "\n")


if __name__ == "__main__":
    main()
