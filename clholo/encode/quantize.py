"""8-bit upload of phase patterns: lookup tables, wrap, gray levels, SLM-sized PNG sequences.

HOLOGRAPHY.md section 8: ``gray = round(wrap(P) / (2 pi) * N_2pi)``, generalised to a measured
table. A :class:`PhaseLUT` holds, for one wavelength, the phase each of the 256 gray levels
gives (radians, relative to gray 0). The forward map (:meth:`PhaseLUT.to_gray`) wraps ``P`` to
``[0, 2 pi)`` and picks the *usable* level (phase below ``2 pi``) nearest to it on the circle,
so a phase just below ``2 pi`` may go to level 0. Levels whose phase reaches ``2 pi`` or more
(SLMs whose range exceeds ``2 pi``, e.g. ``2 pi`` at gray 200) are never emitted: they repeat
lower levels modulo ``2 pi``. The inverse map (:meth:`PhaseLUT.to_phase`) reads the table, so
``to_gray(to_phase(g)) == g`` exactly for every usable level ``g``.

:func:`quantize` is NumPy on the host (float64). :class:`DeviceQuantizer` does the same on the
OpenCL device (``kernels/quantize.cl``), bit for bit, so that only the 8-bit patterns leave the
device: the host tabulates its own ``to_gray`` as a step function of the float32 input (every
float32 where the level changes, :func:`clholo.reference.step_table`, cached per table) and the
kernel counts the breakpoints at or below each phase by comparisons and looks the level up;
phases outside the tabulated range, NaN or inf are
an error, never a silently wrong pattern.
"""

from __future__ import annotations

import functools
import json
import math
from pathlib import Path
from typing import Optional, Sequence, Tuple, Union

import numpy as np

__all__ = ["LEVELS", "PhaseLUT", "parse_lut", "parse_luts", "read_luts", "wrap_phase",
           "quantize", "dequantize", "real_phases",
           "DEVICE_PHASE_RANGE", "device_table", "DeviceQuantizer", "PendingPatterns", "fit_to_slm",
           "write_pattern_pngs", "read_pattern_pngs"]

LEVELS = 256  # 8-bit SLM
TWO_PI = 2.0 * math.pi
# a table must reach within two mean steps of 2 pi, else some phases cannot be shown at all
_MIN_RANGE = TWO_PI * (1.0 - 2.0 / LEVELS)

PathLike = Union[str, Path]


def real_phases(phase, *, name: str = "phase") -> np.ndarray:
    """``phase`` as a NumPy array of real phases (radians), refusing what would be converted
    with a loss or an unrelated meaning: complex values (NumPy would drop the imaginary part
    with only a ``ComplexWarning``), bools, strings, objects, ``None``, and unsigned integers
    (SLM gray levels, not radians: :func:`dequantize` gives their phases).

    Parameters
    ----------
    phase : array_like of float or (signed) int
        Phases in radians.
    name : str
        The argument's name, for the message.

    Returns
    -------
    numpy.ndarray
        ``np.asarray(phase)``, an integer or floating dtype.

    Raises
    ------
    clholo.errors.InputTypeError
        Complex, bool, unsigned or non-numeric input; the message names ``name`` and the fix.
    """
    from clholo.errors import InputTypeError

    if phase is None or isinstance(phase, (str, bytes)):
        raise InputTypeError(f"{name} must be an array of real phases in radians, got "
                             f"{phase!r}")
    arr = np.asarray(phase)
    if np.iscomplexobj(arr):
        raise InputTypeError(
            f"{name} must be real phases in radians, got complex values ({arr.dtype}); a "
            f"complex field's phase is np.angle(field), and a hologram is encoded with "
            f"dpac_encode or sgd_encode")
    if arr.dtype == np.bool_ or not (np.issubdtype(arr.dtype, np.integer)
                                     or np.issubdtype(arr.dtype, np.floating)):
        raise InputTypeError(f"{name} must be real phases in radians (a float array), got "
                             f"dtype {arr.dtype}")
    if np.issubdtype(arr.dtype, np.unsignedinteger):
        # radians are never unsigned integers; SLM patterns are: quantised twice, or
        # phase_to_hologram called on patterns, would otherwise run on nonsense
        raise InputTypeError(
            f"{name} must be real phases in radians, got {arr.dtype}, which looks like SLM "
            f"gray levels: dequantize(gray, luts) gives their phases, simulate_slm(gray, "
            f"optics, luts) their field")
    return arr


def wrap_phase(phase: np.ndarray) -> np.ndarray:
    """``phase mod 2 pi`` in ``[0, 2 pi)`` (float64); values that round up to ``2 pi`` give 0.
    Complex or non-numeric ``phase`` is refused (:func:`real_phases`)."""
    w = np.mod(np.asarray(real_phases(phase), np.float64), TWO_PI)
    # np.where, not item assignment: a 0-d phase (one number) gives a 0-d array back
    return np.where(w >= TWO_PI, 0.0, w)


