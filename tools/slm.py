"""Showing 8-bit patterns on a phase-only SLM driven as an extra monitor.

* :class:`SLMWindow`: a borderless window covering one monitor at its native resolution (GLFW +
  OpenGL, ``pip install clholo[slm]``), vsync'd buffer swaps, read-back for tests;
* :class:`MemoryDisplay`: the same interface backed by memory, for tests and soak runs;
* :func:`choose_monitor`: which monitor is the SLM, testable with an injected monitor list;
  :func:`find_monitor`: the same on the window system's monitors, without opening a window.

Both take only ``uint8`` patterns of the display's shape ``[H, W]``, checked before every upload,
apply a per-colour lookup table (256 entries, from the encoding's calibration) and keep a log
of when each frame went on screen. ``play`` shows a ``[T, C, H, W]`` sequence colour after
colour, one pattern per refresh.
"""

from __future__ import annotations

import contextlib
import csv
import time
from pathlib import Path
from typing import Callable, Iterator, List, NamedTuple, Optional, Sequence, Tuple, Union

import numpy as np

__all__ = ["Monitor", "FrameRecord", "choose_monitor", "find_monitor", "check_pattern",
           "check_lut", "load_lut", "Display", "MemoryDisplay", "SLMWindow", "PLUTO_RESOLUTION",
           "write_frame_log", "list_monitors", "check_display_server", "check_refresh_hz",
           "check_settle_s", "REFRESH_HZ_RANGE", "MAX_SETTLE_S", "on_display_lost"]

#: HOLOEYE Pluto-2.1: 1920 x 1080 pixels (width, height)
PLUTO_RESOLUTION = (1920, 1080)
#: a monitor's refresh rate, hertz: outside, the number is not one (0.06: kHz? 1e-9: a slip)
REFRESH_HZ_RANGE = (1.0, 1000.0)
#: a liquid crystal settles in milliseconds to tens of them; a settle time above 1 s is
#: milliseconds given as seconds
MAX_SETTLE_S = 1.0


def _real(value, what: str, fix: str) -> float:
    from clholo.validate import real_scalar

    return real_scalar(what, value, fix=fix)


def check_refresh_hz(value, *, label: str = "refresh_hz") -> float:
    """A monitor's refresh rate in hertz, :data:`REFRESH_HZ_RANGE` (1..1000): the one check of
    the displays and of the bench file's ``[slm] refresh_hz``.

    Parameters
    ----------
    value : float
        The refresh rate, hertz.
    label : str
        How the message names it (``[slm] refresh_hz`` for the bench file).

    Raises
    ------
    clholo.errors.InputError
        NaN, infinite or outside 1..1000 Hz, naming ``label`` and the range.
    clholo.errors.InputTypeError
        Not a number.
    """
    from clholo.errors import InputError

    low, high = REFRESH_HZ_RANGE
    fix = f"give hertz from {low:g} to {high:g}, e.g. refresh_hz = 60"
    hz = _real(value, label, fix)
    if not low <= hz <= high:
        raise InputError(f"{label} = {value!r} is not a monitor refresh rate in hertz "
                         f"({low:g}..{high:g}); write e.g. refresh_hz = 60")
    return hz


def check_settle_s(value, *, label: str = "settle_s") -> float:
    """A liquid-crystal settle time in seconds, ``0 <= s <= 1`` (:data:`MAX_SETTLE_S`): the one
    check of the displays and of the bench file's ``[slm] settle_s``.

    Parameters
    ----------
    value : float
        The settle time, seconds.
    label : str
        How the message names it (``[slm] settle_s`` for the bench file).

    Raises
    ------
    clholo.errors.InputError
        NaN, infinite, negative or above 1 s (milliseconds given?), naming ``label``.
    clholo.errors.InputTypeError
        Not a number.
    """
    from clholo.errors import InputError

    example = "settle_s = 0.15 for 150 ms"
    x = _real(value, label, f"give seconds from 0 to {MAX_SETTLE_S:g}, e.g. {example}")
    if x < 0:
        raise InputError(f"{label} = {value!r} is negative: give seconds >= 0, e.g. {example}")
    if x > MAX_SETTLE_S:
        raise InputError(f"{label} = {value!r} is more than {MAX_SETTLE_S:g} s: settle_s is in "
                         f"seconds (milliseconds given?); write e.g. {example}")
    return x


class Monitor(NamedTuple):
    """A monitor as the window system reports it: name, native mode (pixels, Hz) and position
    on the desktop (pixels)."""
    name: str
    width: int
    height: int
    x: int = 0
    y: int = 0
    refresh_hz: float = 60.0


class FrameRecord(NamedTuple):
    """One pattern on screen: sequence frame ``t``, colour ``c``, the time (s, monotonic
    clock) its swap returned, and the time the settle delay ended."""
    t: int
    c: int
    shown_s: float
    settled_s: float


class _DefaultResolution(tuple):
    """``resolution``'s default, the Pluto-2.1's ``(1920, 1080)``: it picks the SLM among the
    monitors when none is named, but a monitor named or indexed is taken at its own size. A
    ``resolution`` given explicitly (the bench file's ``[slm] resolution``) is the SLM's size,
    and a named monitor of another size is refused."""
    __slots__ = ()

    def __repr__(self) -> str:
        return repr(tuple(self))


_DEFAULT_RESOLUTION = _DefaultResolution(PLUTO_RESOLUTION)


