"""The bench's configuration: one TOML file, not code.

Example (every key optional except where the sweep needs it; lengths in the unit of their name,
and every value with a unit checked for it: a settle time in milliseconds, depths in millimetres,
counts per micrometre, a phase table in degrees are refused naming the file, key and fix)::

    [slm]
    monitor = "PLUTO"              # name substring, or an integer index
    resolution = [1920, 1080]      # width, height
    pitch_m = 8e-6
    wavelengths_m = [638e-9, 520e-9, 450e-9]
    luts = ["red.lut", "green.lut", "blue.lut"]   # 256 levels each; paths relative to this file
    phase_luts = ["linear:255", "lut_g.csv", "linear:200"]   # encoders' phase->gray tables
    settle_s = 0.02                # seconds (a value above 1 s is refused: milliseconds?)
    refresh_hz = 60                # the SLM monitor's refresh; paces the memory display

    [z_stage]                      # camera focus (focal sweeps)
    port = "/dev/ttyUSB0"
    kind = "apt"
    counts_per_mm = 34554.96       # Thorlabs' current value for the Z8 motor (older: 34304)
    limits_mm = [0.0, 25.0]
    tolerance_mm = 0.005           # a sweep refuses a measured position farther from its target
    move_timeout = 60              # seconds one move (or homing) of a sweep may take

    [pupil_stage]                  # pupil at the Fourier plane (parallax sweeps)
    port = "/dev/ttyUSB1"
    kind = "conex"

    [camera]
    kind = "file"                  # "file" (writes the SLM's levels) or "opencv"
    device = 0

    [focal_sweep]
    positions_mm = [5.0, 7.5, 10.0]
    depths_m = [0.002, 0.004, 0.006]   # optional: the scene depth each position focuses on

    [parallax_sweep]
    positions_mm = [-2.0, 0.0, 2.0]
    distance_m = 0.2               # optional: lens focal length, to log viewing angles
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Dict, List, Optional, Tuple, Union

import numpy as np

__all__ = ["BenchConfig", "StageConfig", "SweepConfig", "load_bench_config", "parse_bench_config"]


def _toml():
    if sys.version_info >= (3, 11):
        import tomllib
    else:  # pragma: no cover - 3.9/3.10
        import tomli as tomllib
    return tomllib


@dataclass
class StageConfig:
    """A stage of the bench file: how to open it.

    Attributes
    ----------
    port : str
        Serial port or pyserial URL (``/dev/ttyUSB0``, ``COM3``, a pty's name).
    kind : str
        ``"apt"`` (Thorlabs) or ``"conex"`` (Newport).
    settings : dict
        Passed to :func:`clholo.tools.stages.open_stage`.
    move_timeout : float
        Seconds one move (or homing) of a capture sweep may take (``move_timeout``).
    """
    port: str
    kind: str = "apt"
    settings: Dict[str, Any] = field(default_factory=dict)   # passed to open_stage
    move_timeout: float = 60.0

    def open(self):
        """Open the stage (:func:`clholo.tools.stages.open_stage`)."""
        from clholo.tools.stages import open_stage

        return open_stage(self.port, self.kind, **self.settings)


@dataclass
class SweepConfig:
    """A capture sweep of the bench file.

    Attributes
    ----------
    positions_mm : list of float
        Stage positions, millimetres.
    depths_m : list of float, optional
        Focal sweeps: the scene depth each position focuses on, metres.
    distance_m : float, optional
        Parallax sweeps: the Fourier lens' focal length, metres.
    """
    positions_mm: List[float]
    depths_m: Optional[List[float]] = None
    distance_m: Optional[float] = None


@dataclass
class BenchConfig:
    """The bench file (``bench.toml``, ``docs/bench.md``) as checked values in SI units.

    Attributes
    ----------
    monitor : str, int or None
        The SLM's monitor (name substring or index); None: the one of ``resolution``.
    resolution : (int, int)
        The SLM's ``(width, height)``, pixels.
    pitch_m : float
        SLM pixel pitch, metres.
    wavelengths_m : tuple of float
        Laser wavelengths, metres, one per colour.
    lut_files : list of pathlib.Path, optional
        Display lookup tables, one per wavelength (:meth:`luts` reads them).
    phase_luts : list of str, optional
        Phase lookup tables for :func:`clholo.encode.quantize.quantize` (``"linear"``,
        ``"linear:N"`` or a file's path): one for all colours or one per wavelength, where a
        file of one column per colour counts as one table per colour
        (:func:`clholo.encode.quantize.parse_luts`).
    settle_s : float
        Liquid-crystal settle time after a swap, seconds.
    refresh_hz : float
        The SLM monitor's refresh rate, hertz.
    z_stage, pupil_stage : StageConfig, optional
        The camera's z stage and the Fourier-plane pupil stage.
    camera : dict
        The camera's kind and settings.
    focal_sweep, parallax_sweep : SweepConfig, optional
        The sweeps.
    source : pathlib.Path, optional
        The file it was read from.
    """
    monitor: Union[str, int, None] = None
    resolution: Tuple[int, int] = (1920, 1080)
    pitch_m: float = 8e-6
    wavelengths_m: Tuple[float, ...] = (638e-9, 520e-9, 450e-9)
    lut_files: Optional[List[Path]] = None
    phase_luts: Optional[List[str]] = None
    settle_s: float = 0.0
    refresh_hz: float = 60.0   # the SLM monitor's refresh (Pluto-2.1: 60 Hz)
    z_stage: Optional[StageConfig] = None
    pupil_stage: Optional[StageConfig] = None
    camera: Dict[str, Any] = field(default_factory=lambda: {"kind": "file"})
    focal_sweep: Optional[SweepConfig] = None
    parallax_sweep: Optional[SweepConfig] = None
    source: Optional[Path] = None

    def luts(self) -> Optional[List[np.ndarray]]:
        """The LUT files read (one per wavelength), or None."""
        if self.lut_files is None:
            return None
        from clholo.tools.slm import load_lut

        return [load_lut(p) for p in self.lut_files]


_SECTIONS = {
    "slm": {"monitor", "resolution", "pitch_m", "wavelengths_m", "luts", "phase_luts",
            "settle_s", "refresh_hz"},
    "z_stage": None, "pupil_stage": None,   # port, kind, anything the driver takes
    "camera": {"kind", "device", "width", "height"},
    "focal_sweep": {"positions_mm", "depths_m"},
    "parallax_sweep": {"positions_mm", "distance_m"},
}
_STAGE_KEYS = {"apt": {"counts_per_mm", "limits_mm", "channel", "reply_timeout", "poll",
                       "keepalive", "retries", "require_homed", "purge_dwell", "tolerance_mm",
                       "move_timeout"},
               "conex": {"address", "limits_mm", "reply_timeout", "retries", "reset_wait",
                         "poll", "tolerance_mm", "move_timeout"}}
#: stage keys for the sweep, not the driver (not passed to open_stage)
_SWEEP_KEYS = {"move_timeout"}

# Plausible ranges of the values with a unit; a value outside is almost always another unit
# (milliseconds for seconds, millimetres for metres, counts per micrometre for counts per mm),
# and is refused with the fix rather than run (a 150 s settle, a 2 m focus depth). The stages'
# keys are checked by the drivers' own check (clholo.tools.stages.base.check_setting), the
# SLM's settle_s and refresh_hz by the display's (clholo.tools.slm.check_settle_s,
# check_refresh_hz), so that the bench file and the Python API refuse the same values.
#: travel of a bench stage, mm
_TRAVEL_MM = 1000.0


class _Bad(ValueError):
    """A bad value in the bench file; :func:`load_bench_config` adds the file's name."""


def _numbers(where: str, value, *, length: Optional[int] = None) -> List[float]:
    from clholo.validate import real_scalar

    if not isinstance(value, (list, tuple)) or not value:
        raise _Bad(f"{where} must be a non-empty list of numbers, got {value!r}")
    try:
        out = [real_scalar(where, v) for v in value]
    except (TypeError, ValueError) as exc:
        raise _Bad(str(exc)) from None
    if length is not None and len(out) != length:
        raise _Bad(f"{where} must have {length} entries, got {len(out)}")
    return out


def _number(where: str, value) -> float:
    from clholo.validate import real_scalar

    try:
        return real_scalar(where, value)
    except (TypeError, ValueError) as exc:
        raise _Bad(str(exc)) from None


def _whole(where: str, value, minimum: int, maximum: Optional[int] = None) -> int:
    from clholo.validate import count

    try:
        return count(value, name=where, minimum=minimum, maximum=maximum)
    except (TypeError, ValueError) as exc:
        raise _Bad(str(exc)) from None


def _slm_value(check, key: str, value):
    """``[slm] key`` checked by the display's own check (:mod:`clholo.tools.slm`)."""
    try:
        return check(value, label=f"[slm] {key}")
    except (TypeError, ValueError) as exc:
        raise _Bad(str(exc)) from None


def _metres(where: str, value, example: str) -> float:
    from clholo.validate import bench_metres

    try:
        return bench_metres(where, value, example=example)
    except (TypeError, ValueError) as exc:
        raise _Bad(str(exc)) from None


def _stage(where: str, table: dict) -> StageConfig:
    from clholo.tools.stages.base import check_setting

    example = 'port = "/dev/ttyUSB0" (or COM3, or a pyserial URL such as socket://host:port)'
    if "port" not in table:
        raise _Bad(f"[{where}] needs {example}")
    port = table["port"]
    if not isinstance(port, str) or not port.strip():
        raise _Bad(f"[{where}] port = {port!r} is not a serial port: give the controller's "
                   f"port, e.g. {example}")
    kind = table.get("kind", "apt")
    if kind not in _STAGE_KEYS:
        raise _Bad(f"[{where}] kind must be one of {sorted(_STAGE_KEYS)}, got {kind!r}")
    settings = {}
    move_timeout = 60.0
    w = f"[{where}]"
    for key, value in table.items():
        if key in ("port", "kind"):
            continue
        if key not in _STAGE_KEYS[kind]:
            raise _Bad(f"[{where}] has unknown key {key!r} for a {kind} stage; known: "
                       f"port, kind, {', '.join(sorted(_STAGE_KEYS[kind]))}")
        # the drivers' own check (the same for open_stage's keyword arguments)
        try:
            checked = check_setting(key, value, label=f"{w} {key}")
        except (TypeError, ValueError) as exc:
            raise _Bad(str(exc)) from None
        if key in _SWEEP_KEYS:
            move_timeout = checked
            continue
        settings["limits" if key == "limits_mm" else key] = checked
    return StageConfig(port, kind, settings, move_timeout)


def _sweep(where: str, table: dict) -> SweepConfig:
    if "positions_mm" not in table:
        raise _Bad(f"[{where}] needs positions_mm = [...] (stage positions in mm)")
    positions = _numbers(f"[{where}] positions_mm", table.get("positions_mm"))
    far = [p for p in positions if abs(p) > _TRAVEL_MM]
    if far:
        raise _Bad(f"[{where}] positions_mm = {table['positions_mm']!r} reaches {far[0]:g} mm: "
                   f"positions_mm is in millimetres (micrometres given?)")
    depths = table.get("depths_m")
    if depths is not None:
        depths = _numbers(f"[{where}] depths_m", depths, length=len(positions))
        bad = [d for d in depths if not 0 < d <= 1.0]
        if bad:
            raise _Bad(f"[{where}] depths_m = {table['depths_m']!r}: {bad[0]:g} is not a depth "
                       f"in metres behind the hologram plane (millimetres given?); write e.g. "
                       f"depths_m = [0.002, 0.004, 0.006] for 2, 4 and 6 mm")
        for i, d in enumerate(depths):  # one focus per stage position: a copy-paste slip
            j = next((j for j in range(i) if depths[j] == d and positions[j] != positions[i]),
                     None)
            if j is not None:
                raise _Bad(f"[{where}] depths_m gives {d:g} m for two stage positions "
                           f"({positions[j]:g} and {positions[i]:g} mm): each position focuses "
                           f"one depth; fix depths_m (or repeat the position itself)")
            # and the reverse: one stage position cannot focus two depths (a position repeated
            # with its own depth is a repeat, and allowed)
            j = next((j for j in range(i) if positions[j] == positions[i] and depths[j] != d),
                     None)
            if j is not None:
                raise _Bad(f"[{where}] positions_mm gives {positions[i]:g} mm twice (entries "
                           f"{j} and {i}) with two depths_m ({depths[j]:g} and {d:g} m): a stage "
                           f"position focuses one depth; fix positions_mm (or depths_m, if "
                           f"entry {i} repeats entry {j})")
    distance = table.get("distance_m")
    if distance is not None:
        distance = _metres(f"[{where}] distance_m", distance, "distance_m = 0.2 for 200 mm")
    return SweepConfig(positions, depths, distance)


def parse_bench_config(data: dict, *, base: Optional[Path] = None) -> BenchConfig:
    """A :class:`BenchConfig` from the parsed TOML tables; paths are relative to ``base``.

    Every value with a unit is checked for its unit's plausible range (a settle time in
    milliseconds, depths in millimetres, counts per micrometre are refused with the fix), every
    file it names (``luts``, ``phase_luts``) is read and checked here, and every sweep position
    against the travel of the stage it steps (``limits_mm``, or the apt driver's default).

    Parameters
    ----------
    data : dict
        The TOML file's tables.
    base : pathlib.Path, optional
        Folder that relative paths are relative to (the file's).

    Raises
    ------
    ValueError
        Naming the section, the key, the value and the fix.
    """
    from clholo import validate

    unknown = set(data) - set(_SECTIONS)
    if unknown:
        raise _Bad(f"unknown section(s) {sorted(unknown)} in the bench file; known: "
                   f"{sorted(_SECTIONS)}")
    for name, keys in _SECTIONS.items():
        if name in data and not isinstance(data[name], dict):
            raise _Bad(f"{name} must be a [{name}] section (a table), got {data[name]!r}")
        if keys is not None and name in data:
            extra = set(data[name]) - keys
            if extra:
                raise _Bad(f"[{name}] has unknown key(s) {sorted(extra)}; known: "
                           f"{sorted(keys)}")
    cfg = BenchConfig()
    slm = data.get("slm", {})
    if "monitor" in slm:
        if not isinstance(slm["monitor"], (str, int)) or isinstance(slm["monitor"], bool):
            raise _Bad(f"[slm] monitor must be a name or an index, got {slm['monitor']!r}")
        cfg.monitor = slm["monitor"]
    if "resolution" in slm:
        res = slm["resolution"]
        if not isinstance(res, list) or len(res) != 2:
            raise _Bad(f"[slm] resolution must be [width, height], got {res!r}")
        cfg.resolution = (_whole("[slm] resolution width", res[0], 1, 65536),
                          _whole("[slm] resolution height", res[1], 1, 65536))
    try:
        if "pitch_m" in slm:
            cfg.pitch_m = validate.pitch(slm["pitch_m"], name="[slm] pitch_m")
        if "wavelengths_m" in slm:
            cfg.wavelengths_m = validate.wavelengths(slm["wavelengths_m"],
                                                     name="[slm] wavelengths_m")
    except (TypeError, ValueError) as exc:
        raise _Bad(str(exc)) from None
    from clholo.tools.slm import check_refresh_hz, check_settle_s

    if "settle_s" in slm:
        cfg.settle_s = _slm_value(check_settle_s, "settle_s", slm["settle_s"])
    if "refresh_hz" in slm:
        cfg.refresh_hz = _slm_value(check_refresh_hz, "refresh_hz", slm["refresh_hz"])
    if "luts" in slm:
        files = slm["luts"]
        if not isinstance(files, list) or len(files) != len(cfg.wavelengths_m):
            raise _Bad(f"[slm] luts must list one file per wavelength "
                       f"({len(cfg.wavelengths_m)}), got {files!r}")
        _file_names("[slm] luts", files)
        cfg.lut_files = [(base / f) if base is not None and not Path(f).is_absolute() else Path(f)
                         for f in files]
        if base is not None:
            try:
                cfg.luts()   # read and checked now, naming the file
            except (OSError, TypeError, ValueError) as exc:
                raise _Bad(f"[slm] luts: {exc}") from None
    if "phase_luts" in slm:
        # as `clholo encode --lut`: one table for all colours or one per wavelength, where a
        # file of one column per colour (colour-sequential SLMs ship one table per laser) gives
        # one table per column, in the order of wavelengths_m
        specs = slm["phase_luts"]
        C = len(cfg.wavelengths_m)
        if not isinstance(specs, list) or not specs or (base is None and len(specs) not in (1, C)):
            raise _Bad(f"[slm] phase_luts must list one table for all colours or one per "
                       f"wavelength ({C}), got {specs!r}")
        _file_names("[slm] phase_luts", specs)
        cfg.phase_luts = [
            s if str(s).startswith("linear") or base is None or Path(s).is_absolute()
            else str(base / s) for s in specs]
        if base is not None:
            from clholo.encode.quantize import parse_luts

            counts = []
            for spec in cfg.phase_luts:
                try:
                    counts.append(len(parse_luts(spec)))
                except FileNotFoundError as exc:
                    raise _Bad(f"[slm] phase_luts: {exc}") from None
                except (TypeError, ValueError) as exc:
                    raise _Bad(f"[slm] phase_luts: {exc}") from None
            if sum(counts) not in (1, C):
                columns = "".join(f"; {Path(spec).name} holds {n} (one column per colour)"
                                  for spec, n in zip(cfg.phase_luts, counts) if n > 1)
                raise _Bad(f"[slm] phase_luts must give one table for all colours or one per "
                           f"wavelength ({C}), got {sum(counts)} from {specs!r}{columns}")
    for name in ("z_stage", "pupil_stage"):
        if name in data:
            setattr(cfg, name, _stage(name, data[name]))
    if "camera" in data:
        cam = dict(data["camera"])
        if cam.get("kind", "file") not in ("file", "opencv"):
            raise _Bad(f"[camera] kind must be 'file' or 'opencv', got {cam['kind']!r}")
        cam.setdefault("kind", "file")
        if "device" in cam:
            cam["device"] = _whole("[camera] device", cam["device"], 0, 255)
        for key in ("width", "height"):
            if key in cam:
                cam[key] = _whole(f"[camera] {key}", cam[key], 1, 65536)
        cfg.camera = cam
    for name in ("focal_sweep", "parallax_sweep"):
        if name in data:
            setattr(cfg, name, _sweep(name, data[name]))
    for sweep_name, stage_name in _SWEEP_STAGES:
        _check_reach(sweep_name, getattr(cfg, sweep_name), stage_name,
                     getattr(cfg, stage_name), data)
    return cfg


def _file_names(key: str, entries: list) -> None:
    """Refuse a list entry that is not a file name as text (``luts = [5]`` reached ``Path(5)``,
    a TypeError)."""
    for i, entry in enumerate(entries):
        if not isinstance(entry, str) or not entry:
            raise _Bad(f"{key} must list file names as text (quoted), got {entry!r} (entry "
                       f"{i}) in {entries!r}")


#: each sweep and the stage it steps (``clholo capture focal-sweep`` / ``parallax-sweep``)
_SWEEP_STAGES = (("focal_sweep", "z_stage"), ("parallax_sweep", "pupil_stage"))


def _apt_default_limits() -> Tuple[float, float]:
    """The travel an apt stage takes when ``limits_mm`` is not given (the driver's default)."""
    import inspect

    from clholo.tools.stages.apt import AptStage

    low, high = inspect.signature(AptStage.__init__).parameters["limits"].default
    return float(low), float(high)


def _check_reach(sweep_name: str, sweep: Optional[SweepConfig], stage_name: str,
                 stage: Optional[StageConfig], data: dict) -> None:
    """Refuse a sweep position outside its stage's travel when the file is read, naming both
    keys: the driver would refuse it too, but only once the sweep runs (the SLM window open,
    the stage opened), and naming neither key nor the file."""
    if sweep is None or stage is None:
        return
    limits = stage.settings.get("limits")
    if limits is not None:
        low, high = limits
        travel = f"[{stage_name}] limits_mm = [{low:g}, {high:g}]"
        fix = (f"give positions from {low:g} to {high:g} mm, or widen [{stage_name}] limits_mm "
               f"if the stage travels further")
    elif stage.kind == "apt":
        low, high = _apt_default_limits()
        travel = (f"[{low:g}, {high:g}] mm (the apt driver's default: [{stage_name}] limits_mm "
                  f"is not set)")
        fix = (f"give positions from {low:g} to {high:g} mm, or set [{stage_name}] limits_mm to "
               f"the stage's travel")
    else:
        return   # a conex stage without limits_mm asks its controller when it opens
    for i, p in enumerate(sweep.positions_mm):
        if not low <= p <= high:
            raise _Bad(f"[{sweep_name}] positions_mm = {data[sweep_name]['positions_mm']!r}: "
                       f"{p:g} mm (entry {i}) is outside the stage's travel, {travel}: {fix}")


def load_bench_config(path: Union[str, Path]) -> BenchConfig:
    """Read and check a bench TOML file (see the module docstring for its keys).

    Raises
    ------
    clholo.errors.InputError
        ``FILE: [section] key = value ...: the fix`` for a bad value, unit or file it names.
    FileNotFoundError
        ``path`` does not exist.
    """
    from clholo.errors import InputError

    from clholo.io.images import check_input_file

    # stat only, never open: a named pipe would wait for a writer, a device never end
    path = check_input_file(path, "bench configuration", "give the TOML file")
    try:
        # a byte-order mark (Windows editors' "UTF-8 with BOM") is no TOML statement
        data = _toml().loads(path.read_text(encoding="utf-8").lstrip("\ufeff"))
    except UnicodeDecodeError:
        raise InputError(f"bench configuration {path} is not a text (TOML) file") from None
    except _toml().TOMLDecodeError as exc:
        raise InputError(f"{path} is not valid TOML: {exc}") from None
    except RecursionError:
        raise InputError(f"{path} is not valid TOML that can be read: its arrays or tables "
                         f"are nested thousands deep (a corrupt or generated file); write it "
                         f"again") from None
    except ValueError as exc:  # Python's limit on integer digits (4300), raised mid-parse
        if "digits" not in str(exc):
            raise
        raise InputError(f"{path} is not valid TOML that can be read: it holds an integer of "
                         f"more than 4300 digits, which no setting is (a corrupt or generated "
                         f"file); write it again") from None
    try:
        cfg = parse_bench_config(data, base=path.parent)
    except _Bad as exc:
        raise InputError(f"{path}: {exc}") from None
    cfg.source = path
    return cfg
