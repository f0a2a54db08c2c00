"""Every option that more than one command takes, defined once (pip's ``cmdoptions`` model), for
the command line and for manifest rows alike (``clholo batch``), so it lives in the library.

A command adds the groups it needs (:func:`add_scene_options`, :func:`add_optics_options`,
:func:`add_render_options`, :func:`add_method_option`, :func:`add_out_option`, ...) and turns
the parsed values into library objects with the matching ``*_from_args`` function, so an option
has one spelling, one type check and one help text in every command.

The number types (:func:`whole`, :func:`positive`, :func:`fraction`, :func:`pad`) raise
``argparse.ArgumentTypeError``, so a bad value is reported by argparse as a usage error
(exit 2) naming the option; :func:`parse_row` uses the same options on a manifest row and raises
:class:`clholo.errors.InputError` instead of exiting.
"""

from __future__ import annotations

import argparse
import math
from typing import List, Optional, Sequence

from clholo.errors import InputError

__all__ = ["whole", "positive", "metres", "fraction", "pad", "add_scene_options",
           "scene_spec_from_args", "add_optics_options", "optics_from_args", "match_channels",
           "add_render_options", "add_method_option", "add_out_option", "add_overwrite_option",
           "add_hologram_format_option", "add_render_flow_options", "SCENE_FIELDS", "RowParser", "parse_row"]


# ---- number types -----------------------------------------------------------------------

#: Most MPI planes made from an RGB-D pair or splats (``clholo.io.rgbd_to_mpi``'s limit too):
#: refused by the parser, before any loading or device buffer.
MAX_LAYERS = 256


def whole(minimum: int, maximum: Optional[int] = None):
    """argparse type: a whole number in ``[minimum, maximum]``."""
    def parse(value: str) -> int:
        try:
            n = int(value)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a whole number, got {value!r}") from None
        if n < minimum:
            raise argparse.ArgumentTypeError(f"must be >= {minimum}, got {n}")
        if maximum is not None and n > maximum:
            raise argparse.ArgumentTypeError(f"must be <= {maximum}, got {n}")
        return n
    parse.__name__ = "whole number"
    return parse


def _not_a_number(value: str) -> str:
    """The refusal of a value float() does not take; "1e-6,2e-6" is several values."""
    if "," in value:
        return (f"expected a number, got {value!r}: separate several values with spaces, not "
                f"commas (a decimal comma is written as a point)")
    return f"expected a number, got {value!r}"


def positive(value: str) -> float:
    """argparse type: a finite number > 0."""
    try:
        x = float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(_not_a_number(value)) from None
    if not (x > 0 and math.isfinite(x)):
        raise argparse.ArgumentTypeError(f"must be a finite number > 0, got {value!r}")
    return x


def non_negative(value: str) -> float:
    """argparse type: a finite number >= 0 (0 often means "off")."""
    try:
        x = float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(_not_a_number(value)) from None
    if not (x >= 0 and math.isfinite(x)):
        raise argparse.ArgumentTypeError(f"must be a finite number >= 0, got {value!r}")
    return x


#: The shortest bench distance a command takes (metres): nothing of a display sits within
#: 10 um of the SLM, and 1e-6 for 1 mm (micrometres typed for millimetres) placed a scene's
#: layers half a micrometre apart, a thousandth of the hologram's depth of focus
MIN_BENCH_DISTANCE_M = 1e-5


def metres(value: str) -> float:
    """argparse type: a distance in metres, finite, in ``[10 um, 1 m]`` (values above 1 m are
    almost always millimetres or scene units, below 10 um micrometres or nanometres: both are
    refused with the fix)."""
    x = positive(value)
    if x > 1.0:
        raise argparse.ArgumentTypeError(
            f"{value} m is more than a metre: give metres, e.g. 0.004 for 4 mm")
    if x < MIN_BENCH_DISTANCE_M:
        raise argparse.ArgumentTypeError(
            f"{value} m is less than 10 um: give metres, e.g. 0.004 for 4 mm")
    return x


def fraction(value: str) -> float:
    """argparse type: a number in (0, 1]."""
    x = positive(value)
    if x > 1:
        raise argparse.ArgumentTypeError(f"must be in (0, 1], got {value!r}")
    return x


def pad(value: str):
    """argparse type: ``auto`` or a padding factor >= 1."""
    if value == "auto":
        return "auto"
    try:
        factor = float(value)
    except ValueError:
        factor = float("nan")
    if not (factor >= 1 and math.isfinite(factor)):
        raise argparse.ArgumentTypeError(
            f"must be 'auto' or a factor >= 1 such as 2, got {value!r}")
    return factor


# ---- scene ----------------------------------------------------------------------------------

SCENE_FIELDS = ("layers", "near", "far", "spacing", "mode", "depth_kind", "depth_spacing",
                "match_size", "scale", "min_depth", "max_depth", "camera_json", "camera_index",
                "znear", "max_splats")


