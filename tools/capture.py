"""Capture sweeps: step a stage through positions, show a pattern sequence at each, and let a
camera take one image per pattern.

Output folder (written under a temporary name, renamed when complete)::

    OUT/
      log.json                   kind, start/end times, stage, positions requested and measured,
                                 move times, and per image: file, frame t, colour c, the times the
                                 pattern went on screen, settled and was captured
      frames.csv                 the display's frame-time log (see Display.write_log)
      clholo-output.json         clholo's output manifest (clholo.io.output)
      p000_t00_c0.png ...        one image per position p, frame t, colour c

The time-multiplexed view at a position is the sum (or mean) of its T x C images.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import json
import math
import shutil
import time
from pathlib import Path
from typing import Optional, Sequence, Union

import numpy as np

from .stages.base import TOLERANCE_MM, Stage, StagePositionError, check_setting

__all__ = ["sweep", "focal_sweep", "parallax_sweep", "check_patterns", "load_patterns"]


def check_patterns(patterns, shape: Sequence[int]) -> np.ndarray:
    """A ``uint8 [T, C, H, W]`` sequence (``[C, H, W]`` and ``[H, W]`` are promoted).

    Parameters
    ----------
    patterns : array
        The sequence.
    shape : (int, int)
        The SLM's ``(height, width)``, pixels.
    """
    from .slm import check_pattern

    if not isinstance(patterns, np.ndarray):
        raise TypeError(f"patterns must be a NumPy uint8 array [T, C, H, W], got "
                        f"{type(patterns).__name__}")
    while patterns.ndim < 4:
        patterns = patterns[None]
    if patterns.ndim != 4:
        raise ValueError(f"patterns must be [T, C, H, W], got shape {patterns.shape}")
    # before any indexing: patterns[0, 0] of an empty T or C axis does not exist
    if patterns.shape[0] == 0 or patterns.shape[1] == 0:
        from clholo.errors import InputError

        raise InputError(f"patterns holds no pattern (shape {patterns.shape}): T (frames) and "
                         f"C (colours) must be at least 1")
    check_pattern(patterns[0, 0], shape, name="patterns[t, c]")
    return patterns


def _as_list(name: str, values, example: str) -> list:
    """``values`` as a list, refusing a single number (or a string) with the fix: a sweep's
    positions and depths are lists even for one entry."""
    from clholo.errors import InputTypeError

    try:
        items = None if isinstance(values, (str, bytes, dict)) else list(values)
    except TypeError:   # a number: not iterable
        items = None
    if items is None:
        raise InputTypeError(f"{name} must be a list of numbers, one per stage position, got "
                             f"{values!r}: give e.g. {example} (a list even for one)")
    return items


def _numbers(name: str, values, example: str) -> list:
    """``values`` as a list of finite floats (:func:`_as_list`), each named by its index."""
    from clholo.validate import real_scalar

    return [real_scalar(f"{name}[{i}]", v) for i, v in
            enumerate(_as_list(name, values, example))]


def _metres(name: str, value, example: str) -> float:
    """``value`` checked as the bench file checks its metres
    (:func:`clholo.validate.bench_metres`: finite, > 0, at most 1 m), naming ``name``."""
    from clholo.validate import bench_metres

    return bench_metres(name, value, example=example)


def _check_camera(camera) -> None:
    """Refuse, before anything moves, a camera without a ``capture(path, info)`` method."""
    from clholo.errors import InputTypeError

    if not callable(getattr(camera, "capture", None)):
        raise InputTypeError(f"camera must have a capture(path, info) method that takes one "
                             f"image, writes it to path and returns the path written "
                             f"(clholo.tools.camera.FileCamera, OpenCVCamera), got "
                             f"{type(camera).__name__}")


def _image_size(path: Path, where: str) -> tuple:
    """``(height, width, channels)`` of the image file a camera wrote, from its header."""
    from clholo.errors import InputError
    from clholo.io.images import _oiio

    oiio = _oiio()
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise InputError(f"the camera wrote {path}{where}, which cannot be read as an image "
                         f"({oiio.geterror().strip() or 'unknown format'}): its capture must "
                         f"write an image (PNG) and return its path")
    try:
        spec = inp.spec()
        return (spec.height, spec.width, spec.nchannels)
    finally:
        inp.close()


def _captured(result, where: str) -> Path:
    """The path ``camera.capture`` returned, checked: a path to a file that exists."""
    import os

    from clholo.errors import InputError, InputTypeError

    if not isinstance(result, (str, os.PathLike)):
        raise InputTypeError(f"camera.capture{where} returned {result!r}: it must return the "
                             f"path of the image it wrote (a str or pathlib.Path)")
    path = Path(result)
    if not path.is_file():
        raise InputError(f"camera.capture{where} returned {path}, which is not a file: it must "
                         f"write the image and return the path written")
    return path


def load_patterns(path: Union[str, Path], shape: Sequence[int], *,
                  option: str = "patterns") -> np.ndarray:
    """Read a pattern sequence file and check it before any hardware moves: a ``.npy`` of
    ``uint8`` levels ``[T, C, H, W]`` (``[C, H, W]`` and ``[H, W]`` are promoted) with
    ``(H, W) = shape``, the SLM's (height, width).

    Parameters
    ----------
    path : str or os.PathLike
        The ``.npy`` file.
    shape : (int, int)
        The SLM's ``(height, width)``, pixels.
    option : str
        The option named in refusals.

    Raises
    ------
    clholo.errors.InputError
        Naming ``option``, the file, what it holds and the fix: not a regular file, not a
        ``.npy`` (or a pickled one), a damaged or truncated one, not ``uint8``, not 2 to 4
        axes, not the SLM's size, no pattern at all.
    FileNotFoundError
        The file does not exist.
    """
    from clholo.errors import InputError
    from clholo.io._npy import load_npy

    path = Path(path)
    where = f"{option} {path}"
    if path.is_dir():
        raise InputError(f"{where} is a folder: give the .npy file of uint8 patterns")
    # load_npy refuses what is not a regular .npy of numbers, and a header that claims other
    # than the bytes stored (np.load allocated what a damaged header claimed)
    data = load_npy(path, what=option, fix="give one .npy array of uint8 levels [T, C, H, W] "
                                           "(numpy.save of the output of clholo.encode.quantize)")
    H, W = (int(v) for v in shape)
    if data.dtype != np.uint8:
        raise InputError(f"{where} holds {data.dtype} values: the SLM takes uint8 levels 0..255; "
                         f"encode and quantise the holograms first (clholo encode, or "
                         f"clholo.encode.quantize)")
    if not 2 <= data.ndim <= 4:
        raise InputError(f"{where} has shape {data.shape}: give [T, C, H, W] (or [C, H, W], "
                         f"[H, W]) patterns")
    if data.shape[-2:] != (H, W):
        raise InputError(f"{where} has patterns of {data.shape[-2]} x {data.shape[-1]} pixels "
                         f"(H x W) but the SLM is {H} x {W} ([slm] resolution = [{W}, {H}]): "
                         f"encode at the SLM's size, or fix the resolution in the bench file")
    if data.size == 0:
        raise InputError(f"{where} holds no pattern (shape {data.shape})")
    return check_patterns(data, (H, W))


def sweep(kind: str, stage: Stage, display, camera, patterns: np.ndarray,
          positions_mm: Sequence[float], out: Union[str, Path], *, home: bool = True,
          overwrite: bool = False, move_timeout: float = 60.0,
          tolerance_mm: Optional[float] = None,
          extra: Optional[dict] = None, out_option: str = "out") -> Path:
    """Run one sweep (see the module docstring for what it writes); returns ``out``.

    Parameters
    ----------
    kind : str
        Recorded in the log ("focal-sweep", "parallax-sweep").
    stage : Stage
        The stage to step (already open).
    display : Display
        The SLM (or a MemoryDisplay).
    camera : Camera
        ``capture(path, info) -> Path`` (checked before anything moves). ``info`` holds
        ``index`` (the position's), ``position_mm`` (measured), ``t`` and ``c``. Each image it
        returns is checked: a file that exists, of the same size as the first.
    patterns : uint8 [T, C, H, W]
        The sequence shown at every position, colour after colour.
    positions_mm : sequence of float
        Stage positions in mm, each inside ``stage.limits`` (all checked before the first move);
        a list even for one position.
    out : path
        Output folder (checked before anything moves); an existing one is replaced only with
        ``overwrite`` and only if clholo wrote it (:mod:`clholo.io.output`).
    overwrite : bool
        Replace an existing ``out`` that clholo wrote.
    move_timeout : float
        Seconds one stage move (or the homing) may take.
    tolerance_mm : float, optional
        How far (mm) the position measured after each move may lie from the requested one;
        farther (a stage that stopped at the end of its travel, limits wider than it
        travels, a non-finite read-out) raises
        :class:`~clholo.tools.stages.base.StagePositionError` naming the position, and
        nothing is written. Default: the stage's ``tolerance_mm`` (0.005 mm).
    home : bool
        Home the stage first.
    extra : dict
        More entries for the log (e.g. the depth or angle of each position).
    out_option : str
        How error messages name ``out`` (``--out`` from the command line).
    """
    from clholo.errors import EnvironmentProblem
    from clholo.io.output import check_output_folder, output_folder

    from .slm import _write_frame_rows, on_display_lost

    # the camera, every pattern and every setting are checked before anything moves
    move_timeout = check_setting("move_timeout", move_timeout)
    if tolerance_mm is None:
        tolerance_mm = getattr(stage, "tolerance_mm", TOLERANCE_MM[0])
    tolerance_mm = check_setting("tolerance_mm", tolerance_mm)
    _check_camera(camera)
    patterns = display.check_sequence(check_patterns(patterns, display.shape))
    positions = _numbers("positions_mm", positions_mm, "positions_mm=[5.0]")
    if not positions:
        raise ValueError("positions_mm is empty: give at least one stage position")
    for i, p in enumerate(positions):
        stage._check_target(p, name=f"positions_mm[{i}]")
    check_output_folder(out, overwrite=overwrite, option=out_option)
    log = {"kind": kind, "started": _dt.datetime.now(_dt.timezone.utc).isoformat(),
           "stage": type(stage).__name__, "stage_limits_mm": list(stage.limits),
           "patterns_shape": list(patterns.shape), "clock": "time.monotonic() seconds",
           "positions": []}
    log.update(extra or {})
    with contextlib.ExitStack() as guards:
        tmp = guards.enter_context(output_folder(out, overwrite=overwrite, command=kind,
                                                 option=out_option))
        # the X server going away ends the process inside a GLFW call, where no finally
        # runs (clholo.tools.slm.on_display_lost): remove the temporary folder and stop the
        # stage from there
        guards.enter_context(on_display_lost(
            lambda: shutil.rmtree(tmp, ignore_errors=True), "nothing written"))
        stop_blind = getattr(stage, "_stop_blind", None)
        if callable(stop_blind):
            guards.enter_context(on_display_lost(stop_blind, "the stage was told to stop"))
        if home:
            t0 = time.monotonic()
            stage.home(timeout=move_timeout)
            log["homed"] = {"start_s": t0, "end_s": time.monotonic()}
        first_log = len(display.log)
        first_size = []   # (height, width, channels) of the first image: all must match it
        for i, target in enumerate(positions):
            entry = {"index": i, "requested_mm": target, "move_start_s": time.monotonic()}
            stage.move_to(target, timeout=move_timeout)
            entry["move_end_s"] = time.monotonic()
            entry["measured_mm"] = _arrived(stage, i, target, tolerance_mm)
            entry["images"] = images = []

            def on_frame(rec, i=i, target=target, entry=entry, images=images):
                name = f"p{i:03d}_t{rec.t:02d}_c{rec.c}"
                info = {"index": i, "position_mm": entry["measured_mm"], "t": rec.t,
                        "c": rec.c}
                where = f" at position index {i} ({target:g} mm), frame t={rec.t}, " \
                        f"colour c={rec.c}"
                result = camera.capture(tmp / name, info)
                captured = time.monotonic()   # before the checks below, which take time too
                path = _captured(result, where)
                size = _image_size(path, where)
                if not first_size:
                    first_size.append(size)
                elif size != first_size[0]:
                    h, w, c = size
                    h0, w0, c0 = first_size[0]
                    # the camera changed mode under us: hardware, not the user's input
                    raise EnvironmentProblem(
                        f"the camera's image{where} is {h} x {w} pixels with {c} channel(s), "
                        f"the first was {h0} x {w0} with {c0}: a sweep's images must all have "
                        f"one size (the camera's mode changed? another program set it?); "
                        f"nothing written")
                images.append({"file": path.name, "t": rec.t, "c": rec.c,
                               "shown_s": rec.shown_s, "settled_s": rec.settled_s,
                               "captured_s": captured})

            display.play(patterns, on_frame=on_frame)
            log["positions"].append(entry)
        log["finished"] = _dt.datetime.now(_dt.timezone.utc).isoformat()
        # allow_nan=False: NaN/Infinity is not JSON (positions are checked finite above)
        (tmp / "log.json").write_text(json.dumps(log, indent=1, allow_nan=False))
        _write_frame_rows(display.log[first_log:], tmp / "frames.csv")  # tmp: a new folder
    return Path(out)


def _arrived(stage: Stage, index: int, target: float, tolerance_mm: float) -> float:
    """The position ``stage`` measures after the move to ``target`` (mm), checked: finite and
    within ``tolerance_mm`` of it. A controller ends a move at the end of its travel as if it
    were done, so without this a sweep would capture the wrong plane without a word."""
    measured = float(stage.position())
    where = f"position index {index} ({target:g} mm)"
    if not math.isfinite(measured):
        raise StagePositionError(f"{where}: the stage reports its position as {measured!r}: a "
                                 f"controller fault or a garbled line; nothing written")
    if abs(measured - target) > tolerance_mm:
        raise StagePositionError(
            f"{where}: the stage stopped at {measured:.4f} mm, {measured - target:+.4f} mm "
            f"from the position asked for (tolerance_mm = {tolerance_mm:g}): it reached the "
            f"end of its travel (limits_mm wider than the stage travels?) or was blocked; "
            f"nothing written")
    return measured


def focal_sweep(stage: Stage, display, camera, patterns, positions_mm, out, *,
                depths_m: Optional[Sequence[float]] = None, **kwargs) -> Path:
    """A focal stack: the camera's z stage steps through ``positions_mm``; ``depths_m`` (the
    scene depth each position focuses on) goes into the log.

    Parameters
    ----------
    stage : Stage
        The stage to step (already open).
    display : Display
        The SLM (or a :class:`clholo.tools.slm.MemoryDisplay`).
    camera : Camera
        ``capture(path, info) -> Path``.
    patterns : uint8 array ``[T, C, H, W]``
        The sequence shown at every position.
    positions_mm : sequence of float
        Stage positions, millimetres.
    out : str or os.PathLike
        The output folder.
    depths_m : sequence of float, optional
        The scene depth (metres) each position focuses on, one per position; each checked as
        the bench file's ``depths_m`` (finite, ``0 < d <= 1``: millimetres are refused).
    **kwargs
        Passed to :func:`sweep` (``home``, ``overwrite``, ``move_timeout``, ...).
    """
    positions = _numbers("positions_mm", positions_mm, "positions_mm=[5.0, 7.5]")
    extra = {}
    if depths_m is not None:
        example = "depths_m=[0.002, 0.004] for 2 and 4 mm"
        depths = _as_list("depths_m", depths_m, example)
        if len(depths) != len(positions):
            raise ValueError(f"depths_m has {len(depths)} entries but positions_mm has "
                             f"{len(positions)}: give one depth per position")
        extra["depths_m"] = [_metres(f"depths_m[{i}]", d, example)
                             for i, d in enumerate(depths)]
    return sweep("focal-sweep", stage, display, camera, patterns, positions_mm, out,
                 extra=extra, **kwargs)


def parallax_sweep(stage: Stage, display, camera, patterns, positions_mm, out, *,
                   distance_m: Optional[float] = None, **kwargs) -> Path:
    """Views through a pupil stepped across the Fourier plane; with the Fourier lens' focal
    length ``distance_m`` the log holds each position's viewing angle
    ``atan(position / distance)`` in degrees.

    Parameters
    ----------
    stage : Stage
        The stage to step (already open).
    display : Display
        The SLM (or a :class:`clholo.tools.slm.MemoryDisplay`).
    camera : Camera
        ``capture(path, info) -> Path``.
    patterns : uint8 array ``[T, C, H, W]``
        The sequence shown at every position.
    positions_mm : sequence of float
        Stage positions, millimetres.
    out : str or os.PathLike
        The output folder.
    distance_m : float, optional
        The Fourier lens' focal length, metres; checked as the bench file's ``distance_m``
        (finite, ``0 < d <= 1``: millimetres are refused).
    **kwargs
        Passed to :func:`sweep` (``home``, ``overwrite``, ``move_timeout``, ...).
    """
    positions = _numbers("positions_mm", positions_mm, "positions_mm=[-2.0, 0.0, 2.0]")
    extra = {}
    if distance_m is not None:
        distance = _metres("distance_m", distance_m, "distance_m=0.2 for 200 mm")
        extra["distance_m"] = distance
        # positions are checked (finite, in travel) by sweep before anything is written
        extra["angles_deg"] = [float(np.degrees(np.arctan(p * 1e-3 / distance)))
                               for p in positions]
    return sweep("parallax-sweep", stage, display, camera, patterns, positions_mm, out,
                 extra=extra, **kwargs)
