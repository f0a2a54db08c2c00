"""``clholo encode``: complex hologram file -> 8-bit phase-only SLM patterns (PNG sequence)."""

from __future__ import annotations

import argparse

from clholo import options


# the largest SLMs are 4K-8K panels; a side beyond this is a typo that would only fail after the
# whole encoding, when the patterns are placed on the SLM
MAX_SLM_SIDE = 16384
# SGD converges in hundreds of steps (default 200): a count beyond this is a typo that would
# run for days (the layer counts are capped the same way: options.MAX_LAYERS)
MAX_ITERATIONS = 100_000
# Adam's learning rate is its step in radians (default 0.05): a step beyond a full turn of
# phase, or so small that MAX_ITERATIONS steps move less than a hundredth of a radian, is a slip
MIN_LR, MAX_LR = 1e-7, 2 * 3.141592653589793
# an --amax more than this factor outside the hologram's amplitudes saturates or flattens
# (nearly) every pixel
AMAX_FAR = 100.0


def _learning_rate(value: str) -> float:
    """argparse type of --lr: a number in [MIN_LR, MAX_LR] (radians per step)."""
    x = options.positive(value)
    if not MIN_LR <= x <= MAX_LR:
        raise argparse.ArgumentTypeError(
            f"must be in [{MIN_LR:g}, {MAX_LR:.4g}] (Adam's step in radians, 2 pi at most; "
            f"default {_METHOD_OPTIONS['lr'][1]}), got {value!r}")
    return x


# option -> (the method it belongs to, its default when not given)
_METHOD_OPTIONS = {
    "iterations": ("sgd", 200), "lr": ("sgd", 0.05), "init": ("sgd", "target"),
    "seed": ("sgd", 0), "tol": ("sgd", 1e-4), "check_every": ("sgd", 10),
    "cutoff": ("dpac", 0.5), "amax": ("dpac", None),
}


def _default(name: str) -> str:
    return f"(default: {_METHOD_OPTIONS[name][1]})"


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
                        "file of 256 phases in radians; one for all colours or one per colour "
                        "(also: one file of 256 rows, one column per colour)")
    p.add_argument("--slm-size", type=options.whole(1, MAX_SLM_SIDE), nargs=2,
                   default=[1080, 1920], metavar=("ROWS", "COLS"),
                   help=f"SLM's native size in pixels, at most {MAX_SLM_SIDE} a side "
                        f"(Pluto-2.1: 1080 1920)")
    sgd = p.add_argument_group("--method sgd only (refused with dpac)")
    sgd.add_argument("--iterations", type=options.whole(1, MAX_ITERATIONS), default=None,
                     help=f"largest number of steps, at most {MAX_ITERATIONS} "
                          f"{_default('iterations')}")
    sgd.add_argument("--lr", type=_learning_rate, default=None,
                     help=f"Adam learning rate, radians per step, in [{MIN_LR:g}, 2 pi] "
                          f"{_default('lr')}")
    sgd.add_argument("--init", choices=["target", "random"], default=None,
                     help=f"initial phase: the target's phase at the SLM plane, or random "
                          f"{_default('init')}")
    sgd.add_argument("--seed", type=options.whole(0), default=None,
                     help=f"seed of the random initial phase, --init random only {_default('seed')}")
    sgd.add_argument("--tol", type=options.non_negative, default=None,
                     help=f"stop when the loss falls by less than this (relative) between two "
                          f"readings; 0: no early stop, run every iteration {_default('tol')}")
    sgd.add_argument("--check-every", type=options.whole(1, MAX_ITERATIONS), default=None,
                     help=f"iterations between loss readings {_default('check_every')}")
    dpac = p.add_argument_group("--method dpac only (refused with sgd)")
    dpac.add_argument("--cutoff", type=options.fraction, default=None,
                      help=f"Fourier filter half-width, fraction of the Nyquist frequency "
                           f"{_default('cutoff')}")
    dpac.add_argument("--amax", type=options.positive, default=None,
                      help="amplitude that maps to 1 (default: each frame's maximum)")
    p.add_argument("--pad", type=options.pad, default="auto",
                   help="propagation padding: 'auto' or a factor such as 2")
    options.add_out_option(p, default="clholo-encode",
                           what="(one PNG per frame and colour, patterns.json)")
    p.set_defaults(func=cmd_encode)