def choose_monitor(monitors: Sequence[Monitor], *, name: Optional[str] = None,
                   index: Optional[int] = None,
                   resolution: Optional[Sequence[int]] = _DEFAULT_RESOLUTION,
                   source: Union[str, Path, None] = None) -> Monitor:
    """Pick the SLM among ``monitors``.

    ``index`` wins, then a case-insensitive ``name`` substring; otherwise the monitor whose native
    mode is ``resolution`` (width, height), the last one when several match (the SLM is the
    extra monitor, listed after the primary).

    Parameters
    ----------
    monitors : sequence of Monitor
        What the window system reports (:func:`list_monitors`), or an injected list (tests).
    name : str, optional
        A case-insensitive substring of the SLM monitor's name.
    index : int, optional
        The SLM monitor's index in ``monitors``.
    resolution : (int, int) or None
        The SLM's ``(width, height)``. Given explicitly, a monitor picked by ``index`` or
        ``name`` must have it (a window of another size would show patterns of the wrong
        size); by default (the Pluto-2.1's 1920 x 1080) it only picks the monitor when none is
        named; None: the last monitor.
    source : str or os.PathLike, optional
        The bench file that ``name``/``index`` and ``resolution`` come from (its ``[slm]
        monitor`` and ``[slm] resolution``): refusals then name the file and those keys
        instead of this function's arguments.

    Returns
    -------
    Monitor
        The SLM's monitor.

    Raises
    ------
    clholo.errors.InputError
        An index out of range, a name that matches no monitor, a named monitor whose size is not
        ``resolution``, or no monitor of ``resolution``: naming the monitors there and the fix.
    ValueError
        No monitor at all.
    """
    from clholo.errors import InputError

    monitors = list(monitors)
    listing = "; ".join(f"{i}: {m.name} {m.width}x{m.height}" for i, m in enumerate(monitors))
    if not monitors:
        raise ValueError("no monitor found: connect the SLM as a display (or set DISPLAY)")
    file = f"{source}: " if source is not None else ""
    explicit = resolution is not None and not isinstance(resolution, _DefaultResolution)
    w, h = (None, None) if resolution is None else (int(v) for v in resolution)
    if index is not None or name:
        if index is not None:
            said = f"[slm] monitor = {index!r}" if source is not None else f"monitor index={index}"
            if not 0 <= int(index) < len(monitors):
                raise InputError(f"{file}{said} is not one of the {len(monitors)} monitors "
                                 f"({listing}): give the SLM's index or a part of its name")
            chosen = monitors[int(index)]
        else:
            said = f"[slm] monitor = {name!r}" if source is not None else f"monitor name={name!r}"
            hits = [m for m in monitors if name.lower() in m.name.lower()]
            if not hits:
                raise InputError(f"{file}{said} matches none of: {listing}; give a part of the "
                                 f"SLM monitor's name or its index")
            chosen = hits[0]
        # a window covers the monitor at its native mode: a monitor of another size than the
        # SLM's would show every pattern at the wrong size (or the run would fail later with a
        # shape that names neither key)
        if explicit and (chosen.width, chosen.height) != (w, h):
            if source is not None:
                raise InputError(
                    f"{file}{said} is {chosen.width}x{chosen.height} ({chosen.name}) but [slm] "
                    f"resolution = [{w}, {h}]; fix one: write resolution = [{chosen.width}, "
                    f"{chosen.height}] if that monitor is the SLM, else set monitor to the SLM's "
                    f"name or index (monitors: {listing})")
            raise InputError(
                f"{said} is {chosen.width}x{chosen.height} ({chosen.name}) but "
                f"resolution={(w, h)}; fix one: pass resolution=({chosen.width}, "
                f"{chosen.height}) if that monitor is the SLM, else the SLM's monitor (monitors: "
                f"{listing})")
        return chosen
    if resolution is not None:
        hits = [m for m in monitors if (m.width, m.height) == (w, h)]
        if not hits:
            if source is not None:
                raise InputError(
                    f"{file}no monitor has the SLM's [slm] resolution = [{w}, {h}] ({listing}): "
                    f"set [slm] monitor to the SLM monitor's name or index (and [slm] "
                    f"resolution to its size), or connect the SLM")
            raise InputError(f"no monitor has the SLM's resolution {w}x{h} ({listing}): give "
                             f"the monitor's name or index")
        return hits[-1]
    return monitors[-1]


def check_pattern(pattern, shape: Sequence[int], *, name: str = "pattern") -> np.ndarray:
    """Refuse anything but a ``uint8`` array of ``shape`` (H, W); returns it C-contiguous.

    Parameters
    ----------
    pattern : array
        The pattern.
    shape : (int, int)
        ``(H, W)``, pixels.
    name : str
        The argument named in refusals.
    """
    if not isinstance(pattern, np.ndarray):
        raise TypeError(f"{name} must be a NumPy uint8 array of shape {tuple(shape)}, got "
                        f"{type(pattern).__name__}")
    if pattern.dtype != np.uint8:
        raise TypeError(f"{name} must be uint8 (8-bit SLM levels), got {pattern.dtype}: encode "
                        f"and quantise it first (e.g. clholo.encode)")
    if pattern.shape != tuple(shape):
        raise ValueError(f"{name} has shape {pattern.shape}, the display needs {tuple(shape)} "
                         f"(height, width)")
    return np.ascontiguousarray(pattern)


