"""``clholo experiment layers``: quality and runtime versus the number of layers."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from clholo import options


def register(subparsers) -> None:
    from clholo.experiments.layers import MAX_WIDTH, METHODS, SCENES
    from clholo.methods import METHODS as REGISTRY

    parser = subparsers.add_parser(
        "experiment", help="run a study (layers: quality and runtime versus layer count)")
    sub = parser.add_subparsers(dest="experiment", required=True, metavar="EXPERIMENT")
    _name_first(parser, ["layers"])
    p = sub.add_parser(
        "layers", help="MPI vs RGB-D (and RPWS) holograms: focal-stack and pupil-view quality "
        "against ray optics, and render time, versus the number of layers L")
    options.add_out_option(p, default="layers-study",
                           what="(results.csv, results.md, plots, crop sheets)")
    p.add_argument("--reduced", action="store_true",
                   help="CI size: L in {4, 8}, T = 4, 64-pixel-wide scenes (about a minute)")
    p.add_argument("--scenes", nargs="+", choices=SCENES, default=None,
                   help="scenes to run (default all)")
    p.add_argument("--methods", nargs="+", choices=[m for m in REGISTRY if m in METHODS],
                   default=None,
                   help="methods of the registry to compare (default: mpi rgbd); rpws renders "
                        "the splat scene (fox) once, one propagation per splat (about 10 min "
                        "for all 50,000 at the default size on 2 CPU cores; --max-splats "
                        "shortens it)")
    p.add_argument("--max-splats", type=options.whole(1), default=None,
                   help="splat scene (fox): a seeded uniform subset of at most this many visible "
                        "splats, for every method (default: all)")
    p.add_argument("--layers", nargs="+", type=options.whole(2, 256), default=None,
                   help="layer counts L (default 4 8 16 32 64; reduced 4 8)")
    p.add_argument("--frames", type=options.whole(1), default=None, help="T frames (default 24; reduced 4)")
    p.add_argument("--width", type=options.whole(16, MAX_WIDTH), default=None,
                   help=f"scene width in pixels, at most {MAX_WIDTH} (default 128; reduced 64)")
    p.add_argument("--seed", type=options.whole(0), default=0, help="phase stream seed")
    p.add_argument("--data", default=None, help="the shared data folder (twain-mpi, gaussians); "
                   "default ../shared/data or $CLHOLO_SHARED_DATA")
    p.set_defaults(func=_cmd_layers,
                   interrupt_note="nothing written (the study's folder is written only when "
                                  "complete)")


def _cmd_layers(args) -> int:
    from clholo.errors import InputError
    from clholo.experiments.layers import (FULL, REDUCED, SPLAT_SCENES, check_data,
                                          describe_estimate, run_study)
    from clholo.io.output import check_output_folder
    from clholo.progress import StepLog

    config = REDUCED if args.reduced else FULL
    changes = {}
    if args.scenes:
        changes["scenes"] = tuple(args.scenes)
    if args.layers:
        changes["layers"] = tuple(args.layers)
    if args.frames is not None:
        changes["frames"] = args.frames
    if args.width is not None:
        changes["width"] = args.width
    if args.methods:
        changes["methods"] = tuple(args.methods)
    if args.max_splats is not None:
        changes["max_splats"] = args.max_splats
    changes["seed"] = args.seed
    config = dataclasses.replace(config, **changes)
    if args.max_splats is not None and not any(s in SPLAT_SCENES for s in config.scenes):
        raise InputError(f"--max-splats acts on the splat scene ({', '.join(SPLAT_SCENES)}), "
                         f"which --scenes leaves out: drop --max-splats or add the scene")
    if args.data is not None and not Path(args.data).is_dir():
        raise InputError(f"--data {args.data} is not a folder: give the shared data folder "
                         f"(it holds twain-mpi/ and gaussians/)")
    config = config.validated()  # a bad combination is refused before the folder is checked
    check_output_folder(args.out, overwrite=args.overwrite)  # before any work
    # the scenes' files too: a scene folder given for --data failed only when that scene's
    # turn came, as ".../twain-mpi/twain-mpi/mpi.json does not exist"
    check_data(config.scenes, Path(args.data) if args.data is not None else None,
               option="--data")
    log = StepLog(mode=args.progress)
    repeated = _repeated(args)
    if repeated:
        log.note(repeated)
    log.note(describe_estimate(config))
    result = run_study(Path(args.out), config, data=Path(args.data) if args.data else None,
                       overwrite=args.overwrite, log=log)
    print(f"wrote {len(result['rows'])} scores to {result['out_dir']} "
          f"({result['seconds']:.1f} s): results.csv, results.md, quality_vs_layers.png, "
          f"time_vs_layers.png, crops_*.png")
    return 0


def _repeated(args) -> str:
    """One line naming every option that repeats a value (each runs once), or ''."""
    parts = []
    for flag in ("scenes", "methods", "layers"):
        given = getattr(args, flag) or []
        once = list(dict.fromkeys(str(v) for v in given))
        if len(once) < len(given):
            parts.append(f"--{flag} {' '.join(map(str, given))} runs {' '.join(once)}")
    return ("each value runs once: " + "; ".join(parts)) if parts else ""


def _name_first(parser, names) -> None:
    """``clholo experiment --out x`` (the experiment's name left out) is told so, with the
    experiments, rather than that 'x' is an invalid choice."""
    error = parser.error
    usage = f"write clholo experiment NAME [options] with NAME one of: {', '.join(names)}"

    def name_error(message: str):
        if "invalid choice:" in message and message.startswith("argument EXPERIMENT"):
            got = message.split("invalid choice:", 1)[1].split("(", 1)[0].strip()
            error(f"the experiment's name is missing ({got} is not one): {usage}")
        if "required: EXPERIMENT" in message:
            error(f"the experiment's name is missing: {usage}")
        error(message)

    parser.error = name_error