def _method_options(args: argparse.Namespace) -> dict:
    """The values of the chosen method's options (defaults filled in); an option of the other
    method is refused (it would be ignored)."""
    from clholo.errors import InputError

    given = [name for name, (method, _) in _METHOD_OPTIONS.items()
             if method != args.method and getattr(args, name) is not None]
    if given:
        flags = ", ".join("--" + name.replace("_", "-") for name in given)
        other = "dpac" if args.method == "sgd" else "sgd"
        raise InputError(f"{flags} appl{'ies' if len(given) == 1 else 'y'} to --method {other} "
                         f"only and would be ignored with --method {args.method}: drop "
                         f"{'it' if len(given) == 1 else 'them'} or pass --method {other}")
    values = {name: (default if getattr(args, name) is None else getattr(args, name))
              for name, (method, default) in _METHOD_OPTIONS.items() if method == args.method}
    if args.method == "sgd" and args.seed is not None and values["init"] != "random":
        raise InputError("--seed seeds the random initial phase of --init random only and would "
                         "be ignored with --init target: drop --seed or pass --init random")
    return values


def cmd_encode(args: argparse.Namespace) -> int:
    import time

    import numpy as np

    from clholo.encode.dpac import dpac_encode
    from clholo.encode.quantize import parse_luts, quantize, write_pattern_pngs
    from clholo.encode.sgd import sgd_encode
    from clholo.errors import InputError
    from clholo.io.holograms import read_hologram
    from clholo.io.output import check_output_folder, destination_state
    from clholo.progress import StepLog
    from clholo.scene import Optics

    values = _method_options(args)  # an option of the other method is refused, not ignored
    check_output_folder(args.out, overwrite=args.overwrite,  # before any work, not after
                        inputs=[args.hologram])
    # what --out is now: another run's folder written there during the work is refused at the
    # rename, not replaced by --overwrite
    seen = destination_state(args.out)
    # refuse a bad table before any work; a file of one column per colour gives one each
    per_spec = [(spec, parse_luts(spec)) for spec in args.lut]
    luts = [t for _, tables in per_spec for t in tables]
    columns = "".join(f"; {spec} holds {len(tables)} (one column per colour)"
                      for spec, tables in per_spec if len(tables) > 1)
    log = StepLog(mode=args.progress)
    t_read = time.perf_counter()
    field, meta = read_hologram(args.hologram)
    optics = Optics(pitch=meta["pitch"], wavelengths=tuple(meta["wavelengths"]))
    if len(luts) not in (1, optics.channels):
        raise InputError(f"--lut: give one table for all colours or {optics.channels} (one per "
                         f"colour), got {len(luts)}{columns}")
    T, C, H, W = field.shape
    if not np.any(field):
        # no field has a phase to code: DPAC would write flat patterns of two gray levels, SGD
        # has no scale to fit. One dark colour is fine (a red scene has no green light).
        raise InputError(f"{args.hologram} holds no light (every value is 0): render the scene "
                         f"again, or encode a hologram that carries it")
    import sys

    rows, cols = args.slm_size
    if rows < H or cols < W:  # the patterns are centred on the SLM: a smaller one cuts them
        print(f"clholo encode: warning: --slm-size {rows} {cols} is smaller than the hologram "
              f"({H} x {W}): the patterns keep its centre {min(rows, H)} x {min(cols, W)}, the "
              f"rest is cut off", file=sys.stderr)
    log.step(f"read {args.hologram}: {T} frame(s) x {C} colour(s), {H}x{W}",
             time.perf_counter() - t_read)
    t0 = time.perf_counter()
    info = {"method": args.method, "z_slm": args.z_slm, "hologram": str(args.hologram),
            "luts": [lut.describe() for lut in luts], **values}
    if args.method == "sgd":
        info["max_iterations"] = values["iterations"]
    if args.method == "sgd":
        log.start(f"SGD: up to {values['iterations']} iterations per batch of frames")
        res = sgd_encode(field, optics, z_slm=args.z_slm, pad=args.pad,
                         progress=log.tracker("sgd iterations"), **values)
        phase = res.phase
        balance = res.colour_balance()  # laser power ratios restoring the complex colours
        info.update(iterations=res.iterations, loss=res.loss.tolist(),
                    colour_balance=balance.tolist(), scale_abs=np.abs(res.scale).tolist())
        info["stopped"] = res.stop_reason()
        summary = (f"SGD {res.iterations}/{values['iterations']} iterations "
                   f"({res.stop_reason()}), mean loss {float(res.loss.mean()):.4g}, "
                   f"colour balance (laser power, max 1) "
                   f"{' / '.join(f'{v:.3g}' for v in balance)}")
    else:
        _warn_far_amax(values["amax"], field)
        phase = dpac_encode(field, optics, z_slm=args.z_slm, pad=args.pad, **values)
        summary = "DPAC"
    # after the work, which refuses bad input first: warnings of a run that goes on
    _warn_lut_and_border(luts, C, (H, W), (rows, cols))
    gray = quantize(phase, luts)
    seconds = time.perf_counter() - t0
    log.step(f"{summary}, quantised", seconds)
    info["seconds"] = seconds
    out = write_pattern_pngs(gray, args.out, slm_shape=tuple(args.slm_size),
                             overwrite=args.overwrite, metadata=info, option="--out",
                             expect=seen, wavelengths=optics.wavelengths)
    print(f"{summary}: {T} frame(s) x {C} colour(s) in {seconds:.2f} s -> {out}/ "
          f"({args.slm_size[0]}x{args.slm_size[1]} PNGs)")
    return 0