def check_lut(lut, *, name: str = "lut") -> np.ndarray:
    """A lookup table: 256 uint8 entries (output level for each input level).

    Parameters
    ----------
    lut : array
        The table.
    name : str
        The argument named in refusals.
    """
    from clholo.errors import InputTypeError

    arr = np.asarray(lut)
    if arr.shape != (256,):
        raise ValueError(f"{name} must have 256 entries (one per 8-bit level), got shape "
                         f"{arr.shape}")
    if arr.dtype != np.uint8:
        # strings, objects, bools and complex numbers are not levels; refused before min/max,
        # which NumPy cannot even compute for strings
        if arr.dtype == np.bool_ or not (np.issubdtype(arr.dtype, np.integer)
                                         or np.issubdtype(arr.dtype, np.floating)):
            raise InputTypeError(f"{name} must hold integers 0..255 (output level per input "
                                 f"level), got dtype {arr.dtype}: give numbers, e.g. "
                                 f"np.arange(256, dtype=np.uint8) for the identity, or read a "
                                 f"file with load_lut")
        if not np.all(np.isfinite(arr)) or \
                arr.min() < 0 or arr.max() > 255 or np.any(arr != np.round(arr)):
            raise ValueError(f"{name} must hold integers 0..255, got {arr.dtype} values "
                             f"{arr.min()}..{arr.max()}")
        arr = arr.astype(np.uint8)
    return arr


def _check_luts(luts) -> Optional[List[np.ndarray]]:
    """``Display(luts=...)``: None, or a non-empty sequence of 256-entry tables, one per colour.

    A single table (an array of shape ``(256,)``, or 256 numbers) is refused rather than taken
    as one colour: a display that shows one colour only would refuse ``channel=1`` and ``2``
    later, with a message about channels, far from the mistake.
    """
    from clholo.errors import InputError, InputTypeError

    if luts is None:
        return None
    if isinstance(luts, (str, bytes, Path)):
        raise InputTypeError(f"luts must be a list of tables, one per colour, got {luts!r}: "
                             f"read LUT files with load_lut, e.g. luts=[load_lut('red.lut'), "
                             f"load_lut('green.lut'), load_lut('blue.lut')]")
    if isinstance(luts, np.ndarray):
        if luts.ndim == 1:
            raise InputError(f"luts is one table (shape {luts.shape}), not a list of tables: "
                             f"give one per colour, luts=[table] for one colour or "
                             f"luts=[table] * 3 for the same table on red, green and blue")
        if luts.ndim == 2 and luts.shape[0] == 256 and luts.shape[1] != 256:
            raise InputError(f"luts has shape {luts.shape}: one table per column; the display "
                             f"takes one table per colour, so give list(luts.T)")
    try:
        tables = list(luts)
    except TypeError:
        raise InputTypeError(f"luts must be a list of 256-entry tables, one per colour, or None "
                             f"for none; got {type(luts).__name__}") from None
    if not tables:
        raise InputError("luts is empty: give one 256-entry table per colour (in the order of "
                         "the wavelengths), or luts=None for none")
    if len(tables) == 256 and all(np.ndim(t) == 0 for t in tables):
        raise InputError("luts holds 256 numbers: that is one table, not a list of tables; "
                         "give one per colour, luts=[table] for one colour or luts=[table] * 3 "
                         "for the same table on red, green and blue")
    return [check_lut(t, name=f"luts[{i}]") for i, t in enumerate(tables)]


def load_lut(path: Union[str, Path]) -> np.ndarray:
    """Read a LUT file: ``.npy`` or text with 256 integers (whitespace or comma separated).

    Parameters
    ----------
    path : str or os.PathLike
        The file.

    Raises
    ------
    FileNotFoundError
        ``path`` does not exist.
    ValueError
        Not a regular file (a folder, a named pipe, a device), a damaged, truncated or pickled
        ``.npy``, or not 256 integers 0..255; the message names the file.
    """
    from clholo.io._npy import load_npy
    from clholo.io.images import check_input_file

    fix = ("give 256 integers 0..255 (text, whitespace or comma separated, or a .npy saved by "
           "numpy.save)")
    # a named pipe, a device or a loop of symbolic links is named as what it is (each was
    # "does not exist"), and never opened
    path = check_input_file(path, "LUT file", fix)
    if path.suffix.lower() == ".npy":
        # checks its header against the bytes stored before NumPy allocates what it claims
        return check_lut(load_npy(path, what="LUT file", fix=fix), name=f"LUT file {path}")
    try:
        data = np.array(path.read_text().replace(",", " ").split(), dtype=float)
    except (ValueError, OSError) as exc:   # UnicodeDecodeError is a ValueError
        raise ValueError(f"LUT file {path} cannot be read as 256 integers 0..255 (text, "
                         f"whitespace or comma separated, or .npy): {exc}") from None
    return check_lut(data, name=f"LUT file {path}")


def write_frame_log(records: Sequence[FrameRecord], path: Union[str, Path], *,
                    overwrite: bool = False) -> None:
    """Frame records as CSV: t, channel, shown_s, settled_s, interval_s (since the previous
    swap; empty for the first). Written under a temporary name and renamed, under clholo's
    output-file rule (:func:`clholo.io.output.output_file`, as :meth:`Display.write_log`).

    Parameters
    ----------
    records : sequence of FrameRecord
        The frames' times.
    path : str or os.PathLike
        The CSV file to create.
    overwrite : bool
        Replace an existing ``path`` that clholo wrote (a frame log written earlier and not
        changed since). A file clholo did not write, or one edited since, is never replaced,
        whatever this says.

    Raises
    ------
    clholo.errors.OutputRefused
        ``path`` exists and may not be replaced, or is a folder; the message names it.
    FileNotFoundError
        Its parent folder does not exist.
    PermissionError
        Its parent folder cannot be written to.
    """
    _write_frame_log(records, path, overwrite=overwrite, command="write_frame_log")


