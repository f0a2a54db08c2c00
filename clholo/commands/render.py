"""``clholo demo`` and ``clholo render``: scene -> method -> frames -> render folder."""

from __future__ import annotations

import argparse

from clholo import options


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "demo", help="render scikit-image's motorcycle RGB-D scene as an RGB hologram and write "
                     "its focal stack")
    options.add_render_flow_options(p, demo=True)
    _add_folder_options(p, default="clholo-demo")
    p.set_defaults(func=cmd_demo)

    p = subparsers.add_parser("render", help="render a scene file or folder as a hologram")
    options.add_render_flow_options(p)
    _add_folder_options(p, default="clholo-render")
    p.set_defaults(func=cmd_render)


def _add_folder_options(p: argparse.ArgumentParser, *, default: str) -> None:
    options.add_out_option(p, default=default,
                           what="(focal_stack.png, focal_stack.npz, hologram, summary.json)")


def cmd_demo(args: argparse.Namespace) -> int:
    render_command(args, demo=True, command="demo")
    return 0


def cmd_render(args: argparse.Namespace) -> int:
    render_command(args, demo=False, command="render")
    return 0


def render_command(args: argparse.Namespace, *, demo: bool, command: str, log=None,
                   holograms=None, summary_extra=None) -> dict:
    """The whole flow of ``clholo demo``/``render`` from parsed options; returns the summary
    (``clholo batch`` items run exactly this, with ``holograms`` assembled from parts)."""
    from clholo import scenes
    from clholo.io.output import check_output_folder
    from clholo.methods import get_method
    from clholo.progress import StepLog
    from clholo.render_folder import render_to_folder

    spec = options.scene_spec_from_args(args, demo=demo)
    method = get_method(args.method)
    check_output_folder(args.out, overwrite=args.overwrite,  # before any work
                        inputs=list(getattr(args, "inputs", None) or [])
                        + [p for p in (getattr(args, "camera_json", None),) if p])
    optics = options.optics_from_args(args)
    log = StepLog(mode=getattr(args, "progress", "auto")) if log is None else log
    scene = scenes.load(spec, needs=method.needs, method=method.name, log=log)
    channels = (scene.mpi.channels if scene.mpi is not None else scene.primitives.channels)
    optics = options.match_channels(optics, channels)
    summary = render_to_folder(scene, method, optics, args.out, frames=args.frames,
                               seed=args.seed, pad=args.pad, log=log,
                               hologram_format=args.hologram_format, overwrite=args.overwrite,
                               command=command, holograms=holograms,
                               summary_extra=summary_extra, option="--out")
    return summary
