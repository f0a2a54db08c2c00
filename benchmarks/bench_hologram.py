"""MPI -> hologram: clholo vs the NumPy (complex64) and PyTorch versions, side by side (PyTorch
on CUDA when the OpenCL device is a GPU and torch has CUDA, else on the CPU; the table names
the device each ran on).

    python benchmarks/bench_hologram.py [--size 1024] [--layers 32] [--repeats 3] [--breakdown]
    python benchmarks/bench_hologram.py --breakdown-only --shape 1080x1920 --pad auto

Same as ``clholo bench``; see ``clholo/bench.py`` for what is timed. ``--breakdown`` then
times the pieces of one layer (composite, forward, inverse with the multiply, launches and
host work) on the renderer's own plans (``clholo.bench.run_hologram_breakdown``).
"""

import argparse
import sys
from pathlib import Path

if str(Path(__file__).resolve().parent) not in sys.path:  # loaded by path (the tests)
    sys.path.insert(0, str(Path(__file__).resolve().parent))
import _bench_args as _args  # noqa: E402

from clholo.bench import run_hologram_benchmark, run_hologram_breakdown


def main(argv=None) -> None:
    """Parse the arguments (every one checked before anything is measured), then time."""
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--size", type=_args.positive_int, default=1024)
    ap.add_argument("--layers", type=_args.positive_int, default=32)
    ap.add_argument("--repeats", type=_args.positive_int, default=3)
    ap.add_argument("--pad", type=_args.pad, default="2",
                    help="a factor >= 1, or 'auto' (default 2)")
    ap.add_argument("--no-scaling", action="store_true")
    ap.add_argument("--no-numpy", action="store_true",
                    help="leave out the NumPy version (seconds a call: spare a lent GPU's time)")
    ap.add_argument("--breakdown", action="store_true",
                    help="then time the pieces of one layer")
    ap.add_argument("--breakdown-only", action="store_true",
                    help="only the pieces of one layer (no peers)")
    ap.add_argument("--shape", type=_args.shape, default=None,
                    help="HxW of the breakdown's field (default: --size square), e.g. 1080x1920")
    a = ap.parse_args(argv)
    pad = a.pad
    if not a.breakdown_only:
        run_hologram_benchmark(size=a.size, layers=a.layers, repeats=a.repeats,
                               scaling=not a.no_scaling, pad=pad, numpy=not a.no_numpy)
    if a.breakdown or a.breakdown_only:
        shape = a.shape if a.shape else a.size
        run_hologram_breakdown(size=shape, layers=a.layers, repeats=max(a.repeats, 5), pad=pad)


if __name__ == "__main__":
    main()