def _write_frame_log(records: Sequence[FrameRecord], path, *, overwrite, command: str) -> None:
    """:func:`write_frame_log` and :meth:`Display.write_log`: ``command`` names the writer in
    clholo's record of the file."""
    import os

    from clholo import validate
    from clholo.errors import OutputRefused
    from clholo.io.output import output_file

    overwrite = validate.flag(overwrite, name="overwrite")
    if os.fspath(path).strip() and Path(path).is_dir():  # the example a CSV name
        raise OutputRefused(f"path {Path(path).resolve()} is a folder: give a file name, "
                            f"e.g. {Path(path).resolve() / 'frames.csv'}")
    with output_file(path, overwrite=overwrite, command=command, option="path") as tmp:
        _write_frame_rows(records, tmp)


def _write_frame_rows(records: Sequence[FrameRecord], path: Path) -> None:
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["t", "channel", "shown_s", "settled_s", "interval_s"])
        prev = None
        for r in records:
            w.writerow([r.t, r.c, f"{r.shown_s:.6f}", f"{r.settled_s:.6f}",
                        "" if prev is None else f"{r.shown_s - prev:.6f}"])
            prev = r.shown_s


class Display:
    """What every SLM display does; subclasses provide ``_present(levels) -> time``.

    Parameters
    ----------
    width, height : int
        Pixels.
    luts : sequence of arrays or None
        One 256-entry uint8 table per colour channel (in the order of the wavelengths), or
        None for identity. A single table is refused (give ``[table]`` for one colour), and so
        is an empty list.
    settle_s : float
        Seconds to wait after a swap before a frame counts as shown (liquid-crystal response),
        0..1 (:func:`check_settle_s`, the bench file's check).
    refresh_hz : float
        The display's refresh rate, 1..1000 Hz (:func:`check_refresh_hz`, the bench file's
        check).
    """

    def __init__(self, width: int, height: int, *, luts=None, settle_s: float = 0.0,
                 refresh_hz: float = 60.0):
        from clholo.validate import count

        self.width = count(width, name="width")
        self.height = count(height, name="height")
        self.settle_s = check_settle_s(settle_s)
        self.refresh_hz = check_refresh_hz(refresh_hz)
        self.luts = _check_luts(luts)
        self.log: List[FrameRecord] = []

    @property
    def shape(self):
        """(height, width)"""
        return (self.height, self.width)

    #: colours a display without LUTs takes (red, green, blue)
    MAX_CHANNELS = 3

    def _check_channel(self, channel) -> int:
        """``channel`` as an int: ``0 <= channel <`` the number of LUTs (or 3, red, green and
        blue, when the display has none)."""
        import numbers

        from clholo.errors import InputError, InputTypeError

        if isinstance(channel, (bool, np.bool_)) or not isinstance(channel, numbers.Integral):
            raise InputTypeError(f"channel must be a whole number (the colour index), got "
                                 f"{channel!r}")
        channel = int(channel)
        n = self.MAX_CHANNELS if self.luts is None else len(self.luts)
        if not 0 <= channel < n:
            why = (f"the display has {n} LUT(s)" if self.luts is not None
                   else f"a display without LUTs shows at most {n} colours")
            raise InputError(f"channel={channel} is out of range: {why}; give 0..{n - 1}")
        return channel

    def _levels(self, pattern, channel: int) -> np.ndarray:
        pattern = check_pattern(pattern, self.shape)
        if self.luts is None:
            return pattern
        return self.luts[channel][pattern]

    def check_sequence(self, frames) -> np.ndarray:
        """Refuse a sequence that is not ``uint8 [T, C, H, W]`` of the display's shape, or has
        more colours than LUTs, before anything is shown.

        Parameters
        ----------
        frames : uint8 array ``[T, C, H, W]``
            The sequence.
        """
        if not isinstance(frames, np.ndarray):
            raise TypeError(f"frames must be a NumPy uint8 array [T, C, H, W], got "
                            f"{type(frames).__name__}")
        if frames.ndim != 4:
            raise ValueError(f"frames must be [T, C, H, W], got shape {frames.shape}")
        # before any indexing: frames[0, 0] of an empty T or C axis does not exist
        if frames.shape[0] == 0 or frames.shape[1] == 0:
            from clholo.errors import InputError

            raise InputError(f"frames must hold at least one pattern, got shape "
                             f"{frames.shape}: T (frames) and C (colours) must be at least 1")
        check_pattern(frames[0, 0], self.shape, name="frames[t, c]")
        if self.luts is not None and frames.shape[1] > len(self.luts):
            raise ValueError(f"frames have {frames.shape[1]} colours but the display has "
                             f"{len(self.luts)} LUTs")
        if self.luts is None and frames.shape[1] > self.MAX_CHANNELS:
            from clholo.errors import InputError

            raise InputError(f"frames have {frames.shape[1]} colours but a display without "
                             f"LUTs shows at most {self.MAX_CHANNELS} (red, green, blue): give "
                             f"one LUT per colour (luts=...) or at most {self.MAX_CHANNELS} "
                             f"colours")
        return frames

    def show(self, pattern: np.ndarray, *, channel: int = 0, t: int = 0,
             settle_s: Optional[float] = None) -> FrameRecord:
        """Upload ``pattern`` (uint8 [H, W]) through colour ``channel``'s LUT, swap at the next
        refresh, wait the settle delay; returns (and logs) the frame's times.

        Parameters
        ----------
        pattern : uint8 array ``[H, W]``
            Gray levels.
        channel : int
            The colour (and LUT) index: ``0 <=`` channel ``<`` the number of LUTs (3 without
            LUTs); another is refused.
        t : int
            Frame index, for the log.
        settle_s : float, optional
            Settle delay for this frame, seconds (default the display's; checked as the
            display's, 0..1).
        """
        self._check_open()
        channel = self._check_channel(channel)
        settle = self.settle_s if settle_s is None else check_settle_s(settle_s)
        levels = self._levels(pattern, channel)
        shown = self._present(levels)
        if settle > 0:
            time.sleep(settle)
        record = FrameRecord(t, channel, shown, time.monotonic())
        self.log.append(record)
        return record

    def play(self, frames: np.ndarray, *, repeats: int = 1,
             on_frame=None) -> List[FrameRecord]:
        """Show a ``[T, C, H, W]`` uint8 sequence colour after colour (t=0: c=0,1,..; t=1: ...),
        one pattern per refresh, ``repeats`` times. Every pattern is checked before the first
        is shown. ``on_frame(record)`` runs after each pattern settled (e.g. a camera trigger).

        Parameters
        ----------
        frames : uint8 array ``[T, C, H, W]``
            The sequence.
        repeats : int
            How many times to play it (>= 1; 0 or less is refused).
        on_frame : callable, optional
            ``on_frame(record)`` after each pattern settled.
        """
        from clholo.validate import count

        self._check_open()
        repeats = count(repeats, name="repeats")
        frames = self.check_sequence(frames)
        out = []
        for _ in range(repeats):
            for t in range(frames.shape[0]):
                for c in range(frames.shape[1]):
                    rec = self.show(frames[t, c], channel=c, t=t)
                    out.append(rec)
                    if on_frame is not None:
                        on_frame(rec)
        return out

    def write_log(self, path: Union[str, Path], *, overwrite: bool = False) -> None:
        """The frame-time log as CSV (columns as :func:`write_frame_log`'s), under clholo's
        output-file rule (:func:`clholo.io.output.output_file`, as ``clholo display --log``).

        Parameters
        ----------
        path : str or os.PathLike
            The CSV file to create.
        overwrite : bool
            Replace an existing ``path`` that clholo wrote (a frame log written earlier and not
            changed since). A file clholo did not write, or one edited since, is never
            replaced, whatever this says.

        Raises
        ------
        clholo.errors.OutputRefused
            ``path`` exists and may not be replaced, or is a folder; the message names it.
        FileNotFoundError
            Its parent folder does not exist.
        PermissionError
            Its parent folder cannot be written to.
        """
        _write_frame_log(self.log, path, overwrite=overwrite, command="Display.write_log")

    def _present(self, levels: np.ndarray) -> float:  # pragma: no cover - abstract
        raise NotImplementedError

    def _check_open(self) -> None:
        """Raise when the display can no longer show anything (nothing to check here)."""

    def close(self) -> None:
        """Release the display (nothing to release in the base class)."""
        pass

    def __enter__(self):
        self._check_open()
        return self

    def __exit__(self, *exc):
        self.close()