def add_scene_options(p: argparse.ArgumentParser, *, inputs: bool = True,
                      demo: bool = False) -> None:
    """The scene options: inputs (unless ``inputs=False``), layers, depths, RGB-D, Stereo
    Magnification and splat options. ``demo=True``: the bundled scene's options only (layers,
    near/far, scale), with its defaults."""
    if inputs:
        p.add_argument("inputs", nargs="+", metavar="SCENE",
                       help="an MPI folder (mpi.json), a Stereo Magnification folder, an image "
                            "and a depth/disparity map, an EXR with colour and a Z channel, or a 3D "
                            "Gaussian splat .ply")
    g = p.add_argument_group("scene")
    if demo:
        g.add_argument("--layers", type=whole(2, MAX_LAYERS), default=8, help="MPI planes to make")
        g.add_argument("--near", type=metres, default=2e-3,
                       help="depth of the nearest plane, metres behind the hologram plane")
        g.add_argument("--far", type=metres, default=6e-3,
                       help="depth of the farthest plane, metres behind the hologram plane")
        g.add_argument("--scale", type=fraction, default=1.0,
                       help="downsample the 741x500 scene by this factor in (0, 1] first")
        return
    g.add_argument("--layers", type=whole(1, MAX_LAYERS), default=None,
                   help="MPI planes to make from RGB-D or splats (default: 32; an MPI keeps "
                        "its own layers)")
    g.add_argument("--near", type=metres, default=None,
                   help="depth of the nearest plane, metres behind the hologram plane (default: "
                        "an MPI's own depths, which must then be metres)")
    g.add_argument("--far", type=metres, default=None,
                   help="depth of the farthest plane, metres behind the hologram plane (default: "
                        "an MPI's own depths, which must then be metres)")
    g.add_argument("--spacing", choices=["index", "depth", "inverse"], default=None,
                   help="MPI, Stereo Magnification and splat inputs: how --near/--far re-place "
                        "the planes (default: index)")
    g.add_argument("--mode", choices=["hard", "soft"], default=None,
                   help="RGB-D: each pixel in one plane, or split between two (default: hard)")
    g.add_argument("--depth-kind", choices=["auto", "depth", "disparity"], default=None,
                   help="RGB-D: what the map holds (default: auto, disparity for .pfm and names "
                        "with 'disp')")
    g.add_argument("--depth-spacing", choices=["linear", "disparity"], default=None,
                   help="RGB-D: planes uniform in the map's values, or uniform in disparity "
                        "(default: linear)")
    g.add_argument("--match-size", choices=["photo", "edges", "depth"], default=None,
                   help="RGB-D whose depth map is the photo's shape at another size (a "
                        "phone's): resize the depth map to the photo's size (photo; nearest "
                        "neighbour; edges: the same along the photo's edges) or the photo to "
                        "the depth map's (depth; anti-aliased) (default: refused; a depth "
                        "photo's own map: photo)")
    g.add_argument("--scale", type=fraction, default=None,
                   help="downsample the input by this factor in (0, 1] first (default: 1)")
    g.add_argument("--min-depth", type=positive, default=None,
                   help="Stereo Magnification: nearest plane in scene units (default: the "
                        "network's default, 1)")
    g.add_argument("--max-depth", type=positive, default=None,
                   help="Stereo Magnification: farthest plane in scene units (default: the "
                        "network's default, 100)")
    g.add_argument("--camera-json", default=None,
                   help="splats: a 3DGS cameras.json to take the camera from (default: a camera "
                        "framing the splats along +z)")
    g.add_argument("--camera-index", type=whole(0), default=None,
                   help="splats: which camera of --camera-json (default: 0)")
    g.add_argument("--znear", type=positive, default=None,
                   help="splats: near plane in scene units (default: 1%% of the median splat "
                        "depth)")
    g.add_argument("--max-splats", type=whole(1), default=None,
                   help="splats: keep a random subset (seeded by --seed) of at most this many "
                        "visible splats (default: all)")


def scene_spec_from_args(args: argparse.Namespace, *, demo: bool = False):
    """The :class:`clholo.scenes.SceneSpec` of parsed scene options."""
    from clholo.scenes import DEMO, SceneSpec

    values = {f: getattr(args, f) for f in SCENE_FIELDS if hasattr(args, f)}
    seed = getattr(args, "seed", 0) or 0
    if demo:
        return SceneSpec(inputs=(DEMO,), subset_seed=seed, **values)
    return SceneSpec(inputs=tuple(args.inputs), subset_seed=seed, **values)


# ---- optics, rendering, method ----------------------------------------------------------