def _warn_lut_and_border(luts, channels: int, shape, slm_shape) -> None:
    """One warning line each for one measured table taken for every colour, and for patterns
    smaller than the SLM (its gray-0 border)."""
    import sys

    (H, W), (rows, cols) = shape, slm_shape
    if len(luts) == 1 and channels > 1 and not luts[0].name.startswith("linear"):
        # the phase a gray level gives scales about as 1/lambda: red's 2 pi at gray 255 is
        # green's at about 208 and blue's at 180 (phases off by up to 23 % and 42 %)
        print(f"clholo encode: warning: --lut {luts[0].name} is one measured table for all "
              f"{channels} colours, but a gray level's phase depends on the wavelength: give "
              f"one table per colour (--lut once per colour, or a file of one column per "
              f"colour)", file=sys.stderr)
    if rows >= H and cols >= W and (rows, cols) != (H, W):
        # gray 0 around the patterns is a flat mirror: a plane wave that reaches the hologram
        # plane, which neither the simulation nor SGD's fit includes (an error of 0.47 where
        # 0.11 was simulated, for a 128^2 DPAC pattern on a 384^2 SLM at 4 cm)
        print(f"clholo encode: warning: the {H} x {W} patterns fill only part of the {rows} x "
              f"{cols} SLM (--slm-size); its border of gray 0 reflects a plane wave onto the "
              f"hologram plane that the patterns' simulation leaves out: render the hologram "
              f"at the SLM's size, or block the border in the optics", file=sys.stderr)


def _warn_far_amax(amax, field) -> None:
    """One warning line when ``--amax`` lies far (:data:`AMAX_FAR`) outside the hologram's
    amplitudes: below them every pixel saturates, above them the patterns are all but flat.
    (The hologram's amplitudes stand for the SLM plane's: the propagation keeps their
    energy.)"""
    import sys

    import numpy as np

    if amax is None:
        return
    amp = np.abs(field)
    hi = float(amp.max(initial=0.0))
    if not hi > 0:
        return
    rms = float(np.sqrt(np.mean(np.square(amp[amp > 0], dtype=np.float64))))
    if amax < rms / AMAX_FAR:
        what = (f"far below the hologram's amplitudes (rms {rms:.3g}, largest {hi:.3g}): "
                f"nearly every pixel saturates at full amplitude")
    elif amax > hi * AMAX_FAR:
        what = (f"far above the hologram's largest amplitude {hi:.3g}: every pixel codes "
                f"less than {100 * hi / amax:.2g}% amplitude, the patterns are all but flat")
    else:
        return
    print(f"clholo encode: warning: --amax {amax:g} is {what}; leave --amax out to use each "
          f"frame's maximum", file=sys.stderr)