class MemoryDisplay(Display):
    """A display in memory: :attr:`screen` holds the levels last shown (after the LUT),
    :attr:`count` how many patterns were shown. With ``pace=True`` each swap waits for the next
    refresh tick like a vsync'd window.

    Parameters
    ----------
    width, height : int
        Pixels (default the Pluto-2.1's 1920 x 1080).
    pace : bool
        Wait for the next refresh tick at each swap.
    keep : int
        Keep the last ``keep`` patterns shown in :attr:`history` (0: none; a negative count is
        refused).
    **kwargs
        ``luts``, ``settle_s``, ``refresh_hz`` as for :class:`Display`.
    """

    def __init__(self, width: int = PLUTO_RESOLUTION[0], height: int = PLUTO_RESOLUTION[1], *,
                 pace: bool = False, keep: int = 0, **kwargs):
        from clholo.validate import count

        super().__init__(width, height, **kwargs)
        self.pace = pace
        self.keep = count(keep, name="keep", minimum=0)
        self.screen = np.zeros(self.shape, np.uint8)
        self.history: List[np.ndarray] = []
        self.count = 0
        self._t0 = time.monotonic()
        self._last_tick = 0

    def _present(self, levels: np.ndarray) -> float:
        np.copyto(self.screen, levels)
        if self.keep:
            self.history.append(levels.copy())
            del self.history[:-self.keep]
        self.count += 1
        now = time.monotonic()
        if self.pace:
            # like a vsync'd swap: the next refresh tick after now and after the last swap;
            # the tick itself is the time the frame went on screen
            period = 1.0 / self.refresh_hz
            k = max(np.ceil((now - self._t0) / period), self._last_tick + 1)
            self._last_tick = k
            tick = self._t0 + k * period
            time.sleep(max(0.0, tick - now))
            return float(tick)
        return now


def _glfw():
    from clholo.errors import require_extra

    return require_extra("glfw", "slm", "the SLM window (SLMWindow)")


