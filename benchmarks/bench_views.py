"""Operators on holograms, side by side in one run: a focal slice, a pupil view (refocus and
pupil in one spectrum pass) and the STFT light field, against their NumPy references.

    python benchmarks/bench_views.py [--size 256] [--frames 8] [--repeats 3]

Prints the best of ``repeats`` wall times and the ratios to the focal slice (the pupil view
should cost about the same: the same two FFTs per frame plus a mask kernel).
"""

import argparse
import sys
import time
from pathlib import Path

import numpy as np

if str(Path(__file__).resolve().parent) not in sys.path:  # loaded by path (the tests)
    sys.path.insert(0, str(Path(__file__).resolve().parent))
import _bench_args as _args  # noqa: E402

from clholo import Optics, focal_stack, reference, views


def best(fn, repeats):
    fn()  # warm-up: programs, plans, transfer functions
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def main():
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--size", type=_args.positive_int, default=256)
    ap.add_argument("--frames", type=_args.positive_int, default=8)
    ap.add_argument("--repeats", type=_args.positive_int, default=3)
    a = ap.parse_args()
    rng = np.random.default_rng(0)
    optics = Optics()
    n, T = a.size, a.frames
    holo = (rng.standard_normal((T, 3, n, n)) + 1j * rng.standard_normal((T, 3, n, n))
            ).astype(np.complex64)
    d = 4e-3
    cases = {
        "focal slice (device)": lambda: focal_stack(holo, optics, [d], pad=2),
        "pupil view (device)": lambda: views.pupil_view(holo, optics, focus_depth=d,
                                                        angles_rad=[(0.01, 0.0)], pad=2),
        "3 pupil views (device)": lambda: views.pupil_view(
            holo, optics, focus_depth=d, angles_rad=[(-0.01, 0.0), (0.0, 0.0), (0.01, 0.0)],
            pad=2),
        "light field w=16 (device)": lambda: views.light_field(holo, optics, window=16),
        "pupil view (NumPy ref)": lambda: reference.pupil_view(
            holo, d, wavelengths=optics.wavelengths, pitch=optics.pitch,
            angles_rad=[(0.01, 0.0)], pupil_angle_rad=0.005),
        "light field w=16 (NumPy ref)": lambda: reference.light_field(holo, window=16, hop=16),
    }
    results = {name: best(fn, a.repeats) for name, fn in cases.items()}
    base = results["focal slice (device)"]
    print(f"{n}x{n}, 3 colours, T = {T}, pad 2, best of {a.repeats}")
    for name, t in results.items():
        print(f"  {name:32s} {t * 1e3:9.1f} ms   x{t / base:6.2f} of the focal slice")


if __name__ == "__main__":
    main()
