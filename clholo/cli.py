"""``clholo`` command line: ``info``, ``demo``, ``render``, ``bench``."""

from __future__ import annotations

import argparse
import importlib
import sys
from typing import List, Optional

# Modules that add their own subcommands: each defines ``register_cli(subparsers)``, which adds
# its parser(s) and sets ``func``; it imports only argparse at registration, so that
# ``clholo --help`` stays fast and optional extras are imported only by the command that needs
# them.
COMMAND_MODULES: List[str] = [
    "clholo.encode.cli",
    "clholo.tools.cli_bench",
    "clholo.experiments.layers",
    "clholo.experiments.report",
    "clholo.batch",
    "clholo.selftest",
]


def _fmt_bytes(n: int) -> str:
    for unit in ("B", "KiB", "MiB", "GiB", "TiB"):
        if n < 1024 or unit == "TiB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    return str(n)


def cmd_info(args: argparse.Namespace) -> int:
    from clholo.host import runtime

    devices = runtime.list_devices()
    if not devices:
        print("No OpenCL platform/device found.\n" + runtime.INSTALL_HINT, file=sys.stderr)
        return 1
    try:
        chosen = runtime.choose_device()
        chosen_key = (chosen.platform.name.strip(), chosen.name.strip())
        chosen_err = None
    except runtime.NoDeviceError as exc:
        chosen_key, chosen_err = None, str(exc)
    platform = None
    for d in devices:
        if d.platform_name != platform:
            platform = d.platform_name
            print(f"platform {d.platform_index}: {platform}")
        mark = "*" if chosen_key == (d.platform_name, d.device_name) else " "
        print(f" {mark} {d.selector}  {d.device_name}  [{d.device_type}]")
        print(f"        compute units {d.compute_units}, global memory "
              f"{_fmt_bytes(d.global_mem_bytes)}, local memory {_fmt_bytes(d.local_mem_bytes)}, "
              f"max work-group {d.max_work_group_size}, fp64 {'yes' if d.fp64 else 'no'}")
        print(f"        {d.opencl_version}")
    if chosen_err:
        print(chosen_err, file=sys.stderr)
        return 1
    print(f"clholo uses * ({chosen_key[0]} / {chosen_key[1]}); choose another with "
          f"CLHOLO_DEVICE=P:D or a name substring")
    return 0


def _optics(args) -> "Optics":
    from clholo.scene import Optics

    return Optics(pitch=args.pitch, wavelengths=tuple(args.wavelengths))


def _whole(minimum: int):
    """argparse type: a whole number >= minimum, with the option's own error message."""
    def parse(value: str) -> int:
        try:
            n = int(value)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a whole number, got {value!r}") from None
        if n < minimum:
            raise argparse.ArgumentTypeError(f"must be >= {minimum}, got {n}")
        return n
    return parse


def _positive(value: str) -> float:
    """argparse type: a finite number > 0."""
    try:
        x = float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {value!r}") from None
    if not (x > 0 and x < float("inf")):
        raise argparse.ArgumentTypeError(f"must be a finite number > 0, got {value!r}")
    return x


def _pad(value: str):
    if value == "auto":
        return "auto"
    try:
        factor = float(value)
    except ValueError:
        factor = float("nan")
    if not (factor >= 1 and factor < float("inf")):
        raise argparse.ArgumentTypeError(
            f"--pad must be 'auto' or a factor >= 1 such as 2, got {value!r}")
    return factor


def demo_scene(args: argparse.Namespace, log) -> tuple:
    """``clholo demo``'s scene from its parsed options: ``(mpi, optics, source)``.

    (The command line, ``clholo batch`` and scripts build a demo scene through this one
    function, so they cannot drift apart.)"""
    import time

    from clholo.demo import motorcycle_mpi

    log.start("scene: scikit-image Middlebury motorcycle RGB-D")
    t = time.perf_counter()
    mpi = motorcycle_mpi(layers=args.layers, near=args.near, far=args.far, scale=args.scale)
    log.step(f"scene: scikit-image Middlebury motorcycle RGB-D -> {mpi.layers}-plane MPI "
             f"({mpi.shape[0]}x{mpi.shape[1]})", time.perf_counter() - t)
    return mpi, _optics(args), "skimage.data.stereo_motorcycle"


