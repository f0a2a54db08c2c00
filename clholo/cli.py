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


def _pad(value: str):
    if value == "auto":
        return "auto"
    try:
        return float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--pad must be 'auto' or a factor such as 2, got {value!r}")


def cmd_demo(args: argparse.Namespace) -> int:
    import time
    from pathlib import Path

    from clholo.demo import StepLog, motorcycle_mpi, render_and_save

    log = StepLog()
    t = time.perf_counter()
    mpi = motorcycle_mpi(layers=args.layers, near=args.near, far=args.far, scale=args.scale)
    log.step(f"scene: scikit-image Middlebury motorcycle RGB-D -> {mpi.layers}-plane MPI "
             f"({mpi.shape[0]}x{mpi.shape[1]})", time.perf_counter() - t)
    render_and_save(mpi, _optics(args), Path(args.out), frames=args.frames, seed=args.seed,
                    pad=args.pad, log=log, source="skimage.data.stereo_motorcycle",
                    hologram_format=args.hologram_format)
    return 0


def cmd_render(args: argparse.Namespace) -> int:
    import time
    from pathlib import Path

    from clholo.demo import StepLog, render_and_save
    from clholo.io import load_scene

    log = StepLog()
    t = time.perf_counter()
    inputs = args.inputs[0] if len(args.inputs) == 1 else list(args.inputs)
    mpi = load_scene(inputs, layers=args.layers, near=args.near, far=args.far,
                     spacing=args.spacing, mode=args.mode, depth_kind=args.depth_kind)
    optics = _optics(args)
    if mpi.channels != optics.channels and mpi.channels == 1:
        optics = type(optics)(pitch=optics.pitch, wavelengths=optics.wavelengths[1:2])
    log.step(f"scene: {' + '.join(args.inputs)} -> {mpi.layers}-plane MPI "
             f"({mpi.shape[0]}x{mpi.shape[1]}x{mpi.channels}), depths "
             f"{mpi.depths[0]:.4g}..{mpi.depths[-1]:.4g} m", time.perf_counter() - t)
    if mpi.depths[-1] > 1.0:
        raise ValueError(
            f"the scene's depths reach {mpi.depths[-1]:.4g} m (scene units?): give --near and "
            f"--far in metres behind the hologram plane, e.g. --near 0.002 --far 0.006")
    render_and_save(mpi, optics, Path(args.out), frames=args.frames, seed=args.seed,
                    pad=args.pad, log=log, source=" + ".join(args.inputs),
                    hologram_format=args.hologram_format)
    return 0


def cmd_bench(args: argparse.Namespace) -> int:
    from clholo.bench import run_hologram_benchmark, run_slm_benchmark

    if args.slm:
        run_slm_benchmark(repeats=args.repeats, layers=args.layers)
        return 0
    run_hologram_benchmark(size=args.size, layers=args.layers, repeats=args.repeats,
                           scaling=not args.no_scaling, pad=args.pad)
    return 0


def _add_render_options(p: argparse.ArgumentParser, *, layers: Optional[int], near, far) -> None:
    p.add_argument("--layers", type=int, default=layers,
                   help="number of MPI planes to make (RGB-D, splats)")
    p.add_argument("--near", type=float, default=near,
                   help="depth of the nearest plane, metres behind the hologram plane")
    p.add_argument("--far", type=float, default=far,
                   help="depth of the farthest plane, metres behind the hologram plane")
    p.add_argument("--frames", type=int, default=8, help="time-multiplexed frames T (paper: 24)")
    p.add_argument("--seed", type=int, default=0, help="random-phase seed")
    p.add_argument("--pad", type=_pad, default="auto", help="'auto' or a factor such as 2")
    p.add_argument("--pitch", type=float, default=8e-6, help="SLM pixel pitch, metres")
    p.add_argument("--wavelengths", type=float, nargs="+", default=[638e-9, 520e-9, 450e-9],
                   help="one wavelength per colour channel, metres")
    p.add_argument("--hologram-format", choices=["npz", "exr"], default="npz")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="clholo", description="Wave-optics holograms from multiplane images (OpenCL).")
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("info", help="list OpenCL platforms and devices, and the one clholo uses")
    p.set_defaults(func=cmd_info)

    p = sub.add_parser("demo", help="render scikit-image's motorcycle RGB-D scene as an RGB "
                                    "hologram and write its focal stack")
    _add_render_options(p, layers=8, near=2e-3, far=6e-3)
    p.add_argument("--scale", type=float, default=1.0,
                   help="resize the 741x500 scene by this factor first")
    p.add_argument("--out", default="clholo-demo", help="output folder (replaced when done)")
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
    p.add_argument("--out", default="clholo-render", help="output folder (replaced when done)")
    p.set_defaults(func=cmd_render)

    p = sub.add_parser("bench", help="time clholo against the NumPy and PyTorch versions of "
                                     "the same method, side by side")
    p.add_argument("--size", type=int, default=1024, help="field size N (N x N)")
    p.add_argument("--layers", type=int, default=32)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--pad", type=_pad, default=2.0)
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
    except (NoDeviceError, ProgramBuildError, ValueError, TypeError, FileNotFoundError,
            FileExistsError, MemoryError) as exc:
        print(f"clholo {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