def check_display_server() -> None:
    """Refuse, before GLFW is touched, to open a window where there is no display server (on
    Linux: neither ``DISPLAY`` nor ``WAYLAND_DISPLAY`` is set).

    Raises
    ------
    clholo.errors.NoDisplayError
        Saying what to do: run in the bench's desktop session (or under Xvfb), or show on
        memory instead.
    """
    import os
    import sys

    from clholo.errors import NoDisplayError

    if sys.platform.startswith(("linux", "freebsd")) and not (
            os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        raise NoDisplayError(
            "no display server: DISPLAY is not set, so no window can open on the SLM; run in "
            "the bench's desktop session (or under Xvfb), or show on memory instead "
            "(clholo display --memory, clholo capture --simulate)")


def list_monitors() -> List[Monitor]:
    """The window system's monitors (GLFW must be initialised)."""
    glfw = _glfw()
    out = []
    for m in glfw.get_monitors() or []:
        mode = glfw.get_video_mode(m)
        x, y = glfw.get_monitor_pos(m)
        name = glfw.get_monitor_name(m)
        out.append(Monitor(name.decode() if isinstance(name, bytes) else str(name),
                           mode.size.width, mode.size.height, x, y,
                           float(mode.refresh_rate or 60)))
    return out


def _glfw_quietly(glfw, call, *args):
    """``call(*args)`` and the errors GLFW reported meanwhile, as text.

    The glfw package reports GLFW's errors as Python warnings (``GLFWError``) by default, which
    would print a two-line warning (its source file and line) before clholo's own one-line
    error; kept as text, they go into that error instead. Other warnings are passed on; a
    ``GLFWError`` raised (a program that set ``glfw.ERROR_REPORTING = 'raise'``) counts as a
    failed call.
    """
    import re
    import warnings

    category = getattr(glfw, "GLFWError", None) or type("GLFWError", (UserWarning,), {})
    errors: List[str] = []
    result = None
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", category)
        try:
            result = call(*args)
        except category as exc:
            errors.append(str(exc))
    for w in caught:
        if issubclass(w.category, category):
            errors.append(str(w.message))
        else:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno, source=w.source)
    # "(65550) b'X11: Failed to open display :99'" -> "X11: Failed to open display :99"
    text = [re.sub(r"^\(\d+\) b?(['\"])(.*)\1$", r"\2", e, flags=re.S) for e in errors]
    return result, text


def _init_glfw(glfw) -> None:
    """``glfw.init()``, or :class:`clholo.errors.NoDisplayError` saying what GLFW said."""
    import os

    from clholo.errors import NoDisplayError

    ok, errors = _glfw_quietly(glfw, glfw.init)
    if not ok:
        said = f" ({'; '.join(errors)})" if errors else ""
        where = os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")
        raise NoDisplayError(f"GLFW could not initialise: no display server answered"
                             f"{f' on {where}' if where else ''}{said}: check DISPLAY (the "
                             f"bench's desktop session), or run under Xvfb for tests")


#: How many users of GLFW this process has now: open :class:`SLMWindow` objects and running
#: :func:`find_monitor` calls. GLFW is initialised once for all of them and terminated when the
#: last one is done, because ``glfw.terminate()`` destroys every window of the process: with
#: two windows open (a notebook cell run again opens a second), closing one would otherwise
#: blank the other, whose ``show`` would go on returning records while nothing is on screen.
_glfw_users = 0


def _acquire_glfw(glfw) -> None:
    """Initialise GLFW (a no-op when already initialised) and count one more user of it."""
    global _glfw_users
    _init_glfw(glfw)
    _glfw_users += 1


def _release_glfw(glfw) -> None:
    """Count one user of GLFW less; terminate GLFW when it was the last."""
    global _glfw_users
    _glfw_users = max(0, _glfw_users - 1)
    if _glfw_users == 0:
        glfw.terminate()


def _monitor_choice(monitor: Union[str, int, None]) -> dict:
    """``monitor`` (a name substring or an index) as :func:`choose_monitor`'s keywords."""
    return {"name": monitor if isinstance(monitor, str) else None,
            "index": monitor if isinstance(monitor, int) else None}


def find_monitor(monitor: Union[str, int, None] = None, *,
                 resolution: Optional[Sequence[int]] = _DEFAULT_RESOLUTION,
                 source: Union[str, Path, None] = None) -> Monitor:
    """The SLM's monitor as :class:`SLMWindow` would choose it, without opening a window.

    A command calls it before it loads a scene, so that a bench file whose monitor and
    resolution disagree is refused in a second. It initialises GLFW and terminates it again,
    unless an :class:`SLMWindow` is open (which keeps GLFW initialised until it closes).

    Parameters
    ----------
    monitor : str, int or None
        The monitor's name (substring) or index; None picks the monitor of ``resolution``.
    resolution : (int, int) or None
        The SLM's ``(width, height)`` (see :func:`choose_monitor`).
    source : str or os.PathLike, optional
        The bench file they come from, named in refusals (see :func:`choose_monitor`).

    Returns
    -------
    Monitor
        The SLM's monitor.

    Raises
    ------
    clholo.errors.NoDisplayError
        No display server (``DISPLAY`` unset, or no server answers on it).
    clholo.errors.InputError
        As :func:`choose_monitor`.
    """
    check_display_server()
    glfw = _glfw()
    _acquire_glfw(glfw)
    try:
        return choose_monitor(list_monitors(), **_monitor_choice(monitor),
                              resolution=resolution, source=source)
    finally:
        _release_glfw(glfw)


#: (cleanup, note) to run when the X connection is lost, innermost last (:func:`on_display_lost`)
_display_lost: List[Tuple[Callable[[], None], str]] = []
#: the ctypes callback given to Xlib, kept alive for as long as the process runs
_xio_handler = None