class PhaseLUT:
    """Gray level -> phase table of one wavelength (radians), 256 entries.

    Parameters
    ----------
    phases : array, shape (256,)
        Phase at gray levels 0..255, strictly increasing, finite; only differences matter (the
        table is stored relative to gray 0). It must reach at least ``2 pi (1 - 2/256)``.
    name : str
        Where the table came from (shown in errors and metadata).

    Raises
    ------
    clholo.errors.InputTypeError
        Complex or non-numeric phases.
    ValueError
        Wrong length, NaN/inf, a span of more than four turns (degrees given for radians:
        the same check as a table file's), not strictly increasing, or a range short of
        ``2 pi``: each names the reason and the fix.
    """

    def __init__(self, phases, *, name: str = "lookup table"):
        self._setup(phases, name, radians_check=True)

    def _setup(self, phases, name: str, *, radians_check: bool) -> None:
        arr = np.asarray(real_phases(phases, name=f"{name}: phases"), dtype=np.float64)
        self.name = str(name)
        if arr.ndim != 1 or arr.size != LEVELS:
            raise ValueError(f"{self.name}: an 8-bit SLM's lookup table has {LEVELS} phases (one "
                             f"per gray level 0..255), got shape {arr.shape}")
        bad = np.flatnonzero(~np.isfinite(arr))
        if bad.size:
            raise ValueError(f"{self.name}: phase at gray level {int(bad[0])} is {arr[bad[0]]}; "
                             f"every entry must be a finite phase in radians")
        steps = np.diff(arr)
        down = np.flatnonzero(steps <= 0)
        if down.size:
            g = int(down[0])
            raise ValueError(f"{self.name}: not monotone: the phase at gray {g + 1} "
                             f"({arr[g + 1]:.6g} rad) does not exceed the phase at gray {g} "
                             f"({arr[g]:.6g} rad); the table must increase strictly "
                             f"(smooth a noisy measurement; a table whose phase falls with "
                             f"the gray level is not taken: reversed, it would show the "
                             f"conjugate field, a twin image at -z)")
        if radians_check:  # the same check as a table file's (clholo encode --lut, bench files)
            _check_radians(arr, self.name)
        span = float(arr[-1] - arr[0])
        if span < _MIN_RANGE:
            raise ValueError(f"{self.name}: covers only {span:.4g} rad, short of 2 pi; some "
                             f"phases cannot be shown (phases in degrees? give radians)")
        self.phases = arr - arr[0]
        self.phases.setflags(write=False)
        usable = np.flatnonzero(self.phases < TWO_PI)
        self.usable_levels = int(usable[-1]) + 1  # levels 0..usable_levels-1 lie below 2 pi
        self._circle = np.append(self.phases[:self.usable_levels], TWO_PI)

    @classmethod
    def linear(cls, gray_2pi: int = 255) -> "PhaseLUT":
        """Linear table: gray ``N = gray_2pi`` gives ``2 pi`` (phase ``2 pi g / N``); ``N < 255``
        is an SLM whose range exceeds ``2 pi``.

        Parameters
        ----------
        gray_2pi : int
            The gray level that gives ``2 pi``, a whole number in ``2..256``.

        Raises
        ------
        clholo.errors.InputTypeError
            Not a whole number (a float, NaN, None, a string, a bool).
        ValueError
            Outside ``2..256``.
        """
        from clholo.validate import count

        # count names gray_2pi for NaN, None or a string too (int() would say only "cannot
        # convert float NaN to integer")
        n = count(gray_2pi, name="gray_2pi (the gray level that gives 2 pi)", minimum=2,
                  maximum=LEVELS)
        lut = cls.__new__(cls)  # linear:2 spans many turns on purpose: not a unit slip
        lut._setup(TWO_PI * np.arange(LEVELS) / n, f"linear:{n}", radians_check=False)
        return lut

    @classmethod
    def from_file(cls, path: PathLike) -> "PhaseLUT":
        """Measured table from ``.npy`` (256 phases) or ``.csv``/``.txt``: one column of 256
        phases, or two columns ``gray, phase`` with gray 0..255 in order; a header line is
        skipped. Radians. A file of one column per colour is :func:`read_luts`'s.

        Parameters
        ----------
        path : str or os.PathLike
            The table's file.
        """
        tables = read_luts(path)
        if len(tables) != 1:
            raise ValueError(f"{path} holds {len(tables)} lookup tables (one column per "
                             f"colour): give it where one table per colour is taken (clholo "
                             f"encode --lut, a bench file's [slm] phase_luts, "
                             f"quantize(luts=...), read_luts)")
        return tables[0]

    def to_gray(self, phase) -> np.ndarray:
        """Nearest usable gray level (uint8) to ``wrap(phase)`` on the circle.

        Parameters
        ----------
        phase : array_like of float
            Phases in radians, any range; real and finite.

        Raises
        ------
        clholo.errors.InputTypeError
            Complex or non-numeric ``phase``.
        clholo.errors.InputError
            NaN or infinite phases (as :func:`quantize`): they have no gray level, and would
            otherwise index past the table.
        """
        from clholo.errors import InputError

        phase = real_phases(phase)
        if not np.all(np.isfinite(phase)):  # checked before the wrap, which warns on inf
            raise InputError("phase contains NaN/inf values")
        shape = phase.shape
        # a scalar as one element: the wrap assigns into its result, which a NumPy scalar is not
        theta = wrap_phase(phase if phase.ndim else phase.reshape(1))
        lower = np.searchsorted(self._circle, theta, side="right") - 1
        upper = lower + 1
        take_upper = (self._circle[upper] - theta) < (theta - self._circle[lower])
        level = np.where(take_upper, upper, lower)
        level[level == self.usable_levels] = 0  # 2 pi is gray 0
        return level.astype(np.uint8).reshape(shape)

    def to_phase(self, gray) -> np.ndarray:
        """Phase (float64, radians, relative to gray 0) that gray levels ``gray`` show."""
        g = np.asarray(gray)
        if g.dtype != np.uint8:
            if not np.issubdtype(g.dtype, np.integer):
                raise ValueError(f"gray levels must be integers in 0..{LEVELS - 1}, got dtype "
                                 f"{g.dtype}")
            lo, hi = int(g.min(initial=0)), int(g.max(initial=0))
            if lo < 0 or hi >= LEVELS:
                raise ValueError(f"gray levels must be integers in 0..{LEVELS - 1}, got values "
                                 f"{lo}..{hi}")
        return self.phases[g]

    def describe(self) -> dict:
        """A summary for records and manifests: ``name``, ``usable_levels`` and
        ``range_rad`` (the phase of gray 255, radians)."""
        return {"name": self.name, "usable_levels": self.usable_levels,
                "range_rad": float(self.phases[-1])}


_LUT_FILE_FIX = ("give a .csv or .npy table of 256 phases in radians (or 'linear', "
                 "'linear:N')")


def _lut_file(path: PathLike) -> Path:
    """``path`` when it is a regular file; a folder, a named pipe, a device or a loop of
    symbolic links is named as what it is (``Path.is_file`` is False for all of them, and
    they were said not to exist)."""
    from clholo.io.images import check_input_file

    path = Path(path)
    if path.is_dir():
        raise ValueError(f"lookup table {path} is a folder, not a file: {_LUT_FILE_FIX}")
    return check_input_file(path, "lookup table", _LUT_FILE_FIX)