def render_scene(args: argparse.Namespace, log) -> tuple:
    """``clholo render``'s scene from its parsed options: ``(mpi, optics, source)``, depths in
    metres (scene units are refused with the fix)."""
    import time

    from clholo.io import load_scene
    from clholo.io.load import scene_depth_units

    log.start(f"scene: loading {' + '.join(args.inputs)}")
    t = time.perf_counter()
    inputs = args.inputs[0] if len(args.inputs) == 1 else list(args.inputs)
    mpi = load_scene(inputs, layers=args.layers, near=args.near, far=args.far,
                     spacing=args.spacing, mode=args.mode, depth_kind=args.depth_kind,
                     depth_spacing=args.depth_spacing, scale=args.scale,
                     min_depth=args.min_depth, max_depth=args.max_depth,
                     camera_json=args.camera_json, camera_index=args.camera_index,
                     znear=args.znear)
    optics = _optics(args)
    if mpi.channels != optics.channels and mpi.channels == 1:
        optics = type(optics)(pitch=optics.pitch, wavelengths=optics.wavelengths[1:2])
    units = "m" if args.near is not None else scene_depth_units(inputs)
    units = "m" if units == "metres" else units
    log.step(f"scene: {' + '.join(args.inputs)} -> {mpi.layers}-plane MPI "
             f"({mpi.shape[0]}x{mpi.shape[1]}x{mpi.channels}), depths "
             f"{mpi.depths[0]:.4g}..{mpi.depths[-1]:.4g} {units}", time.perf_counter() - t)
    if units != "m":
        raise ValueError(
            f"the scene's depths are in {units} ({mpi.depths[0]:.4g}..{mpi.depths[-1]:.4g}): "
            f"give --near and --far in metres behind the hologram plane, e.g. --near 0.002 "
            f"--far 0.006")
    if mpi.depths[-1] > 1.0:
        raise ValueError(
            f"the scene's depths reach {mpi.depths[-1]:.4g} m (scene units?): give --near and "
            f"--far in metres behind the hologram plane, e.g. --near 0.002 --far 0.006")
    return mpi, optics, " + ".join(args.inputs)


SCENES = {"demo": demo_scene, "render": render_scene}


def render_folder(args: argparse.Namespace, mpi, optics, source: str, log, *, command: str,
                  holograms=None) -> dict:
    """Render (or take ``holograms``) and write the output folder ``args.out`` as
    ``clholo demo``/``render`` do; returns the summary."""
    from pathlib import Path

    from clholo.demo import render_and_save

    return render_and_save(mpi, optics, Path(args.out), frames=args.frames, seed=args.seed,
                           pad=args.pad, log=log, source=source,
                           hologram_format=args.hologram_format, overwrite=args.overwrite,
                           command=command, holograms=holograms)


def cmd_demo(args: argparse.Namespace) -> int:
    from clholo.demo import StepLog
    from clholo.io import check_output_folder

    check_output_folder(args.out, overwrite=args.overwrite)
    log = StepLog()
    mpi, optics, source = demo_scene(args, log)
    render_folder(args, mpi, optics, source, log, command="demo")
    return 0


def cmd_render(args: argparse.Namespace) -> int:
    from clholo.demo import StepLog
    from clholo.io import check_output_folder

    check_output_folder(args.out, overwrite=args.overwrite)
    if args.method == "rpws" or args.max_splats is not None:  # .ply only: RPWS / subsampled
        from clholo.baselines.rpws import cmd_render_splats
        return cmd_render_splats(args)
    log = StepLog()
    mpi, optics, source = render_scene(args, log)
    render_folder(args, mpi, optics, source, log, command="render")
    return 0


def cmd_bench(args: argparse.Namespace) -> int:
    from clholo.bench import run_hologram_benchmark, run_slm_benchmark

    if args.slm:
        run_slm_benchmark(repeats=args.repeats, layers=args.layers)
        return 0
    run_hologram_benchmark(size=args.size, layers=args.layers, repeats=args.repeats,
                           scaling=not args.no_scaling, pad=args.pad)
    return 0


class _HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Shows each option's default; a default of None is worded in the help text instead
    ("default: ..." saying what happens), since "(default: None)" tells a user nothing."""

    def _get_help_string(self, action):
        if action.default is None:
            return action.help
        return super()._get_help_string(action)


class _Parser(argparse.ArgumentParser):
    """Every (sub)command shows each option's default in ``--help``."""

    def __init__(self, *args, **kwargs):
        kwargs.setdefault("formatter_class", _HelpFormatter)
        super().__init__(*args, **kwargs)


