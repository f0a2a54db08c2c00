"""The bench's configuration: one TOML file, not code.

Example (every key optional except where the sweep needs it; lengths in the unit of their name)::

    [slm]
    monitor = "PLUTO"              # name substring, or an integer index
    resolution = [1920, 1080]      # width, height
    pitch_m = 8e-6
    wavelengths_m = [638e-9, 520e-9, 450e-9]
    luts = ["red.lut", "green.lut", "blue.lut"]   # 256 levels each; paths relative to this file
    phase_luts = ["linear:255", "lut_g.csv", "linear:200"]   # encoders' phase->gray tables
    settle_s = 0.02

    [z_stage]                      # camera focus (focal sweeps)
    port = "/dev/ttyUSB0"
    kind = "apt"
    counts_per_mm = 34554.96       # Thorlabs' current value for the Z8 motor (older: 34304)
    limits_mm = [0.0, 25.0]

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
    port: str
    kind: str = "apt"
    settings: Dict[str, Any] = field(default_factory=dict)   # passed to open_stage

    def open(self):
        from clholo.tools.stages import open_stage

        return open_stage(self.port, self.kind, **self.settings)


@dataclass
class SweepConfig:
    positions_mm: List[float]
    depths_m: Optional[List[float]] = None
    distance_m: Optional[float] = None


@dataclass
class BenchConfig:
    monitor: Union[str, int, None] = None
    resolution: Tuple[int, int] = (1920, 1080)
    pitch_m: float = 8e-6
    wavelengths_m: Tuple[float, ...] = (638e-9, 520e-9, 450e-9)
    lut_files: Optional[List[Path]] = None
    phase_luts: Optional[List[str]] = None
    settle_s: float = 0.0
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
            "settle_s"},
    "z_stage": None, "pupil_stage": None,   # port, kind, anything the driver takes
    "camera": {"kind", "device", "width", "height"},
    "focal_sweep": {"positions_mm", "depths_m"},
    "parallax_sweep": {"positions_mm", "distance_m"},
}
_STAGE_KEYS = {"apt": {"counts_per_mm", "limits_mm", "channel", "reply_timeout", "poll",
                       "keepalive", "retries", "require_homed", "purge_dwell"},
               "conex": {"address", "limits_mm", "reply_timeout", "retries", "reset_wait",
                         "poll"}}


def _numbers(where: str, value, *, length: Optional[int] = None) -> List[float]:
    from clholo.validate import real_scalar

    if not isinstance(value, (list, tuple)) or not value:
        raise ValueError(f"{where} must be a non-empty list of numbers, got {value!r}")
    out = [real_scalar(where, v) for v in value]
    if length is not None and len(out) != length:
        raise ValueError(f"{where} must have {length} entries, got {len(out)}")
    return out


def _stage(where: str, table: dict) -> StageConfig:
    if "port" not in table or not isinstance(table["port"], str):
        raise ValueError(f"[{where}] needs port = \"/dev/ttyUSB0\" (or any pyserial URL)")
    kind = table.get("kind", "apt")
    if kind not in _STAGE_KEYS:
        raise ValueError(f"[{where}] kind must be one of {sorted(_STAGE_KEYS)}, got {kind!r}")
    settings = {}
    for key, value in table.items():
        if key in ("port", "kind"):
            continue
        if key not in _STAGE_KEYS[kind]:
            raise ValueError(f"[{where}] has unknown key {key!r} for a {kind} stage; known: "
                             f"port, kind, {', '.join(sorted(_STAGE_KEYS[kind]))}")
        settings["limits" if key == "limits_mm" else key] = (
            _numbers(f"[{where}] limits_mm", value, length=2) if key == "limits_mm" else value)
    return StageConfig(table["port"], kind, settings)


def _sweep(where: str, table: dict) -> SweepConfig:
    positions = _numbers(f"[{where}] positions_mm", table.get("positions_mm"))
    depths = table.get("depths_m")
    if depths is not None:
        depths = _numbers(f"[{where}] depths_m", depths, length=len(positions))
    distance = table.get("distance_m")
    if distance is not None:
        from clholo.validate import distance as check_distance

        distance = check_distance(distance, name=f"[{where}] distance_m", nonzero=True)
    return SweepConfig(positions, depths, distance)


def parse_bench_config(data: dict, *, base: Optional[Path] = None) -> BenchConfig:
    """A :class:`BenchConfig` from the parsed TOML tables; paths are relative to ``base``."""
    from clholo import validate

    unknown = set(data) - set(_SECTIONS)
    if unknown:
        raise ValueError(f"unknown section(s) {sorted(unknown)} in the bench file; known: "
                         f"{sorted(_SECTIONS)}")
    for name, keys in _SECTIONS.items():
        if keys is not None and name in data:
            extra = set(data[name]) - keys
            if extra:
                raise ValueError(f"[{name}] has unknown key(s) {sorted(extra)}; known: "
                                 f"{sorted(keys)}")
    cfg = BenchConfig()
    slm = data.get("slm", {})
    if "monitor" in slm:
        if not isinstance(slm["monitor"], (str, int)) or isinstance(slm["monitor"], bool):
            raise ValueError(f"[slm] monitor must be a name or an index, got {slm['monitor']!r}")
        cfg.monitor = slm["monitor"]
    if "resolution" in slm:
        res = slm["resolution"]
        if not isinstance(res, list) or len(res) != 2:
            raise ValueError(f"[slm] resolution must be [width, height], got {res!r}")
        cfg.resolution = (validate.count(res[0], name="[slm] resolution width"),
                          validate.count(res[1], name="[slm] resolution height"))
    if "pitch_m" in slm:
        cfg.pitch_m = validate.pitch(slm["pitch_m"], name="[slm] pitch_m")
    if "wavelengths_m" in slm:
        cfg.wavelengths_m = validate.wavelengths(slm["wavelengths_m"], name="[slm] wavelengths_m")
    if "settle_s" in slm:
        cfg.settle_s = validate.real_scalar("[slm] settle_s", slm["settle_s"])
        if cfg.settle_s < 0:
            raise ValueError(f"[slm] settle_s must be >= 0 seconds, got {cfg.settle_s}")
    if "luts" in slm:
        files = slm["luts"]
        if not isinstance(files, list) or len(files) != len(cfg.wavelengths_m):
            raise ValueError(f"[slm] luts must list one file per wavelength "
                             f"({len(cfg.wavelengths_m)}), got {files!r}")
        cfg.lut_files = [(base / f) if base is not None and not Path(f).is_absolute() else Path(f)
                         for f in files]
    if "phase_luts" in slm:
        specs = slm["phase_luts"]
        if not isinstance(specs, list) or len(specs) not in (1, len(cfg.wavelengths_m)):
            raise ValueError(f"[slm] phase_luts must list one table for all colours or one per "
                             f"wavelength ({len(cfg.wavelengths_m)}), got {specs!r}")
        cfg.phase_luts = [
            s if str(s).startswith("linear") or base is None or Path(s).is_absolute()
            else str(base / s) for s in specs]
    for name in ("z_stage", "pupil_stage"):
        if name in data:
            setattr(cfg, name, _stage(name, data[name]))
    if "camera" in data:
        cam = dict(data["camera"])
        if cam.get("kind", "file") not in ("file", "opencv"):
            raise ValueError(f"[camera] kind must be 'file' or 'opencv', got {cam['kind']!r}")
        cam.setdefault("kind", "file")
        cfg.camera = cam
    for name in ("focal_sweep", "parallax_sweep"):
        if name in data:
            setattr(cfg, name, _sweep(name, data[name]))
    return cfg


def load_bench_config(path: Union[str, Path]) -> BenchConfig:
    """Read and check a bench TOML file (see the module docstring for its keys)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"bench configuration {path} does not exist")
    try:
        data = _toml().loads(path.read_text())
    except _toml().TOMLDecodeError as exc:
        raise ValueError(f"{path} is not valid TOML: {exc}") from None
    cfg = parse_bench_config(data, base=path.parent)
    cfg.source = path
    return cfg
