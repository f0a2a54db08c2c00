"""``clholo tune``: measure the GPU kernels' tunable settings on the chosen device and store the
fastest (:mod:`clholo.tuning`); ``--show`` prints what is stored and in effect, ``--forget``
removes it."""

from __future__ import annotations

import argparse

from clholo import options


def _shape(value: str):
    """argparse type: ``HxW`` in pixels, each from 8 to 8192."""
    parts = value.lower().replace(" ", "").split("x")
    try:
        h, w = (int(v) for v in parts)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected HxW such as 1080x1920, got {value!r}") from None
    if not (8 <= h <= 8192 and 8 <= w <= 8192):
        raise argparse.ArgumentTypeError(f"H and W must each be from 8 to 8192 pixels, got "
                                         f"{value!r}")
    return h, w


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "tune", help="measure the GPU kernels' settings that change speed but never results on "
                     "the chosen device (CLHOLO_DEVICE) and store the fastest for it")
    p.add_argument("--shape", type=_shape, default="1080x1920", metavar="HxW",
                   help="the render measured, pixels (the lab's SLM by default)")
    p.add_argument("--colours", type=int, choices=(1, 3), default=3,
                   help="colour channels of the render")
    p.add_argument("--layers", type=options.whole(1, options.MAX_LAYERS), default=32,
                   help="MPI layers L")
    p.add_argument("--frames", type=options.whole(1, 64), default=3,
                   help="frames T of each render")
    p.add_argument("--pad", type=options.pad, default="auto",
                   help="zero padding: 'auto' or a factor")
    p.add_argument("--sgd", type=options.whole(0, 4096), default=1024, metavar="N",
                   help="also measure an SGD iteration of N x N pixels, which most settings "
                        "change too (0: renders only)")
    p.add_argument("--rounds", type=options.whole(1, 100), default=5,
                   help="alternations per comparison (the median of their ratios counts)")
    p.add_argument("--threshold", type=options.non_negative, default=0.03,
                   help="the speed-up a setting must show to be taken, as a fraction (0.03 is 3 %%)")
    p.add_argument("--variant", choices=("auto", "gpu"), default="auto",
                   help="the kernels measured: the device's (auto), or the GPU kernels on "
                        "any device ('gpu': a CPU device runs its own kernels otherwise, which "
                        "the settings do not change)")
    p.add_argument("--file", default=None, metavar="PATH",
                   help="the tuning file to read and write (default: CLHOLO_TUNING_FILE, else "
                        "~/.cache/clholo/tuning.json); renders read CLHOLO_TUNING_FILE")
    what = p.add_mutually_exclusive_group()
    what.add_argument("--dry-run", action="store_true",
                      help="measure and print, store nothing")
    what.add_argument("--show", action="store_true",
                      help="print the stored tuning of the chosen device and the settings in "
                           "effect; measure nothing")
    what.add_argument("--forget", action="store_true",
                      help="remove the chosen device's stored tuning; measure nothing")
    p.set_defaults(func=cmd_tune)


def _given_measure_options(args) -> list:
    defaults = {"shape": (1080, 1920), "colours": 3, "layers": 32, "frames": 3, "pad": "auto",
                "sgd": 1024, "rounds": 5, "threshold": 0.03, "variant": "auto"}
    return [f"--{k}" for k, v in defaults.items() if getattr(args, k) != v]


def cmd_tune(args: argparse.Namespace) -> int:
    import sys
    from pathlib import Path

    from clholo import tuning
    from clholo.errors import InputError
    from clholo.host import runtime

    if 0 < args.sgd < 8:
        raise InputError(f"--sgd is {args.sgd}: give N >= 8 (an SGD iteration of N x N pixels), "
                         f"or 0 for renders only")
    path = Path(args.file).expanduser() if args.file is not None else tuning.tuning_file()
    if (args.show or args.forget) and _given_measure_options(args):
        given = ", ".join(_given_measure_options(args))
        raise InputError(f"{given} only apply to a measurement: drop them, or drop "
                         f"{'--show' if args.show else '--forget'}")
    if path is None and not (args.dry_run or args.show):
        raise InputError(f"{tuning.TUNING_FILE_ENV} is off: give --file PATH to store the "
                         f"tuning, or --dry-run to only measure")
    if path is not None and path.is_dir():
        raise InputError(f"--file {path} is a folder: give the tuning file's path, such as "
                         f"{path / 'tuning.json'}")
    if path is not None and not (args.dry_run or args.show):
        from clholo.host.tuning import check_writable

        # before minutes of measuring: never over a file the user owns, never into a folder
        # that a typo in --file names (only the default cache folder is created)
        check_writable(path, option="--file" if args.file is not None
                       else tuning.TUNING_FILE_ENV)
    queue = runtime.get_queue()
    device = queue.device
    if args.show:
        _show(device, path)
        return 0
    if args.forget:
        if tuning.forget_tuning(device, path=path):
            print(f"removed the tuning of {tuning.device_key(device)} from {path}")
        else:
            print(f"{path} holds no tuning of {tuning.device_key(device)}: nothing removed")
        return 0
    from clholo.progress import StepLog

    log = StepLog(sys.stderr, mode=args.progress)  # --progress off: the table alone

    def say(line: str) -> None:
        if log.mode != "off":
            log.note(line)

    log.start(f"measuring {len(tuning.SETTINGS)} settings on {device.name.strip()}")
    result = tuning.tune(shape=args.shape, colours=args.colours, layers=args.layers,
                         frames=args.frames, pad=args.pad, sgd=args.sgd or None,
                         rounds=args.rounds,
                         threshold=args.threshold, variant=args.variant, queue=queue,
                         progress=say)
    print(result.report())
    if args.dry_run:
        print("--dry-run: nothing stored")
        return 0
    written = tuning.save_tuning(result, path=path)
    note = ("" if args.file is None or path == tuning.tuning_file() else
            f" (renders read it where {tuning.TUNING_FILE_ENV}={written})")
    print(f"stored for this device in {written}{note}; plans built on it from now on take it "
          f"({tuning.TUNING_FILE_ENV}=off runs without)")
    return 0


def _show(device, path) -> None:
    from clholo import tuning
    from clholo._version import __version__

    print(f"device: {tuning.device_key(device)}")
    print(f"tuning file: {path if path is not None else f'none ({tuning.TUNING_FILE_ENV}=off)'}")
    entry = tuning.stored_entry(device, path=path) if path is not None else None
    if entry is None and path is not None and not path.exists():
        # a mistyped --file would read as "nothing tuned yet" otherwise
        print(f"stored: nothing: {path} does not exist (run `clholo tune` to make it)")
    elif entry is None:
        print("stored: nothing for this device (run `clholo tune`)")
    else:
        state = ("used" if entry.get("clholo") == __version__
                 else f"not used: measured with clholo {entry.get('clholo')}, this is "
                      f"{__version__}; run `clholo tune` again")
        print(f"stored: {entry.get('date', '?')}, {state}; against the defaults "
              f"{entry.get('speedup', '?')}x")
    in_effect = dict(tuning.settings_for(device)) if path == tuning.tuning_file() else None
    for name, s in tuning.SETTINGS.items():
        stored = (entry or {}).get("settings", {}).get(name, "-")
        now = "" if in_effect is None else f", in effect {in_effect[name]}"
        print(f"  {name}: default {s.default}, stored {stored}{now}  ({s.what})")