def _add_render_options(p: argparse.ArgumentParser, *, layers: Optional[int], near, far) -> None:
    p.add_argument("--layers", type=_whole(1), default=layers,
                   help="number of MPI planes to make from RGB-D or splats (default: an MPI keeps "
                        "its own layers)")
    p.add_argument("--near", type=_positive, default=near,
                   help="depth of the nearest plane, metres behind the hologram plane (default: "
                        "an MPI's own depths, which must then be metres)")
    p.add_argument("--far", type=_positive, default=far,
                   help="depth of the farthest plane, metres behind the hologram plane (default: "
                        "an MPI's own depths, which must then be metres)")
    p.add_argument("--frames", type=_whole(1), default=8,
                   help="time-multiplexed frames T, each with fresh random phases (paper: 24)")
    p.add_argument("--seed", type=_whole(0), default=0,
                   help="key of the random-phase stream; the same seed gives the same hologram")
    p.add_argument("--pad", type=_pad, default="auto",
                   help="zero padding of each propagation: 'auto' (covers the kernel's spread) "
                        "or a factor such as 2")
    p.add_argument("--pitch", type=_positive, default=8e-6, help="SLM pixel pitch, metres")
    p.add_argument("--wavelengths", type=_positive, nargs="+", default=[638e-9, 520e-9, 450e-9],
                   help="one wavelength per colour channel, metres")
    p.add_argument("--hologram-format", choices=["npz", "exr"], default="npz",
                   help="file format of the complex hologram (EXR: real/imaginary channels)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace --out if it holds an earlier clholo output (never anything else)")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="clholo", description="Wave-optics holograms from multiplane images (OpenCL).")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    p = sub.add_parser("info", help="list OpenCL platforms and devices, and the one clholo uses")
    p.set_defaults(func=cmd_info)

    p = sub.add_parser("demo", help="render scikit-image's motorcycle RGB-D scene as an RGB "
                                    "hologram and write its focal stack")
    _add_render_options(p, layers=8, near=2e-3, far=6e-3)
    p.add_argument("--scale", type=_positive, default=1.0,
                   help="resize the 741x500 scene by this factor first")
    p.add_argument("--out", default="clholo-demo",
                   help="output folder to create (see --overwrite)")
    p.set_defaults(func=cmd_demo)

    p = sub.add_parser("render", help="render a scene file or folder as a hologram")
    p.add_argument("inputs", nargs="+",
                   help="an MPI folder (mpi.json), a Stereo Magnification folder, an image and "
                        "a depth/disparity map, or a 3D Gaussian splat .ply")
    _add_render_options(p, layers=None, near=None, far=None)
    p.add_argument("--spacing", choices=["index", "depth", "inverse"], default="index",
                   help="how --near/--far re-place an MPI's planes")
    p.add_argument("--mode", choices=["hard", "soft"], default="hard",
                   help="RGB-D layering: each pixel in one plane, or split between two")
    p.add_argument("--depth-kind", choices=["auto", "depth", "disparity"], default="auto",
                   help="RGB-D: what the map holds (auto: disparity for .pfm and names with "
                        "'disp')")
    p.add_argument("--depth-spacing", choices=["linear", "disparity"], default="linear",
                   help="RGB-D: planes uniform in the map's values, or uniform in disparity "
                        "(inverse depth)")
    p.add_argument("--scale", type=_positive, default=1.0,
                   help="downsample the input by this factor in (0, 1] first")
    p.add_argument("--min-depth", type=_positive, default=None,
                   help="Stereo Magnification: nearest plane in scene units (default: the "
                        "network's default, 1)")
    p.add_argument("--max-depth", type=_positive, default=None,
                   help="Stereo Magnification: farthest plane in scene units (default: the "
                        "network's default, 100)")
    p.add_argument("--camera-json", default=None,
                   help="splats: a 3DGS cameras.json to take the camera from (default: a camera "
                        "framing the splats along +z)")
    p.add_argument("--camera-index", type=_whole(0), default=None,
                   help="splats: which camera of --camera-json (default: 0)")
    p.add_argument("--znear", type=_positive, default=None,
                   help="splats: near plane in scene units (default: 1%% of the median splat "
                        "depth)")
    p.add_argument("--out", default="clholo-render",
                   help="output folder to create (see --overwrite)")
    p.add_argument("--method", choices=["mpi", "rpws"], default="mpi",
                   help="a .ply: the MPI method, or random-phase wave splatting (slow, exact "
                        "baseline, docs/rpws.md)")
    p.add_argument("--max-splats", type=int, default=None,
                   help="a .ply: keep a random subset (seeded by --seed) of at most this many "
                        "visible splats (default: all)")
    p.set_defaults(func=cmd_render)

    p = sub.add_parser("bench", help="time clholo against the NumPy and PyTorch versions of "
                                     "the same method, side by side")
    p.add_argument("--size", type=_whole(8), default=1024, help="field size N (N x N pixels)")
    p.add_argument("--layers", type=_whole(1), default=32, help="MPI layers L")
    p.add_argument("--repeats", type=_whole(1), default=3,
                   help="timed repetitions per method (the best is reported)")
    p.add_argument("--pad", type=_pad, default=2.0,
                   help="zero padding of each propagation: 'auto' or a factor")
    p.add_argument("--no-scaling", action="store_true", help="skip the time-versus-L sweep")
    p.add_argument("--slm", action="store_true", help="the SLM's size instead: 1080x1920, "
                   "RGB, T=3, pad auto, against PyTorch CPU on the same grid (--layers, "
                   "--repeats apply)")
    p.set_defaults(func=cmd_bench)
    for module_name in COMMAND_MODULES:
        importlib.import_module(module_name).register_cli(sub)
    return parser


def main(argv: Optional[List[str]] = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    from clholo.host.runtime import NoDeviceError, ProgramBuildError

    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        # output folders are built under a temporary name and renamed only when complete, so
        # an interrupted command has written nothing
        print(f"clholo {args.command}: interrupted; nothing written", file=sys.stderr)
        return 130
    except (NoDeviceError, ProgramBuildError, ValueError, TypeError, OSError,
            MemoryError) as exc:
        print(f"clholo {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
