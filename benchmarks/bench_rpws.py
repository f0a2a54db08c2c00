"""RPWS against the MPI method on fox-50k.ply: quality (focal stacks) and speed, side by side.

    python benchmarks/bench_rpws.py quality [--size 256] [--splats 2000] [--frames 8]
    python benchmarks/bench_rpws.py cost [--size 256] [--splats 2000]

``quality``: the README's side camera, a seeded subset of the visible splats, green only.
RPWS with 2T frames (two independent halves of T frames) and the MPI of the same footprints
(:func:`clholo.baselines.rpws.primitives_to_mpi`) with L in {4, 8, 16, 32, 64} and T frames;
focal stacks at 5 depths over [near, far]; PSNR and SSIM (scikit-image) of each MPI against
RPWS half A after a least-squares scale fit, and RPWS half B against half A (the speckle
floor at this T). Times of every render in the same run.

``cost``: seconds per RPWS primitive-step and per MPI layer-step at the reduced size and at
1080 x 1920 (RGB, T = 1 frame per launch; both costs are linear in T), and the speed-up of the
MPI (L = 32) over RPWS extrapolated to K splats at the paper's scale (T = 24, RGB, 1080p).
Timings on a shared machine: compare the ratios printed within one run.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

if str(Path(__file__).resolve().parent) not in sys.path:  # loaded by path (the tests)
    sys.path.insert(0, str(Path(__file__).resolve().parent))
import _bench_args as _args  # noqa: E402

from clholo.progress import StepLog

FOX_R = np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]], float)


def fox_camera(width, height):
    from clholo.io.splats import Camera

    return Camera.from_fov(width, height, 50.0, rotation=FOX_R,
                           translation=-FOX_R @ np.array([0, 0, 1.25]) + np.array([0, 0, 4.0]))


def fox_primitives(size, splats, *, near, far, seed=0, height=None):
    from clholo.baselines import rpws
    from clholo.io.splats import read_ply

    g = read_ply("/work/shared/data/gaussians/fox-50k.ply")
    return rpws.primitives_from_splats(g, camera=fox_camera(size, height or size),
                                       near=near, far=far, max_splats=splats, seed=seed)


def scored(test, ref):
    """Mean PSNR and SSIM over focal slices after a least-squares scale of ``test``."""
    from skimage.metrics import peak_signal_noise_ratio, structural_similarity

    ref = np.asarray(ref, np.float64)
    test = np.asarray(test, np.float64)
    s = float(np.sum(test * ref) / np.sum(test * test))
    psnr, ssim = [], []
    for r, t in zip(ref, test):
        rng_ = float(r.max())
        psnr.append(peak_signal_noise_ratio(r, s * t, data_range=rng_))
        ssim.append(structural_similarity(r, s * t, data_range=rng_))
    return float(np.mean(psnr)), float(np.mean(ssim)), s


def quality(args):
    import clholo
    from clholo.baselines import rpws

    optics = clholo.Optics(wavelengths=(520e-9,))
    prims, info = fox_primitives(args.size, args.splats, near=args.near, far=args.far)
    prims = rpws.Primitives(prims.xy, prims.conic, prims.opacity, prims.color[:, 1:2],
                            prims.depths, prims.radius, prims.shape)
    print(f"fox-50k: {info['subsampling']}; {args.size}x{args.size}, green, T = {args.frames}")
    depths = np.linspace(args.near, args.far, 5)
    T = args.frames
    t = time.perf_counter()
    track = StepLog(mode="auto").tracker("RPWS primitive steps") if args.progress else None
    holo = rpws.render_rpws(prims, optics, frames=2 * T, seed=1, progress=track)
    t_rpws = (time.perf_counter() - t) / 2  # per T frames
    stack_a = clholo.focal_stack(holo[:T], optics, depths)[:, 0]
    stack_b = clholo.focal_stack(holo[T:], optics, depths)[:, 0]
    stack_2t = 0.5 * (stack_a + stack_b)
    rows = []
    p, s, k = scored(stack_b, stack_a)
    rows.append({"method": "RPWS (other T frames)", "L": len(prims), "psnr": p, "ssim": s,
                 "scale": k, "seconds": t_rpws, "psnr_2t": float("nan"),
                 "ssim_2t": float("nan")})
    clholo.render_hologram(rpws.primitives_to_mpi(prims, 4), optics, frames=T)  # warm-up
    for L in (4, 8, 16, 32, 64):
        mpi = rpws.primitives_to_mpi(prims, L)
        t = time.perf_counter()
        h = clholo.render_hologram(mpi, optics, frames=T, seed=2)
        t_mpi = time.perf_counter() - t
        st = clholo.focal_stack(h, optics, depths)[:, 0]
        p, s, k = scored(st, stack_a)
        p2, s2, _ = scored(st, stack_2t)
        rows.append({"method": "MPI", "L": L, "psnr": p, "ssim": s, "scale": k,
                     "seconds": t_mpi, "psnr_2t": p2, "ssim_2t": s2})
    print(f"{'method':24s} {'L':>6s} {'PSNR dB':>8s} {'SSIM':>6s} {'scale':>6s} "
          f"{'PSNR 2T':>8s} {'SSIM 2T':>7s} {'seconds':>8s} {'RPWS/this':>9s}")
    for r in rows:
        print(f"{r['method']:24s} {r['L']:6d} {r['psnr']:8.2f} {r['ssim']:6.3f} "
              f"{r['scale']:6.3f} {r['psnr_2t']:8.2f} {r['ssim_2t']:7.3f} {r['seconds']:8.2f} "
              f"{t_rpws / r['seconds']:9.1f}")
    return {"subsampling": info["subsampling"], "size": args.size, "frames": T,
            "focal_depths_m": depths.tolist(), "rows": rows}


def cost(args):
    import clholo
    from clholo.baselines import rpws
    from clholo.host.rpws import RPWSRenderer
    from clholo.host.scheduler import HologramRenderer

    optics = clholo.Optics()
    out = {}
    for label, (H, W) in (("reduced", (args.size, args.size)), ("1080p", (1080, 1920))):
        prims, info = fox_primitives(W, args.splats, near=args.near, far=args.far, height=H)
        r = RPWSRenderer(prims, optics, frames_per_batch=1)
        prim = r.time_per_primitive(1, primitives=args.steps)["seconds_per_primitive"]
        L = 8
        mpi = rpws.primitives_to_mpi(prims, L)
        hr = HologramRenderer(mpi, optics, frames_per_batch=1)
        hr.render(1).get()  # warm-up: programs, plans, transfer functions cached
        t = time.perf_counter()
        for _ in range(args.repeats):
            hr.render(1).get()
        layer = (time.perf_counter() - t) / args.repeats / L
        out[label] = {"shape": [H, W], "padded_rpws": list(r.padded),
                      "padded_mpi": list(hr.padded), "rpws_s_per_primitive": prim,
                      "mpi_s_per_layer": layer, "ratio": prim / layer}
        print(f"{label:8s} {H}x{W} RGB T=1: RPWS {prim * 1e3:8.1f} ms per primitive "
              f"(grid {r.padded}), MPI {layer * 1e3:8.1f} ms per layer (grid {hr.padded}), "
              f"ratio {prim / layer:5.2f}")
    out["extrapolated"] = extrapolate(out["1080p"])
    return out


def extrapolate(c, splats=(100_000, 279_199, 1_000_000), layers=(4, 32), frames=24):
    """EXTRAPOLATION from the measured 1080p RGB steps: both methods are linear in T and in
    their step count (K primitives, L layers), so t = steps x T x (seconds per step)."""
    rows = []
    for K in splats:
        for L in layers:
            t_rpws = K * c["rpws_s_per_primitive"] * frames
            t_mpi = L * c["mpi_s_per_layer"] * frames
            rows.append({"K": K, "L": L, "rpws_s": t_rpws, "mpi_s": t_mpi,
                         "speedup": t_rpws / t_mpi})
            print(f"EXTRAPOLATION K = {K}, L = {L}, T = {frames}, RGB, 1080p: RPWS "
                  f"{t_rpws / 3600:8.1f} h, MPI {t_mpi:7.1f} s, speed-up {t_rpws / t_mpi:9.0f}x")
    return rows


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("part", choices=["quality", "cost"])
    ap.add_argument("--size", type=_args.positive_int, default=256)
    ap.add_argument("--splats", type=_args.positive_int, default=2000)
    ap.add_argument("--frames", type=_args.positive_int, default=8)
    ap.add_argument("--near", type=_args.positive_float, default=2e-3)
    ap.add_argument("--far", type=_args.positive_float, default=6e-3)
    ap.add_argument("--steps", type=_args.positive_int, default=8, help="primitives timed (cost)")
    ap.add_argument("--repeats", type=_args.positive_int, default=2)
    ap.add_argument("--progress", action="store_true")
    ap.add_argument("--json", type=_args.output_file, default=None,
                    help="write the results here")
    args = ap.parse_args()
    res = quality(args) if args.part == "quality" else cost(args)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(res, f, indent=1)


if __name__ == "__main__":
    main()