@contextlib.contextmanager
def on_display_lost(cleanup: Callable[[], None], note: str = "") -> Iterator[None]:
    """Run ``cleanup`` if the X server goes away while the block runs.

    Xlib treats a lost connection as fatal: its I/O error handler must not return (when it
    does, Xlib calls ``exit(1)``), and it runs inside a GLFW call, where no Python exception
    can unwind. So no ``finally`` and no ``with`` block of the caller would run: a sweep would
    leave its temporary output folder and a moving stage behind, and exit 1 after Xlib's
    "XIO: fatal IO error" lines. Instead, while an :class:`SLMWindow` is open on X11, the
    handler runs every registered cleanup (innermost first), prints one line ``clholo CMD:
    error: the display server went away ...`` with the cleanups' notes, and ends the process
    with exit code 3 (:attr:`clholo.errors.ExitCode.ENVIRONMENT`).

    Parameters
    ----------
    cleanup : callable
        Called without arguments; must not need the display (it is gone); errors are ignored.
    note : str
        What it did, for the line (``"nothing written"``).
    """
    entry = (cleanup, note)
    _display_lost.append(entry)
    try:
        yield
    finally:
        _display_lost.remove(entry)


def _display_lost_exit(_display) -> int:  # pragma: no cover - runs in a child process
    """Xlib's I/O error handler (see :func:`on_display_lost`): clean up, one line, exit 3."""
    import os
    import sys

    notes = []
    try:
        for cleanup, note in reversed(list(_display_lost)):
            try:
                cleanup()
                if note:
                    notes.append(note)
            except BaseException:
                pass   # the others still run; the process ends below whatever happens
        argv = sys.argv
        label = (f"clholo {argv[1]}" if os.path.basename(argv[0] or "") == "clholo"
                 and len(argv) > 1 else "clholo")
        where = os.environ.get("DISPLAY", "")
        said = "".join(f"; {n}" for n in notes)
        os.write(2, (f"{label}: error: the display server{f' {where}' if where else ''} went "
                     f"away (X connection lost): the SLM window is gone{said}; start the "
                     f"display server (the bench's desktop session) and run again\n").encode())
    finally:
        os._exit(3)   # ExitCode.ENVIRONMENT; Xlib would exit(1) if the handler returned
    return 0


def _install_display_lost_handler() -> None:
    """Give Xlib :func:`_display_lost_exit` as its I/O error handler (once per process),
    after GLFW opened its connection. GLFW loads libX11 by its soname, so loading that name
    again gives the same library and the handler applies to GLFW's connection; without
    libX11 (Windows, macOS, GLFW on Wayland only) there is nothing to do."""
    global _xio_handler
    import ctypes
    import sys

    if _xio_handler is not None or not sys.platform.startswith(("linux", "freebsd")):
        return
    try:
        x11 = ctypes.CDLL("libX11.so.6")
    except OSError:
        return
    prototype = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_void_p)
    handler = prototype(_display_lost_exit)
    x11.XSetIOErrorHandler.argtypes = [prototype]
    x11.XSetIOErrorHandler.restype = ctypes.c_void_p
    x11.XSetIOErrorHandler(handler)
    _xio_handler = handler