def read_luts(path: PathLike) -> Tuple["PhaseLUT", ...]:
    """The lookup table(s) of one file, radians: 256 phases (``.npy`` shape ``(256,)``, or a
    ``.csv``/``.txt`` column; ``gray, phase`` rows with gray 0..255 in order), or one table per
    colour, as colour-sequential SLMs ship them (one table per laser): 256 rows with one column
    per colour (``.npy`` shape ``(256, C)``; ``.csv`` with ``C >= 3`` columns, optionally
    after a gray column 0..255), in the order of the wavelengths. A header line is skipped.

    Parameters
    ----------
    path : str or os.PathLike
        The table's file (``.npy``, ``.csv`` or ``.txt``).

    Raises
    ------
    ValueError
        Any other shape (named as the file holds it, e.g. ``(3, 256)``: transpose it), values
        that are not real phases in radians, or a table :class:`PhaseLUT` refuses.
    """
    path = _lut_file(path)
    if path.suffix.lower() == ".npy":
        from clholo.io._npy import load_npy

        data = load_npy(path, what="lookup table",
                        fix="save 256 phases in radians with numpy.save (float64)")
    else:
        import warnings

        with warnings.catch_warnings():  # "input contained no data": said below, in one line
            warnings.simplefilter("ignore", UserWarning)
            try:
                data = np.loadtxt(path, delimiter=",", ndmin=2)
            except ValueError:
                try:
                    data = np.loadtxt(path, delimiter=",", ndmin=2, skiprows=1)
                except ValueError as exc:
                    raise ValueError(f"{path}: cannot read a table of numbers ({exc}); "
                                     f"expected one column of phases, 'gray, phase' rows or "
                                     f"one column per colour") from None
        if data.size == 0:
            # empty, or one line of numbers the comma did not split (a ';' file) taken for a
            # header: "got shape (0,)" said neither
            lines = [ln for ln in path.read_text(errors="replace").splitlines() if ln.strip()]
            if not lines:
                raise ValueError(f"{path} is empty: give 256 phases in radians, one per line "
                                 f"(or one column per colour)")
            raise ValueError(f"{path}: no comma-separated numbers after its first line "
                             f"({lines[0][:40]!r}...): give 256 phases in radians, one per "
                             f"line, with commas between columns")
    data = np.asarray(data)
    if path.suffix.lower() != ".npy" and data.ndim == 2 and data.shape[0] != LEVELS:
        # loadtxt skips blank lines: a phase left out shows only as "255 rows"; say where
        lines = path.read_text(errors="replace").splitlines()
        filled = [k for k, ln in enumerate(lines) if ln.strip()]
        blank = [k + 1 for k in range(filled[0], filled[-1]) if not lines[k].strip()] \
            if filled else []
        if blank:
            raise ValueError(f"{path} holds {data.shape[0]} rows, not {LEVELS}: line(s) "
                             f"{', '.join(map(str, blank[:5]))} are blank (a phase left "
                             f"out?); give one phase per gray level 0..255")
    shape = data.shape
    written = f"{shape[0]} row(s) of {shape[1]} column(s)" \
        if data.ndim == 2 and path.suffix.lower() != ".npy" else f"shape {shape}"
    if data.ndim == 2 and shape[1] == 1:
        columns = [data[:, 0]]
    elif data.ndim == 2 and shape[0] == LEVELS and shape[1] >= 2:
        gray = data[:, 0]
        is_gray = np.issubdtype(data.dtype, np.number) and not np.iscomplexobj(data) and \
            np.array_equal(gray, np.arange(LEVELS))
        if shape[1] == 2 and path.suffix.lower() != ".npy" and not is_gray:
            raise ValueError(f"{path}: the gray column must be 0, 1, ..., 255 in order "
                             f"({LEVELS} rows), got {gray.size} rows starting "
                             f"{gray[:3].tolist()}")
        columns = list(data.T[1:] if is_gray else data.T)
    elif data.ndim == 2 and shape[1] == 2 and path.suffix.lower() != ".npy":
        raise ValueError(f"{path}: the gray column must be 0, 1, ..., 255 in order "
                         f"({LEVELS} rows), got {shape[0]} rows starting "
                         f"{data[:3, 0].tolist()}")
    elif data.ndim <= 1:
        columns = [data]
    else:
        hint = " (one row per colour: transpose it)" if data.ndim == 2 and \
            shape[1] == LEVELS else ""
        raise ValueError(f"{path}: a lookup table is {LEVELS} phases (one per gray level "
                         f"0..255), or {LEVELS} rows with one column per colour; the file "
                         f"holds {written}{hint}")
    names = [str(path)] if len(columns) == 1 else \
        [f"{path}[colour {c}]" for c in range(len(columns))]
    return tuple(PhaseLUT(_file_phases(col, path), name=name)
                 for col, name in zip(columns, names))


#: a measured table spans about 2 pi, more on SLMs whose range exceeds it (2 pi at gray 200
#: is 8 rad); a span beyond four turns is a table in degrees (360 for 2 pi)
_MAX_FILE_SPAN = 4 * TWO_PI


def _file_phases(data, path) -> np.ndarray:
    """The 256 phases read from a table file, checked for type and unit (radians)."""
    arr = np.asarray(data)
    if arr.dtype == np.bool_ or not (np.issubdtype(arr.dtype, np.integer)
                                     or np.issubdtype(arr.dtype, np.floating)):
        raise ValueError(f"{path}: a lookup table holds 256 real phases in radians, got "
                         f"{arr.dtype} values")
    arr = arr.astype(np.float64).reshape(-1) if arr.ndim else arr.astype(np.float64)
    if arr.ndim == 1 and arr.size == LEVELS and np.all(np.isfinite(arr)):
        _check_radians(arr, path)
    return arr


def _check_radians(arr: np.ndarray, where) -> None:
    """Refuse a table of 256 finite phases that spans more than four turns: degrees (or
    another unit) taken for radians. One check for :class:`PhaseLUT`, table files (``clholo
    encode --lut``) and a bench file's tables."""
    span = float(arr.max() - arr.min())
    if span > _MAX_FILE_SPAN:
        guess = ("looks like degrees (360 for 2 pi)" if span <= 400
                 else "is not in radians")
        raise ValueError(f"{where}: the phases span {span:.4g} rad ({span / TWO_PI:.3g} "
                         f"turns): the table {guess}; give radians (multiply degrees by "
                         f"pi/180)")


