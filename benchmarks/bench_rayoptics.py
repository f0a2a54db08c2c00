"""Ray-optics views (kernels/rayoptics.cl) against their NumPy reference, side by side.

One 32-layer RGB MPI with random content; an orthographic view (V = 1) and a 49-view incoherent
focal slice. The kernel and the reference take turns within each round; the table prints median
seconds and the ratio reference / kernel. Run: ``python benchmarks/bench_rayoptics.py [H W]``.
"""

import sys
import time

import numpy as np

from clholo import MPI, Optics
from clholo import reference as ref
from clholo.rayoptics import (incoherent_focal_slice, orthographic_view, pupil_directions,
                              shift_homographies)


def main(H=196, W=260, L=32, rounds=3):
    rng = np.random.default_rng(0)
    mpi = MPI(rng.uniform(0, 1, (L, H, W, 3)), rng.uniform(0, 1, (L, H, W)),
              np.linspace(2e-3, 6e-3, L))
    optics = Optics()
    orthographic_view(mpi, optics.pitch, angle_rad=(0.01, 0.0))  # build the kernel first
    one = shift_homographies((mpi.depths[None, :, None] - 4e-3) * np.tan([[0.01, 0.0]])[:, None]
                             / optics.pitch)[None]
    dirs = [pupil_directions(optics.max_angle_rad(c), 7) for c in range(3)]
    many = np.stack([shift_homographies((mpi.depths[None, :, None] - 4e-3)
                                        * np.tan(d)[:, None, :] / optics.pitch) for d in dirs])
    cases = {
        "orthographic view (V=1)": (
            lambda: orthographic_view(mpi, optics.pitch, angle_rad=(0.01, 0.0), focus_depth=4e-3),
            lambda: ref.warp_over_mean(mpi.color, mpi.alpha, np.repeat(one, 3, axis=0))),
        "incoherent focal slice (V=49 per channel)": (
            lambda: incoherent_focal_slice(mpi, optics, 4e-3),
            lambda: ref.warp_over_mean(mpi.color, mpi.alpha, many[:, :1])),  # 1 view, scaled
    }
    print(f"{H}x{W}, L={L}, 3 channels; median of {rounds} interleaved rounds")
    for name, (kern, numpy_ref) in cases.items():
        tk, tr = [], []
        for _ in range(rounds):
            for fn, times in ((kern, tk), (numpy_ref, tr)):
                t = time.perf_counter()
                fn()
                times.append(time.perf_counter() - t)
        k, r = np.median(tk), np.median(tr)
        if "V=49" in name:
            r *= 49  # the reference ran 1 of the 49 views; its time is linear in V
        print(f"{name:45s} kernel {k:8.3f} s   NumPy reference {r:8.2f} s   ratio {r / k:6.1f}")


if __name__ == "__main__":
    args = [int(a) for a in sys.argv[1:3]]
    main(*args)