def add_optics_options(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("optics")
    g.add_argument("--pitch", type=positive, default=8e-6, help="SLM pixel pitch, metres")
    g.add_argument("--wavelengths", type=positive, nargs="+", default=[638e-9, 520e-9, 450e-9],
                   help="one wavelength per colour channel, metres (a single-channel scene uses "
                        "the middle one when three are given)")


def optics_from_args(args: argparse.Namespace, *, channels: Optional[int] = None):
    """The :class:`clholo.Optics` of ``--pitch``/``--wavelengths`` (validated first, so a unit
    mistake is reported before a scene loads); with ``channels``, matched to the scene by
    :func:`match_channels`."""
    from clholo.scene import Optics

    optics = Optics(pitch=args.pitch, wavelengths=tuple(args.wavelengths))
    return optics if channels is None else match_channels(optics, channels)


def match_channels(optics, channels: int, *, source: str = "--wavelengths"):
    """``optics`` for a scene of ``channels`` colours: a one-channel scene takes the middle of
    three wavelengths (green); any other mismatch is refused, naming where the wavelengths came
    from (``source``: ``--wavelengths``, or a bench file's ``[slm] wavelengths_m``)."""
    from clholo.scene import Optics

    wavelengths = tuple(optics.wavelengths)
    if channels == len(wavelengths):
        return optics
    if channels == 1 and len(wavelengths) == 3:
        return Optics(pitch=optics.pitch, wavelengths=wavelengths[1:2])
    raise InputError(f"the scene has {channels} colour channel(s) but {source} gives "
                     f"{len(wavelengths)}: give {channels}")


def add_render_options(p: argparse.ArgumentParser, *, frames: int = 8) -> None:
    """``--frames``, ``--seed``, ``--pad`` (the hologram's)."""
    g = p.add_argument_group("hologram")
    g.add_argument("--frames", type=whole(1), default=frames,
                   help="time-multiplexed frames T, each with fresh random phases (paper: 24)")
    g.add_argument("--seed", type=whole(0), default=0,
                   help="key of the random-phase stream (and of --max-splats' subset); the same "
                        "seed gives the same hologram")
    g.add_argument("--pad", type=pad, default="auto",
                   help="zero padding of each propagation: 'auto' (covers the kernel's spread) "
                        "or a factor such as 2")


def add_method_option(p: argparse.ArgumentParser, *, default: str = "mpi") -> None:
    from clholo.methods import METHODS

    p.add_argument("--method", choices=list(METHODS), default=default,
                   help="hologram method: " + "; ".join(f"{m.name}: {m.summary}"
                                                         for m in METHODS.values()))


def add_hologram_format_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--hologram-format", choices=["npz", "exr"], default="npz",
                   help="file format of the complex hologram (EXR: real/imaginary channels)")


def add_render_flow_options(p: argparse.ArgumentParser, *, demo: bool = False) -> None:
    """Everything ``clholo render`` (``demo=True``: ``clholo demo``) takes but ``--out``: the
    scene, the method, the hologram, the optics and the hologram's file format. ``clholo batch``
    parses each manifest row with exactly these."""
    add_scene_options(p, inputs=not demo, demo=demo)
    add_method_option(p)
    add_render_options(p)
    add_optics_options(p)
    add_hologram_format_option(p)


def add_out_option(p: argparse.ArgumentParser, *, default: Optional[str], kind: str = "folder",
                   what: str = "", required: bool = False, option: str = "--out",
                   overwrite: bool = True) -> None:
    """``--out`` (a folder or a single file) and ``--overwrite``, with one wording."""
    where = f" {what}" if what else ""
    if kind == "folder":
        text = (f"output folder{where} to create; it is built under a temporary name and "
                f"renamed when complete (see --overwrite)")
    else:
        text = f"output file{where}; written under a temporary name and renamed when complete"
    if default is None and not required:
        text += " (default: none)"
    p.add_argument(option, default=default, required=required, help=text)
    if overwrite:
        add_overwrite_option(p)


def add_overwrite_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--overwrite", action="store_true",
                   help="replace an output that clholo wrote earlier; never anything else, and "
                        "never a folder holding files clholo did not write")


# ---- manifest rows -----------------------------------------------------------------------

class _RowError(Exception):
    pass


class RowParser(argparse.ArgumentParser):
    """An argparse parser that raises :class:`clholo.errors.InputError` instead of exiting
    (pip's ``req_file.build_parser`` model): a manifest row is parsed with the command's own
    options, and a bad cell names the row."""

    def __init__(self, *args, **kwargs):
        kwargs.setdefault("add_help", False)
        kwargs.setdefault("allow_abbrev", False)
        super().__init__(*args, **kwargs)

    def error(self, message):  # noqa: D401 (argparse's hook)
        raise _RowError(message)

    def exit(self, status=0, message=None):
        raise _RowError(message or f"exit {status}")


def parse_row(parser: argparse.ArgumentParser, argv: Sequence[str], where: str
              ) -> argparse.Namespace:
    """Parse ``argv`` with ``parser`` (a :class:`RowParser`), raising
    :class:`clholo.errors.InputError` that starts with ``where`` (e.g. ``"manifest.csv row
    3"``)."""
    try:
        return parser.parse_args(list(argv))
    except _RowError as exc:
        raise InputError(f"{where}: {exc}") from None


def option_names(argv: List[str]) -> List[str]:
    """The ``--names`` in an argument list (for messages)."""
    return [a for a in argv if a.startswith("--")]