def parse_lut(spec: Union[str, PathLike, "PhaseLUT"]) -> PhaseLUT:
    """A :class:`PhaseLUT` from ``"linear"`` (2 pi at 255), ``"linear:N"``, or a file path.

    Parameters
    ----------
    spec : str, os.PathLike or PhaseLUT
        What to read (a :class:`PhaseLUT` is returned as it is).
    """
    if isinstance(spec, PhaseLUT):
        return spec
    text = str(spec)
    if text == "linear":
        return PhaseLUT.linear()
    if text.startswith("linear:"):
        try:
            n = int(text.split(":", 1)[1])
        except ValueError:
            raise ValueError(f"lookup table {text!r}: write linear:N with N the gray level that "
                             f"gives 2 pi, e.g. linear:255") from None
        if not 2 <= n <= LEVELS:  # named as written, not as PhaseLUT.linear's parameter
            raise ValueError(f"lookup table {text!r}: N is the gray level that gives 2 pi, an "
                             f"integer in 2..{LEVELS}, got {n}; e.g. linear:255")
        return PhaseLUT.linear(n)
    return PhaseLUT.from_file(text)


def parse_luts(spec: Union[str, PathLike, "PhaseLUT"]) -> Tuple[PhaseLUT, ...]:
    """Like :func:`parse_lut`, but a file of one column per colour gives its tables, one per
    colour (:func:`read_luts`).

    Parameters
    ----------
    spec : str, os.PathLike or PhaseLUT
        ``"linear"``, ``"linear:N"``, a table's file or a :class:`PhaseLUT`.
    """
    if isinstance(spec, PhaseLUT) or str(spec) == "linear" or str(spec).startswith("linear:"):
        return (parse_lut(spec),)
    return read_luts(spec)


_LUTS_ACCEPTED = ("a PhaseLUT, 'linear', 'linear:N', a table's file path, or a sequence of "
                  "them (one per colour)")


def _luts_for(luts, C: int) -> Tuple[PhaseLUT, ...]:
    import os

    from clholo.errors import InputTypeError

    one = (PhaseLUT, str, os.PathLike)
    if isinstance(luts, one):
        luts = [luts]
    elif isinstance(luts, np.ndarray) and luts.dtype != object:
        raise InputTypeError(f"luts must be {_LUTS_ACCEPTED}, got an array of {luts.dtype}; "
                             f"a table of 256 phases in radians is PhaseLUT(phases)")
    try:
        luts = list(luts)
    except TypeError:
        raise InputTypeError(f"luts must be {_LUTS_ACCEPTED}, got {luts!r}") from None
    if not luts:
        raise ValueError(f"luts must name at least one lookup table ({_LUTS_ACCEPTED}), got an "
                         f"empty sequence")
    for x in luts:
        if not isinstance(x, one):
            raise InputTypeError(f"luts must be {_LUTS_ACCEPTED}, got an entry {x!r} "
                                 f"({type(x).__name__})")
    luts = [t for x in luts for t in parse_luts(x)]
    if len(luts) == 1:
        return tuple(luts) * C
    if len(luts) != C:
        raise ValueError(f"give one lookup table for all colours or one per colour ({C}), got "
                         f"{len(luts)}")
    return tuple(luts)


def quantize(phase, luts: Union[PhaseLUT, str, Sequence] = "linear") -> np.ndarray:
    """Phase patterns ``[..., C, H, W]`` (radians, any range) -> uint8 gray levels.

    ``luts``: one table for every colour or one per colour (axis ``-3``).

    Parameters
    ----------
    phase : array ``[..., C, H, W]``
        Phases in radians, any range (wrapped here); real numbers only (complex input is
        refused: its phase is ``np.angle(field)``).
    luts : PhaseLUT, str or sequence of them
        One lookup table for every colour or one per colour (``"linear"``, ``"linear:N"``, a file
        path; :func:`parse_lut`).

    Raises
    ------
    clholo.errors.InputTypeError
        Complex or non-numeric ``phase``; ``luts`` of another type (``None``).
    ValueError
        NaN/inf phases, or a number of tables that is neither 1 nor ``C``.
    """
    phase = real_phases(phase)
    if phase.ndim < 3:
        phase = phase.reshape((1,) * (3 - phase.ndim) + phase.shape)
    if not np.all(np.isfinite(phase)):
        raise ValueError("phase contains NaN/inf values")
    C = phase.shape[-3]
    tables = _luts_for(luts, C)
    out = np.empty(phase.shape, np.uint8)
    for c, lut in enumerate(tables):
        out[..., c, :, :] = lut.to_gray(phase[..., c, :, :])
    return out


#: The float32 phases (radians) the device's tables cover by default: double-phase coding's
#: ``atan2 +- acos`` lie within ``[-3 pi/2, 3 pi/2]``, the kinoform's ``atan2`` within
#: ``[-pi, pi]``; both with room to spare.
DEVICE_PHASE_RANGE = (-2.0 * math.pi, 2.0 * math.pi)
#: the largest ``|lo|``, ``|hi|`` of a device table's ``phase_range`` (radians): 64 pi each
#: way is a table of about 16 000 entries, built in about a second
MAX_DEVICE_PHASE = 64.0 * math.pi


@functools.lru_cache(maxsize=32)
def _cached_table(phases: bytes, lo: float, hi: float) -> Tuple[np.ndarray, np.ndarray]:
    from clholo.reference.quantize import lut_table

    lut = PhaseLUT.__new__(PhaseLUT)  # the phases of a table already checked (linear:2 too)
    lut._setup(np.frombuffer(phases, np.float64), "lookup table", radians_check=False)
    bp, lv = lut_table(lut, lo, hi)
    bp.setflags(write=False)
    lv.setflags(write=False)
    return bp, lv


