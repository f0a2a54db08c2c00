"""MPI -> hologram: clholo vs the NumPy (complex64) and PyTorch CPU versions, side by side.

    python benchmarks/bench_hologram.py [--size 1024] [--layers 32] [--repeats 3] [--breakdown]

Same as ``clholo bench``; see ``clholo/bench.py`` for what is timed. ``--breakdown`` then
times the pieces of one layer (composite, forward, inverse with the multiply, launches and
host work) on the renderer's own plans (``clholo.bench.run_hologram_breakdown``).
"""

import argparse

from clholo.bench import run_hologram_benchmark, run_hologram_breakdown

if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--size", type=int, default=1024)
    ap.add_argument("--layers", type=int, default=32)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--pad", type=float, default=2.0)
    ap.add_argument("--no-scaling", action="store_true")
    ap.add_argument("--breakdown", action="store_true",
                    help="then time the pieces of one layer")
    a = ap.parse_args()
    run_hologram_benchmark(size=a.size, layers=a.layers, repeats=a.repeats,
                           scaling=not a.no_scaling, pad=a.pad)
    if a.breakdown:
        run_hologram_breakdown(size=a.size, layers=a.layers, repeats=max(a.repeats, 5),
                               pad=a.pad)