class SLMWindow(Display):
    """A borderless window covering the SLM's monitor at its native resolution.

    Parameters
    ----------
    monitor : str, int or None
        The monitor's name (substring) or index; None picks the monitor whose mode is
        ``resolution``.
    monitors : sequence of Monitor or None
        Injected monitor list (tests); None asks GLFW.
    resolution : (int, int) or None
        (width, height) the SLM has: given explicitly, a monitor named or indexed must have it
        (refused otherwise); by default (Pluto-2.1: 1920x1080) it only picks the monitor when
        none is named (:func:`choose_monitor`).
    vsync : bool
        Swap at the vertical blank (swap interval 1) and wait for it (``glFinish``).
    keep_readback : bool
        Read the rendered image back (``glReadPixels`` of the back buffer just before each
        swap, so exactly what the swap presents) for :meth:`read_back`. Costs a read per
        frame: for tests and calibration. (The front buffer reads as zeros under Xvfb with
        Mesa's llvmpipe, so it cannot serve.)
    title : str
        The window's title.
    source : str or os.PathLike, optional
        The bench file ``monitor`` and ``resolution`` come from, named in refusals (its ``[slm]
        monitor`` and ``[slm] resolution``).
    **kwargs
        ``luts``, ``settle_s`` as for :class:`Display`.

    Notes
    -----
    Several windows may be open at once (a notebook cell run again opens a second one on the
    same monitor): each draws in its own OpenGL context, and GLFW ends only when the last one
    closes. A closed window refuses ``show``, ``play``, ``read_back`` and ``with``: open a
    new one.

    On X11 the loss of the display server ends the process with exit code 3 and one line,
    after the cleanups registered with :func:`on_display_lost` ran (Xlib allows nothing
    else: see there).
    """

    def __init__(self, monitor: Union[str, int, None] = None, *,
                 monitors: Optional[Sequence[Monitor]] = None,
                 resolution: Optional[Sequence[int]] = _DEFAULT_RESOLUTION, vsync: bool = True,
                 keep_readback: bool = False, title: str = "clholo SLM",
                 source: Union[str, Path, None] = None, **kwargs):
        check_display_server()
        glfw = _glfw()
        self.keep_readback = keep_readback
        self._readback: Optional[np.ndarray] = None
        self._window = None
        _acquire_glfw(glfw)
        try:
            found = list_monitors() if monitors is None else list(monitors)
            chosen = choose_monitor(found, **_monitor_choice(monitor), resolution=resolution,
                                    source=source)
            super().__init__(chosen.width, chosen.height, refresh_hz=chosen.refresh_hz,
                             **kwargs)
            self.monitor = chosen
            for hint, value in ((glfw.DECORATED, False), (glfw.RESIZABLE, False),
                                (glfw.FLOATING, True), (glfw.AUTO_ICONIFY, False),
                                (glfw.FOCUS_ON_SHOW, False), (glfw.DOUBLEBUFFER, True)):
                glfw.window_hint(hint, value)
            self._window, errors = _glfw_quietly(glfw, glfw.create_window, chosen.width,
                                                 chosen.height, title, None, None)
            if not self._window:
                from clholo.errors import EnvironmentProblem

                said = f" ({'; '.join(errors)})" if errors else ""
                raise EnvironmentProblem(f"GLFW could not open a window on the display server "
                                         f"(no OpenGL?){said}: check the graphics driver")
            glfw.set_window_pos(self._window, chosen.x, chosen.y)
            glfw.make_context_current(self._window)
            glfw.swap_interval(1 if vsync else 0)
            self._setup_gl()
            _install_display_lost_handler()   # after GLFW opened its X connection
        except BaseException:
            # other windows may be open: destroy only this one, end GLFW only if it was the last
            if self._window:
                glfw.destroy_window(self._window)
                self._window = None
            _release_glfw(glfw)
            raise

    def _setup_gl(self) -> None:
        from OpenGL import GL

        fw, fh = _glfw().get_framebuffer_size(self._window)
        if (fw, fh) != (self.width, self.height):
            from clholo.errors import EnvironmentProblem

            raise EnvironmentProblem(f"the window's framebuffer is {fw}x{fh}, not the monitor's "
                               f"{self.width}x{self.height} (desktop scaling?)")
        GL.glViewport(0, 0, fw, fh)
        GL.glPixelStorei(GL.GL_UNPACK_ALIGNMENT, 1)
        GL.glPixelStorei(GL.GL_PACK_ALIGNMENT, 1)
        self._texture = GL.glGenTextures(1)
        GL.glBindTexture(GL.GL_TEXTURE_2D, self._texture)
        # NEAREST and a texture the size of the framebuffer: one texel per SLM pixel, exactly
        for param in (GL.GL_TEXTURE_MIN_FILTER, GL.GL_TEXTURE_MAG_FILTER):
            GL.glTexParameteri(GL.GL_TEXTURE_2D, param, GL.GL_NEAREST)
        GL.glTexImage2D(GL.GL_TEXTURE_2D, 0, GL.GL_LUMINANCE8, self.width, self.height, 0,
                        GL.GL_LUMINANCE, GL.GL_UNSIGNED_BYTE, None)
        GL.glEnable(GL.GL_TEXTURE_2D)
        GL.glDisable(GL.GL_DITHER)
        GL.glDisable(GL.GL_BLEND)

    def _check_open(self) -> None:
        """Refuse to use a closed window: GLFW aborts the whole process (a notebook's kernel
        too) on a swap of a destroyed window, instead of raising."""
        if getattr(self, "_window", None) is None:
            from clholo.errors import InputError

            raise InputError("the SLM window is closed: open a new SLMWindow")

    def _present(self, levels: np.ndarray) -> float:
        import ctypes

        from OpenGL import GL

        self._check_open()
        glfw = _glfw()
        # with several windows open, the GL calls below go to the current context: make it
        # this window's (its texture lives there)
        current = glfw.get_current_context()
        if ctypes.cast(current, ctypes.c_void_p).value != \
                ctypes.cast(self._window, ctypes.c_void_p).value:
            glfw.make_context_current(self._window)
        GL.glTexSubImage2D(GL.GL_TEXTURE_2D, 0, 0, 0, self.width, self.height, GL.GL_LUMINANCE,
                           GL.GL_UNSIGNED_BYTE, levels)
        # row 0 of the pattern is the top of the screen; GL's texture origin is the bottom
        GL.glBegin(GL.GL_QUADS)
        for (s, t), (x, y) in (((0, 1), (-1, -1)), ((1, 1), (1, -1)), ((1, 0), (1, 1)),
                               ((0, 0), (-1, 1))):
            GL.glTexCoord2f(s, t)
            GL.glVertex2f(x, y)
        GL.glEnd()
        if self.keep_readback:
            GL.glReadBuffer(GL.GL_BACK)
            data = GL.glReadPixels(0, 0, self.width, self.height, GL.GL_RED,
                                   GL.GL_UNSIGNED_BYTE)
            self._readback = np.frombuffer(data, np.uint8).reshape(self.shape)[::-1].copy()
        glfw.swap_buffers(self._window)
        GL.glFinish()   # returns once the swap happened (at the vertical blank with vsync)
        glfw.poll_events()
        return time.monotonic()

    def read_back(self) -> np.ndarray:
        """The levels the last swap presented, ``uint8 [H, W]`` (red channel; R = G = B),
        row 0 at the top; needs ``keep_readback=True``."""
        self._check_open()
        if not self.keep_readback:
            raise ValueError("read_back needs SLMWindow(..., keep_readback=True)")
        if self._readback is None:
            raise ValueError("nothing shown yet")
        return self._readback.copy()

    def close(self) -> None:
        """Destroy the window, and end GLFW when no other window is open. Closing twice does
        nothing."""
        window = getattr(self, "_window", None)
        if window:
            glfw = _glfw()
            self._window = None
            glfw.destroy_window(window)
            _release_glfw(glfw)