def _float32_range(phase_range) -> Tuple[float, float]:
    try:
        lo, hi = (float(np.float32(v)) for v in phase_range)
    except (TypeError, ValueError):
        raise TypeError(f"phase_range must be two numbers (lo, hi) in radians, got "
                        f"{phase_range!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
        raise ValueError(f"phase_range must be finite with lo < hi (radians), got {phase_range!r}")
    # compared as float32, like the range itself: float32(64 pi) rounds up past 64 pi, and the
    # documented limit must itself be accepted
    if max(abs(lo), abs(hi)) > float(np.float32(MAX_DEVICE_PHASE)):
        raise ValueError(
            f"phase_range={phase_range!r} is not a plausible range of phases: the device's "
            f"tables hold about 256 entries per 2 pi, so they cover at most [-64 pi, 64 pi] "
            f"(+-{MAX_DEVICE_PHASE:.4g} rad); wrap the phases first (np.mod(phase, 2 * np.pi)) "
            f"or quantise on the host (clholo.encode.quantize.quantize)")
    return lo, hi


def device_table(lut: Union[PhaseLUT, str, PathLike], phase_range=DEVICE_PHASE_RANGE
                 ) -> Tuple[np.ndarray, np.ndarray]:
    """The step table of ``lut``'s forward map over the float32 phases in ``phase_range``:
    ``(bp float32 [n], lv uint8 [n + 1])`` with ``lut.to_gray(p) == lv[#{k : bp[k] <= p}]`` for
    every float32 ``p`` in the range (:func:`clholo.reference.step_table`). Built once per table
    content and range (a few milliseconds), then cached; the arrays are read-only."""
    lut = parse_lut(lut)
    lo, hi = _float32_range(phase_range)
    return _cached_table(lut.phases.tobytes(), lo, hi)


class DeviceQuantizer:
    """:func:`quantize` on the OpenCL device: float32 phase patterns ``[..., C, H, W]`` -> uint8
    gray levels, bit for bit :func:`quantize` of the same float32 phases.

    Parameters
    ----------
    luts : PhaseLUT, str or sequence
        One table for every colour or one per colour, as :func:`quantize`.
    channels : int
        ``C``.
    phase_range : (float, float)
        Radians; the float32 phases the tables cover (:data:`DEVICE_PHASE_RANGE`). More range
        costs a longer table (about 256 entries per ``2 pi``), not time per pixel worth noting;
        a range beyond ``[-64 pi, 64 pi]`` (:data:`MAX_DEVICE_PHASE`) is refused.

    Notes
    -----
    Each table is the host's ``to_gray`` tabulated over every float32 in the range
    (:func:`device_table`): the kernel finds how many breakpoints lie at or below the phase by
    comparisons, starting from a guess out of a bucket table (about four buckets per breakpoint)
    that is exact whatever the guess, and looks the level up. A phase outside
    ``phase_range``, NaN or inf sets an error flag that :meth:`__call__` reads back and raises
    as a :class:`ValueError` naming the colour and the problem; :meth:`enqueue` leaves that check
    to the caller (:meth:`check_flags`). Device copies of the tables are made once per OpenCL
    context.
    """

    def __init__(self, luts: Union[PhaseLUT, str, Sequence] = "linear", channels: int = 1, *,
                 phase_range=DEVICE_PHASE_RANGE):
        from clholo import validate

        C = validate.count(channels, name="channels")
        self.luts = _luts_for(luts, C)
        self.channels = C
        self.phase_range = _float32_range(phase_range)
        lo, hi = self.phase_range
        bps, lvs, guesses = [], [], []
        table = np.zeros((C, 5), np.uint32)          # off, n, loff, goff, nb (quantize.cl)
        rng = np.zeros((C, 3), np.float32)           # lo, hi, scale
        off = loff = goff = 0
        for c, lut in enumerate(self.luts):
            bp, lv = device_table(lut, self.phase_range)
            n = len(bp)
            # the kernel's first guess: about four buckets per breakpoint, each holding the count
            # of breakpoints at or below its lower edge (any guess ends exact: quantize.cl)
            nb = max(1, 4 * n)
            edges = lo + (hi - lo) * np.arange(nb) / nb
            guesses.append(np.searchsorted(bp.astype(np.float64), edges, side="right"))
            table[c] = (off, n, loff, goff, nb)
            rng[c] = (lo, hi, nb / (hi - lo))
            bps.append(bp)
            lvs.append(lv)
            off += n
            loff += n + 1
            goff += nb
        # a kernel argument buffer may not be empty
        self._bp = np.concatenate(bps + [np.zeros(1, np.float32)]).astype(np.float32)
        self._lv = np.concatenate(lvs).astype(np.uint8)
        self._guess = np.concatenate(guesses).astype(np.uint32)
        self._table = table
        self._range = rng
        self._device = {}    # context handle -> device copies (bp, lv, guess, table, range)

    def _buffers(self, queue):
        import pyopencl.array as cla

        key = queue.context.int_ptr
        bufs = self._device.get(key)
        if bufs is None:
            bufs = tuple(cla.to_device(queue, a) for a in (self._bp, self._lv, self._guess,
                                                            self._table, self._range))
            self._device[key] = bufs
        return bufs

    def enqueue(self, phase, *, out=None, allocator=None):
        """Enqueue the quantisation of ``phase`` (pyopencl float32 ``[..., C, H, W]``,
        C-contiguous) into ``out`` (uint8, same shape; allocated when ``None``, from
        ``allocator`` where given, e.g. a ``pyopencl.tools.MemoryPool``); returns
        ``(gray, flags)`` with ``flags`` uint32 ``[C]`` on the device (0 where every phase of
        that colour was in range; see :meth:`check_flags`). Does not wait."""
        import pyopencl.array as cla

        from clholo.host import runtime
        from clholo.host.kernel_args import QUANTIZE_PHASE

        if not isinstance(phase, cla.Array):
            raise TypeError(f"phase must be a pyopencl array (use __call__ for NumPy), got "
                            f"{type(phase).__name__}")
        if phase.dtype != np.float32 or phase.ndim < 3 or not phase.flags.c_contiguous:
            raise ValueError(f"phase must be a C-contiguous float32 device array [..., C, H, W], "
                             f"got {phase.dtype} {phase.shape}")
        C = phase.shape[-3]
        if C != self.channels:
            raise ValueError(f"phase has {C} colour(s) (axis -3) but the quantiser has "
                             f"{self.channels} table(s)")
        queue = phase.queue
        if out is None:
            out = cla.empty(queue, phase.shape, np.uint8, allocator=allocator)
        elif out.shape != phase.shape or out.dtype != np.uint8 or not out.flags.c_contiguous:
            raise ValueError(f"out must be C-contiguous uint8 {phase.shape}, got {out.dtype} "
                             f"{out.shape}")
        flags = runtime.zeros(queue, (C,), np.uint32, allocator=allocator)
        if phase.size:
            bp, lv, guess, table, rng = self._buffers(queue)
            npix = phase.shape[-2] * phase.shape[-1]
            kern = runtime.get_kernel(queue.context, "quantize.cl", "quantize_phase")
            runtime.launch(kern, queue, (npix, phase.size // npix), None, *QUANTIZE_PHASE.args(
                phase=phase.data, gray=out.data, bp=bp.data, lv=lv.data, guess=guess.data,
                table=table.data, range=rng.data, n_channels=C, flags=flags.data))
        return out, flags

    def enqueue_read(self, phase, *, out: Optional[np.ndarray] = None,
                     allocator=None) -> "PendingPatterns":
        """Enqueue the quantisation of ``phase`` (as :meth:`enqueue`) and the reads of its gray
        levels into the host array ``out`` and of its flags; returns at once with a
        :class:`PendingPatterns`, whose :meth:`~PendingPatterns.wait` gives the checked patterns.

        Parameters
        ----------
        phase : pyopencl.array.Array
            float32 ``[..., C, H, W]``, C-contiguous, radians.
        out : numpy.ndarray, optional
            uint8, C-contiguous, ``phase``'s shape: where the levels are read to (e.g.
            :func:`clholo.host.memory.pinned_empty`, which a GPU fills by DMA while the host
            works). Default: a new array.
        allocator : callable, optional
            Where the device's levels and flags come from (as for :meth:`enqueue`).
        """
        import pyopencl as cl

        shape = tuple(getattr(phase, "shape", ()))
        if out is not None and (not isinstance(out, np.ndarray) or out.shape != shape
                                or out.dtype != np.uint8 or not out.flags.c_contiguous
                                or not out.flags.writeable):
            raise ValueError(f"out must be a writeable C-contiguous uint8 NumPy array of shape "
                             f"{shape}, got {getattr(out, 'dtype', type(out).__name__)} "
                             f"{getattr(out, 'shape', '')}")
        gray, flags = self.enqueue(phase, allocator=allocator)
        if out is None:
            out = np.empty(gray.shape, np.uint8)
        flags_host = np.empty(flags.shape, np.uint32)
        queue = gray.queue
        events = [cl.enqueue_copy(queue, out, gray.data, is_blocking=False)] if gray.size else []
        events.append(cl.enqueue_copy(queue, flags_host, flags.data, is_blocking=False))
        return PendingPatterns(out, flags_host, events, self.check_flags, (gray, flags))

    def check_flags(self, flags) -> None:
        """Raise :class:`ValueError` for the first colour whose flags (from :meth:`enqueue`,
        device or NumPy) report a phase out of range, NaN or inf."""
        from clholo.reference.quantize import QUANTIZE_BELOW, QUANTIZE_INF, QUANTIZE_NAN

        f = flags.get() if hasattr(flags, "get") else np.asarray(flags)
        lo, hi = self.phase_range
        for c, bits in enumerate(int(v) for v in f):
            if not bits:
                continue
            where = f"colour {c}, lookup table {self.luts[c].name}"
            if bits & (QUANTIZE_NAN | QUANTIZE_INF):
                raise ValueError(f"phase contains NaN/inf values ({where}; quantised on the "
                                 f"device): no pattern is made from them")
            side = "below" if bits & QUANTIZE_BELOW else "above"
            raise ValueError(f"phase of {where} has values {side} [{lo:.7g}, {hi:.7g}] rad, "
                             f"the range the device's tables cover: give DeviceQuantizer a "
                             f"phase_range=(lo, hi) that holds them, or quantise on the host "
                             f"(clholo.encode.quantize.quantize)")

    def __call__(self, phase, *, queue=None) -> np.ndarray:
        """uint8 gray levels (NumPy) of ``phase`` (NumPy or pyopencl, float32 ``[..., C, H,
        W]``; NumPy is uploaded to ``queue``), checked: raises :class:`ValueError` where a phase
        is out of range, NaN or inf. The tables hold float32 inputs: float64 phases are refused
        (quantise them on the host with :func:`quantize`)."""
        import pyopencl.array as cla

        from clholo._arrays import check_context, resolve_queue

        if isinstance(phase, cla.Array) and queue is not None:
            # a device array runs on its own queue: a queue= of another context was ignored
            # without a word
            check_context(queue, phase, name="phase")
        if not isinstance(phase, cla.Array):
            phase = real_phases(phase)
            if phase.dtype != np.float32:
                raise TypeError(f"phase must be float32 for the device tables, got "
                                f"{phase.dtype}; quantise other phases on the host with "
                                f"clholo.encode.quantize.quantize")
            phase = cla.to_device(resolve_queue(queue), np.ascontiguousarray(phase))
        return self.enqueue_read(phase).wait()


class PendingPatterns:
    """8-bit patterns on their way to the host: the quantisation and the reads are enqueued;
    :meth:`wait` waits for them and returns the patterns, checked
    (:meth:`DeviceQuantizer.enqueue_read` makes these).

    The host may do other work meanwhile, e.g. enqueue the next batch's render so that the
    device never waits for the host (the display loop's producer does). Until :meth:`wait`
    has returned, the host array belongs to the device: do not read or reuse it.

    Parameters
    ----------
    out : numpy.ndarray
        uint8: the host array the levels are read into.
    flags : numpy.ndarray
        uint32 ``[C]``: the host array the error flags are read into (``check``'s input).
    events : sequence of pyopencl.Event
        The reads; :meth:`wait` waits for every one.
    check : callable
        ``check(flags)`` raises for flags that report a bad phase
        (:meth:`DeviceQuantizer.check_flags`).
    keep : tuple
        Device arrays to keep alive until the reads are done.
    """

    def __init__(self, out: np.ndarray, flags: np.ndarray, events, check, keep=()):
        self._out = out
        self._flags = flags
        self._events = list(events)
        self._check = check
        self._keep = keep       # the device arrays the reads come from, alive until done
        self._result: Optional[np.ndarray] = None

    @property
    def shape(self) -> Tuple[int, ...]:
        """The patterns' shape."""
        return tuple(self._out.shape)

    def done(self) -> bool:
        """Whether the reads have completed (:meth:`wait` would not wait)."""
        import pyopencl as cl

        complete = cl.command_execution_status.COMPLETE
        return all(ev.command_execution_status <= complete for ev in self._events)

    def wait(self) -> np.ndarray:
        """Wait for the reads; raise :class:`ValueError` where a phase was out of the tables'
        range, NaN or inf (as :meth:`DeviceQuantizer.__call__`); return the uint8 patterns (the
        ``out`` array given to :meth:`DeviceQuantizer.enqueue_read`). Calling it again returns
        the same array."""
        if self._result is None:
            for ev in self._events:
                ev.wait()
            self._events = []
            self._keep = ()
            self._check(self._flags)
            self._result = self._out
        return self._result


def dequantize(gray, luts: Union[PhaseLUT, str, Sequence] = "linear") -> np.ndarray:
    """uint8 gray levels ``[..., C, H, W]`` -> the phases the SLM shows (float64 radians).

    Parameters
    ----------
    gray : uint8 array ``[..., C, H, W]``
        Gray levels.
    luts : PhaseLUT, str or sequence of them
        One lookup table for every colour or one per colour (``"linear"``, ``"linear:N"``, a file
        path; :func:`parse_lut`).
    """
    gray = np.asarray(gray)
    if gray.dtype != np.uint8:
        raise TypeError(f"gray must be uint8 gray levels, got {gray.dtype}")
    if gray.ndim < 3:
        gray = gray.reshape((1,) * (3 - gray.ndim) + gray.shape)
    C = gray.shape[-3]
    tables = _luts_for(luts, C)
    out = np.empty(gray.shape, np.float64)
    for c, lut in enumerate(tables):
        out[..., c, :, :] = lut.to_phase(gray[..., c, :, :])
    return out


def fit_to_slm(gray: np.ndarray, slm_shape: Tuple[int, int], *, fill: int = 0) -> np.ndarray:
    """Centre ``gray [..., H, W]`` on the SLM's ``(rows, cols)``: crop the centre where the
    pattern is larger, pad with gray ``fill`` (flat phase) where smaller. The pattern's pixel
    ``(H // 2, W // 2)`` lands on the SLM's ``(rows // 2, cols // 2)``.

    Parameters
    ----------
    gray : uint8 array ``[..., H, W]``
        The patterns.
    slm_shape : (int, int)
        The SLM's ``(rows, cols)``.
    fill : int
        Gray level of the margin: a whole number in the range of ``gray``'s dtype (0..255 for
        uint8); a float or an out-of-range level is refused, never truncated or wrapped.
    """
    from clholo import validate

    rows, cols = validate.shape2d(slm_shape, name="slm_shape")
    gray = np.asarray(gray)
    if gray.ndim < 2:
        raise ValueError(f"gray must be patterns [..., H, W], got shape {gray.shape}")
    if np.issubdtype(gray.dtype, np.integer):
        info = np.iinfo(gray.dtype)
        fill = validate.count(fill, name="fill", minimum=int(info.min), maximum=int(info.max))
    else:
        fill = validate.real_scalar("fill", fill)
    H, W = gray.shape[-2:]
    out = np.full(gray.shape[:-2] + (rows, cols), fill, dtype=gray.dtype)
    # source and destination windows per axis: offset of the pattern's centre on the SLM
    def window(n, m):
        off = m // 2 - n // 2  # destination start (may be negative = crop)
        src0, dst0 = max(0, -off), max(0, off)
        length = min(n - src0, m - dst0)
        return slice(src0, src0 + length), slice(dst0, dst0 + length)

    sy, dy = window(H, rows)
    sx, dx = window(W, cols)
    out[..., dy, dx] = gray[..., sy, sx]
    return out


def _colour_names(C: int) -> Tuple[str, ...]:
    return ("R", "G", "B") if C == 3 else tuple(f"c{i}" for i in range(C))


def _band(wavelength: float) -> str:
    """The colour a laser of ``wavelength`` metres is: R from 590 nm, G from 490 nm, else B."""
    return "R" if wavelength >= 590e-9 else "G" if wavelength >= 490e-9 else "B"


def _pattern_names(C: int, wavelengths) -> Tuple[str, ...]:
    """Each channel's file name colour: by its wavelength where they are given (a pattern is
    right only under the laser it was computed for: a hologram of wavelengths (450, 520, 638)
    nm wrote its 450 nm pattern to ``frame000_R.png``), ``c{i}`` where two share a band or
    for other than three channels, ``R, G, B`` by index where none are given."""
    if wavelengths is None:
        return _colour_names(C)
    bands = tuple(_band(w) for w in wavelengths)
    return bands if C == 3 and len(set(bands)) == 3 else tuple(f"c{i}" for i in range(C))


def write_pattern_pngs(gray: np.ndarray, folder: PathLike, *,
                       slm_shape: Optional[Tuple[int, int]] = None, overwrite: bool = False,
                       metadata: Optional[dict] = None, option: str = "folder",
                       expect=None, wavelengths=None) -> Path:
    """Write uint8 patterns ``[T, C, H, W]`` as 8-bit grayscale PNGs, one per frame and colour,
    ``frame{t:03d}_{R|G|B}.png``, plus ``patterns.json`` (shape, placement, ``metadata``).

    ``slm_shape``: the SLM's native ``(rows, cols)`` (Pluto-2.1: ``(1080, 1920)``); each
    pattern is centred on it with :func:`fit_to_slm`. The folder is written under a temporary
    name and renamed when complete.

    Parameters
    ----------
    gray : uint8 array ``[T, C, H, W]``
        The patterns.
    folder : str or os.PathLike
        The folder to write.
    slm_shape : (int, int), optional
        The SLM's ``(rows, cols)`` (above).
    overwrite : bool
        Replace an existing folder that clholo wrote (never one it did not write).
    metadata : dict, optional
        Recorded in ``patterns.json``.
    option : str
        How the caller named ``folder``, for refusals (``clholo encode``: ``"--out"``).
    expect : tuple, optional
        :func:`clholo.io.output.destination_state` of ``folder`` taken when the caller checked
        it, before its work: a folder another run wrote there since is then refused, even with
        ``overwrite`` (default: what is there when the write begins).
    wavelengths : sequence of float, optional
        Metres, one per colour: the files are named by each one's colour (``R`` from 590 nm,
        ``G`` from 490 nm, else ``B``; ``c{i}`` where two share one) and ``patterns.json``
        records them (``wavelengths_m``). Without them three colours are named ``R, G, B`` in
        channel order.
    """
    from clholo.io.images import write_image
    from clholo.io.output import output_folder

    gray = np.asarray(gray)
    if gray.dtype != np.uint8 or gray.ndim != 4:
        raise ValueError(f"gray must be uint8 [T, C, H, W], got {gray.dtype} {gray.shape}")
    if min(gray.shape) < 1:
        raise ValueError(f"gray must hold at least one frame, colour and pixel [T, C, H, W], "
                         f"got shape {gray.shape}: no pattern folder is written for it")
    if slm_shape is not None:
        gray = fit_to_slm(gray, slm_shape)
    T, C, H, W = gray.shape
    if wavelengths is not None:
        from clholo import validate

        wavelengths = list(validate.wavelengths(wavelengths, name="wavelengths"))
        if len(wavelengths) != C:
            raise ValueError(f"wavelengths has {len(wavelengths)} entries but gray has {C} "
                             f"colour channels; give one wavelength (metres) per colour")
    names = _pattern_names(C, wavelengths)
    folder = Path(folder)
    state = {} if expect is None else {"expect": expect}
    with output_folder(folder, overwrite=overwrite, command="encode", option=option,
                       **state) as tmp:
        for t in range(T):
            for c in range(C):
                # phase levels, no colour: no sRGB chunk for a viewer to colour-manage
                write_image(tmp / f"frame{t:03d}_{names[c]}.png", gray[t, c],
                            dtype="uint8", encoding="data", atomic=False)
        info = {"frames": T, "channels": list(names), "rows": H, "cols": W,
                "placement": "centred (crop or pad with gray 0)" if slm_shape else "as computed",
                "extra": metadata or {}}
        if wavelengths is not None:
            info["wavelengths_m"] = wavelengths
        (tmp / "patterns.json").write_text(json.dumps(info, indent=1))
    return folder


def read_pattern_pngs(folder: PathLike) -> np.ndarray:
    """Read a folder written by :func:`write_pattern_pngs` back as uint8 ``[T, C, H, W]``."""
    from clholo.io.images import read_image

    folder = Path(folder)
    info_path = folder / "patterns.json"
    if not info_path.is_file():
        raise FileNotFoundError(f"{folder} has no patterns.json: not a pattern folder")
    T, names, rows, cols = _pattern_info(info_path)
    out = np.empty((T, len(names), rows, cols), np.uint8)
    for t in range(T):
        for c, n in enumerate(names):
            png = folder / f"frame{t:03d}_{n}.png"
            if not png.is_file():
                raise ValueError(f"{info_path} lists {T} frame(s) of colours {names}, but "
                                 f"{png.name} is missing: the pattern folder is incomplete")
            pixels, png_info = read_image(png, normalise=False)
            pixels = np.asarray(pixels)
            if png_info.get("format") != "uint8":
                # 16-bit levels were wrapped modulo 256 by the uint8 store below
                raise ValueError(f"{png} holds {png_info.get('format')} levels, not the SLM's "
                                 f"8-bit gray levels: the folder does not match its "
                                 f"patterns.json (write it with write_pattern_pngs, clholo "
                                 f"encode)")
            if pixels.ndim != 3 or pixels.shape[:2] != (rows, cols) or pixels.shape[2] != 1:
                raise ValueError(f"{png} holds an image of shape {pixels.shape}, but {info_path} "
                                 f"says {rows} x {cols} gray patterns: the folder does not "
                                 f"match its patterns.json")
            out[t, c] = pixels[..., 0]
    return out


#: Largest side (pixels) a pattern folder's patterns.json may state.
_MAX_PATTERN_SIDE = 65536


def _pattern_info(info_path: Path) -> Tuple[int, list, int, int]:
    """``(frames, colour names, rows, cols)`` of a pattern folder's ``patterns.json``, checked:
    one :class:`clholo.errors.InputError` naming the file and what is wrong."""
    from clholo.errors import InputError

    try:
        info = json.loads(info_path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"{info_path} is not valid JSON ({exc}): the pattern folder is "
                         f"damaged; write it again (clholo encode)") from None
    if not isinstance(info, dict):
        raise InputError(f"{info_path} must hold a JSON object with frames, channels, rows and "
                         f"cols, got {type(info).__name__}")
    missing = [k for k in ("frames", "channels", "rows", "cols") if k not in info]
    if missing:
        raise InputError(f"{info_path} lacks {', '.join(missing)}: not a pattern folder "
                         f"written by clholo (write_pattern_pngs, clholo encode)")
    for key in ("frames", "rows", "cols"):
        v = info[key]
        if isinstance(v, bool) or not isinstance(v, int) or v < 1:
            raise InputError(f"{info_path}: {key} must be a whole number >= 1, got {v!r}")
        if key != "frames" and v > _MAX_PATTERN_SIDE:  # before a buffer of that size is made
            raise InputError(f"{info_path}: {key} = {v} is larger than any SLM (at most "
                             f"{_MAX_PATTERN_SIDE} pixels): the folder's patterns.json is "
                             f"damaged; write it again (clholo encode)")
    names = info["channels"]
    if not isinstance(names, list) or not names or not all(
            isinstance(n, str) and n and "/" not in n and "\\" not in n for n in names):
        raise InputError(f"{info_path}: channels must be a non-empty list of colour names "
                         f"(e.g. [\"R\", \"G\", \"B\"]), got {names!r}")
    if len(set(names)) != len(names):
        raise InputError(f"{info_path}: channels names a colour twice ({names}): each colour "
                         f"is one file per frame")
    return info["frames"], names, info["rows"], info["cols"]
