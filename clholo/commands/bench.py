"""``clholo bench``: the method against NumPy and PyTorch, side by side (PyTorch on CUDA when
the OpenCL device is a GPU and torch has CUDA, else on the CPU; the table names each device);
``--profile``: where clholo's own device time goes (``clholo.bench.profile_render``)."""

from __future__ import annotations

import argparse

from clholo import options


def register(subparsers) -> None:
    p = subparsers.add_parser("bench", help="time clholo against the NumPy and PyTorch versions "
                                            "of the same method, side by side")
    p.add_argument("--size", type=options.whole(8, 4096), default=None,
                   help="field size N (N x N pixels, at most 4096 so that the padded grid fits "
                        "the FFT; default: 1024)")
    p.add_argument("--layers", type=options.whole(1, options.MAX_LAYERS), default=32,
                   help="MPI layers L")
    p.add_argument("--repeats", type=options.whole(1, 100), default=3,
                   help="timed rounds per method, interleaved (the median is reported; a "
                        "round times back-to-back calls lasting at least 50 ms, per call)")
    p.add_argument("--pad", type=options.pad, default=None,
                   help="zero padding of each propagation: 'auto' or a factor (default: 2)")
    p.add_argument("--no-scaling", action="store_true", help="skip the time-versus-L sweep")
    p.add_argument("--no-numpy", action="store_true", help="leave out the NumPy version "
                   "(seconds a call at 1024^2)")
    p.add_argument("--slm", action="store_true", help="the SLM's size instead: 1080x1920, "
                   "RGB, T=3, pad auto, against PyTorch on the same grid (CUDA on a GPU, else "
                   "CPU; --layers and --repeats apply; --size, --pad and --no-scaling are "
                   "refused)")
    p.add_argument("--profile", action="store_true", help="where the device time goes instead "
                   "of the peers: launches and time per kernel and FFT pass, each pass's bytes "
                   "against the copy bandwidth, and the host's time to enqueue, for one render "
                   "of random RGB layers (T=3; the SLM's 1080x1920 with pad auto, or --size N "
                   "with --pad; --layers and --repeats apply; --no-scaling is refused)")
    p.set_defaults(func=cmd_bench)


def cmd_bench(args: argparse.Namespace) -> int:
    from clholo.bench import run_hologram_benchmark, run_slm_benchmark

    if args.profile:
        return _profile(args)
    if args.slm:
        ignored = [name for name, given in (("--size", args.size is not None),
                                            ("--pad", args.pad is not None),
                                            ("--no-scaling", args.no_scaling),
                                            ("--no-numpy", args.no_numpy)) if given]
        if ignored:
            from clholo.errors import InputError

            raise InputError(f"{', '.join(ignored)} do(es) not apply to bench --slm (its grid is "
                             f"the SLM's 1080x1920 with pad auto): drop {', '.join(ignored)}")
        run_slm_benchmark(repeats=args.repeats, layers=args.layers)
        return 0
    run_hologram_benchmark(size=1024 if args.size is None else args.size, layers=args.layers,
                           repeats=args.repeats, scaling=not args.no_scaling,
                           pad=2.0 if args.pad is None else args.pad,
                           numpy=not args.no_numpy)
    return 0


def _profile(args: argparse.Namespace) -> int:
    from clholo.bench import format_profile, profile_render
    from clholo.errors import InputError

    refused = [name for name, given in (("--no-scaling", args.no_scaling),
                                        ("--no-numpy", args.no_numpy),
                                        ("--size", args.slm and args.size is not None),
                                        ("--pad", args.slm and args.pad is not None)) if given]
    if refused:
        raise InputError(f"{', '.join(refused)} do(es) not apply to bench --profile"
                         f"{' --slm' if args.slm else ''}: drop {', '.join(refused)}")
    if args.size is None:
        height, width = 1080, 1920
        pad = "auto" if args.pad is None else args.pad
    else:
        height = width = args.size
        pad = 2.0 if args.pad is None else args.pad
    result = profile_render(height=height, width=width, colours=3, layers=args.layers, frames=3,
                            pad=pad, repeats=args.repeats)
    print("\n".join(format_profile(result)))
    return 0
