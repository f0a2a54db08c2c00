"""``clholo encode``: complex hologram file -> 8-bit phase-only SLM patterns (PNG sequence)."""

from __future__ import annotations

import argparse

from clholo.commands import options


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "encode", help="turn a complex hologram file into 8-bit phase-only SLM patterns",
        description="Phase-only patterns by SGD (complex-field loss, Adam) or double-phase "
                    "amplitude coding, quantised through per-wavelength lookup tables and "
                    "written as one PNG per frame and colour, centred on the SLM (crop or pad "
                    "with gray 0). The folder is written under a temporary name.")
    p.add_argument("hologram", help="hologram file (.npz or .exr from clholo render)")
    p.add_argument("--method", choices=["sgd", "dpac"], default="sgd", help="encoding")
    p.add_argument("--z-slm", type=options.metres, default=0.04,
                   help="distance from the SLM to the hologram plane, metres")
    p.add_argument("--lut", nargs="+", default=["linear"],
                   help="lookup table(s): 'linear' (2 pi at gray 255), 'linear:N', or a .csv/.npy "
                        "file of 256 phases in radians; one for all colours or one per colour")
    p.add_argument("--slm-size", type=options.whole(1), nargs=2, default=[1080, 1920],
                   metavar=("ROWS", "COLS"), help="SLM's native size (Pluto-2.1: 1080 1920)")
    p.add_argument("--iterations", type=options.whole(1), default=200, help="SGD: largest number of steps")
    p.add_argument("--lr", type=options.positive, default=0.05, help="SGD: Adam learning rate")
    p.add_argument("--init", choices=["target", "random"], default="target",
                   help="SGD: initial phase (the target's phase at the SLM plane, or random)")
    p.add_argument("--seed", type=options.whole(0), default=0, help="SGD: seed of the random initial phase")
    p.add_argument("--tol", type=options.positive, default=1e-4,
                   help="SGD: stop when the loss falls by less than this (relative) between "
                        "two readings")
    p.add_argument("--check-every", type=options.whole(1), default=10,
                   help="SGD: iterations between loss readings")
    p.add_argument("--cutoff", type=options.fraction, default=0.5,
                   help="DPAC: Fourier filter half-width, fraction of the Nyquist frequency")
    p.add_argument("--amax", type=options.positive, default=None,
                   help="DPAC: amplitude that maps to 1 (default: each frame's maximum)")
    p.add_argument("--pad", type=options.pad, default="auto",
                   help="propagation padding: 'auto' or a factor such as 2")
    options.add_out_option(p, default="clholo-encode",
                           what="(one PNG per frame and colour, patterns.json)")
    p.set_defaults(func=cmd_encode)


def cmd_encode(args: argparse.Namespace) -> int:
    import sys
    import time

    import numpy as np

    from clholo.encode.dpac import dpac_encode
    from clholo.encode.quantize import parse_lut, quantize, write_pattern_pngs
    from clholo.encode.sgd import sgd_encode
    from clholo.io.holograms import read_hologram
    from clholo.scene import Optics

    from clholo.io.output import check_output_folder

    check_output_folder(args.out, overwrite=args.overwrite)  # before any work, not after
    pad = args.pad
    luts = [parse_lut(spec) for spec in args.lut]  # refuse a bad table before any work
    field, meta = read_hologram(args.hologram)
    optics = Optics(pitch=meta["pitch"], wavelengths=tuple(meta["wavelengths"]))
    if len(luts) not in (1, optics.channels):
        raise ValueError(f"--lut: give one table for all colours or {optics.channels} (one per "
                         f"colour), got {len(luts)}")
    t0 = time.perf_counter()
    info = {"method": args.method, "z_slm": args.z_slm, "hologram": str(args.hologram),
            "luts": [lut.describe() for lut in luts]}
    if args.method == "sgd":
        res = sgd_encode(field, optics, z_slm=args.z_slm, iterations=args.iterations,
                         lr=args.lr, init=args.init, seed=args.seed, tol=args.tol,
                         check_every=args.check_every, pad=pad, progress=sys.stderr.isatty())
        phase = res.phase
        balance = res.colour_balance()  # laser power ratios restoring the complex colours
        info.update(iterations=res.iterations, loss=res.loss.tolist(), lr=args.lr,
                    colour_balance=balance.tolist(), scale_abs=np.abs(res.scale).tolist())
        summary = (f"SGD {res.iterations} iterations, mean loss {float(res.loss.mean()):.4g}, "
                   f"colour balance (laser power, max 1) "
                   f"{' / '.join(f'{v:.3g}' for v in balance)}")
    else:
        phase = dpac_encode(field, optics, z_slm=args.z_slm, amax=args.amax, cutoff=args.cutoff,
                            pad=pad)
        info.update(cutoff=args.cutoff, amax=args.amax)
        summary = "DPAC"
    gray = quantize(phase, luts)
    seconds = time.perf_counter() - t0
    info["seconds"] = seconds
    out = write_pattern_pngs(gray, args.out, slm_shape=tuple(args.slm_size),
                             overwrite=args.overwrite, metadata=info)
    T, C = gray.shape[:2]
    print(f"{summary}: {T} frame(s) x {C} colour(s) in {seconds:.2f} s -> {out}/ "
          f"({args.slm_size[0]}x{args.slm_size[1]} PNGs)")
    return 0
