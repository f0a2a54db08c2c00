"""MPI -> hologram: clholo vs the NumPy (complex64) and PyTorch CPU versions, side by side.

    python benchmarks/bench_hologram.py [--size 1024] [--layers 32] [--repeats 3]

Same as ``clholo bench``; see ``clholo/bench.py`` for what is timed.
"""

import argparse

from clholo.bench import run_hologram_benchmark

if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--size", type=int, default=1024)
    ap.add_argument("--layers", type=int, default=32)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--pad", type=float, default=2.0)
    ap.add_argument("--no-scaling", action="store_true")
    a = ap.parse_args()
    run_hologram_benchmark(size=a.size, layers=a.layers, repeats=a.repeats,
                           scaling=not a.no_scaling, pad=a.pad)
