"""``clholo bench``: the method against NumPy and PyTorch, side by side (PyTorch on CUDA when
the OpenCL device is a GPU and torch has CUDA, else on the CPU; the table names each device)."""

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
                   help="timed repetitions per method (the best is reported)")
    p.add_argument("--pad", type=options.pad, default=None,
                   help="zero padding of each propagation: 'auto' or a factor (default: 2)")
    p.add_argument("--no-scaling", action="store_true", help="skip the time-versus-L sweep")
    p.add_argument("--slm", action="store_true", help="the SLM's size instead: 1080x1920, "
                   "RGB, T=3, pad auto, against PyTorch on the same grid (CUDA on a GPU, else "
                   "CPU; --layers and --repeats apply; --size, --pad and --no-scaling are "
                   "refused)")
    p.set_defaults(func=cmd_bench)


def cmd_bench(args: argparse.Namespace) -> int:
    from clholo.bench import run_hologram_benchmark, run_slm_benchmark

    if args.slm:
        ignored = [name for name, given in (("--size", args.size is not None),
                                            ("--pad", args.pad is not None),
                                            ("--no-scaling", args.no_scaling)) if given]
        if ignored:
            from clholo.errors import InputError

            raise InputError(f"{', '.join(ignored)} do(es) not apply to bench --slm (its grid is "
                             f"the SLM's 1080x1920 with pad auto): drop {', '.join(ignored)}")
        run_slm_benchmark(repeats=args.repeats, layers=args.layers)
        return 0
    run_hologram_benchmark(size=1024 if args.size is None else args.size, layers=args.layers,
                           repeats=args.repeats, scaling=not args.no_scaling,
                           pad=2.0 if args.pad is None else args.pad)
    return 0
