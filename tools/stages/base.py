"""The one interface every motion stage of the bench implements, and its named errors.

A stage moves along one axis in millimetres. Every wait has a timeout; when a wait fails the
driver tells the controller to stop before it raises, so that a fault never leaves a motor
running.
"""

from __future__ import annotations

import abc
import time
from typing import Any, Callable, Optional, Tuple

__all__ = ["Stage", "StageError", "StageTimeoutError", "HomingTimeoutError",
           "StageProtocolError", "StageLimitError", "StageNotReferencedError",
           "StageCommandError", "StageClosedError", "StagePortBusyError",
           "StagePositionError", "wait_for", "check_setting", "check_wait", "open_port",
           "SECONDS", "COUNTS_PER_MM_RANGE", "TRAVEL_MM", "TOLERANCE_MM", "WHOLE"]

# The drivers' settings and their plausible ranges: one check (:func:`check_setting`) for the
# Python API (the drivers' constructors) and the bench file (``clholo.tools.config``). A value
# outside is almost always another unit (milliseconds for seconds, counts per micrometre for
# counts per mm) or a slip (a negative retry count, NaN), and is refused with the fix rather
# than run (a wait whose deadline is NaN never ends).
#: seconds: (smallest, whether the smallest itself is allowed, largest, example)
SECONDS = {"reply_timeout": (0.0, False, 60.0, "reply_timeout = 0.5 for 500 ms"),
           "poll": (0.0, False, 10.0, "poll = 0.05 for 50 ms"),
           "keepalive": (0.0, False, 1.0, "keepalive = 0.5 for 500 ms"),
           "purge_dwell": (0.0, True, 10.0, "purge_dwell = 0.05 for 50 ms"),
           "reset_wait": (0.0, True, 120.0, "reset_wait = 10 for 10 s"),
           # one stage move (or homing) of a capture sweep; a long stage at low speed may
           # need minutes, an hour is a unit slip
           "move_timeout": (0.0, False, 3600.0, "move_timeout = 120 for 2 minutes")}
#: counts per millimetre of an APT motor (Z8: 34554.96; Z6: 24600; DC servo stages ~2e4)
COUNTS_PER_MM_RANGE = (100.0, 1e6)
#: travel of a bench stage, mm
TRAVEL_MM = 1000.0
#: how far (mm) a measured position may lie from the requested one: (default, largest). The
#: default, 5 um, is far above the settle window of either controller (a few encoder counts of
#: an APT servo, 30 nm counts, or the CONEX-AGP's 0.2 um step) and far below any sweep step;
#: more than 1 mm is a unit slip (micrometres given?)
TOLERANCE_MM = (0.005, 1.0)
#: whole-number settings: (smallest, largest)
WHOLE = {"retries": (0, 100), "channel": (1, 16), "address": (1, 31)}


def check_setting(key: str, value: Any, *, label: Optional[str] = None,
                  assign: str = "=") -> Any:
    """One driver setting checked for its type and plausible range; returns it (a float, an
    int, a bool, or ``[low, high]`` for ``limits``).

    Parameters
    ----------
    key : str
        The setting: a key of :data:`SECONDS`, ``counts_per_mm``, ``limits`` (or
        ``limits_mm``), ``tolerance_mm``, a key of :data:`WHOLE`, or ``require_homed``.
    value
        What was given.
    label : str, optional
        How the message names it (default ``key``; the bench file gives ``[z_stage] key``).
    assign : str
        Between the name and the value in the message (``"="``).

    Raises
    ------
    clholo.errors.InputError
        Naming the setting, the value and the valid range (NaN, infinities, negative or
        implausibly large seconds, counts per mm outside 100..1e6, limits not ``low < high``
        or beyond 1000 mm, a retry count below 0).
    clholo.errors.InputTypeError
        Not a number (a count that is not a whole number; ``require_homed`` not a bool).
    """
    import numbers

    import numpy as np

    from clholo.errors import InputError, InputTypeError
    from clholo.validate import real_scalar

    name = key if label is None else label
    said = f"{name} {assign} {value!r}"

    def number(v, fix):
        return real_scalar(name, v, fix=fix)

    if key in SECONDS:
        low, low_ok, top, example = SECONDS[key]
        fix = f"give seconds {'>=' if low_ok else '>'} {low:g} and <= {top:g}, e.g. {example}"
        x = number(value, fix)
        if x < low or (x == low and not low_ok):
            raise InputError(f"{said} is out of range: {fix}")
        if x > top:
            raise InputError(f"{said} is more than {top:g} s: {key} is in seconds "
                             f"(milliseconds given?); write e.g. {example}")
        return x
    if key == "counts_per_mm":
        low, high = COUNTS_PER_MM_RANGE
        x = number(value, f"give encoder counts per millimetre, {low:g}..{high:g}, e.g. "
                          f"counts_per_mm = 34554.96 for a Z8 motor")
        if not low <= x <= high:
            per = "micrometre" if 0 < x < low else "metre" if x > high else "mm"
            raise InputError(f"{said} is outside the {low:g}..{high:g} of a stage motor "
                             f"(counts per {per} given?): give encoder counts per millimetre, "
                             f"e.g. counts_per_mm = 34554.96 for a Z8 motor")
        return x
    if key == "tolerance_mm":
        top = TOLERANCE_MM[1]
        fix = (f"give millimetres > 0 and <= {top:g}, e.g. tolerance_mm = 0.005 for 5 um")
        x = number(value, fix)
        if x <= 0:
            raise InputError(f"{said} is out of range: {fix}")
        if x > top:
            raise InputError(f"{said} is more than {top:g} mm: tolerance_mm is in millimetres "
                             f"(micrometres given?); write e.g. tolerance_mm = 0.005 for 5 um")
        return x
    if key in ("limits", "limits_mm"):
        if isinstance(value, (str, bytes)) or not hasattr(value, "__len__") or len(value) != 2:
            raise InputError(f"{said} must be (low, high) in mm, two numbers, e.g. [0.0, 25.0]")
        fix = f"give [low, high] in mm within +-{TRAVEL_MM:g}, e.g. [0.0, 25.0]"
        if not all(isinstance(v, numbers.Real) and not isinstance(v, (bool, np.bool_))
                   and np.isfinite(float(v)) for v in value):
            raise InputError(f"{said} must be two finite numbers: {fix}")
        low, high = (float(v) for v in value)
        if not low < high:
            raise InputError(f"{said} must be [low, high] in mm with low < high")
        if max(abs(low), abs(high)) > TRAVEL_MM:
            raise InputError(f"{said} reaches beyond {TRAVEL_MM:g} mm: {key} is in "
                             f"millimetres (micrometres given?); write e.g. [0.0, 25.0]")
        return [low, high]
    if key in WHOLE:
        from clholo.validate import count

        low, high = WHOLE[key]
        try:
            return count(value, name=name, minimum=low, maximum=high)
        except InputTypeError:
            raise
        except ValueError as exc:
            raise InputError(f"{exc}: give a whole number from {low} to {high}") from None
    if key == "require_homed":
        if not isinstance(value, (bool, np.bool_)):
            raise InputTypeError(f"{name} must be true or false, got {value!r}")
        return bool(value)
    raise KeyError(key)  # pragma: no cover - a caller's bug, not a user's


def check_wait(name: str, value: Any) -> float:
    """A wait's length in seconds: finite and > 0 (a NaN deadline never comes, a negative
    one has passed before anything was asked). Raises InputError / InputTypeError naming
    ``name``."""
    import numbers

    import numpy as np

    from clholo.errors import InputError, InputTypeError

    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
        raise InputTypeError(f"{name} must be seconds (a real number), got {value!r}")
    x = float(value)
    if not (np.isfinite(x) and x > 0):
        raise InputError(f"{name}={value!r} must be a finite number of seconds > 0, e.g. "
                         f"{name}=30")
    return x


class StageError(RuntimeError):
    """Base class of every stage fault."""


class StageTimeoutError(StageError, TimeoutError):
    """A reply or a motion did not arrive within its timeout (the stage was told to stop)."""


class HomingTimeoutError(StageTimeoutError):
    """Homing did not finish within its timeout (the stage was told to stop)."""


class StageProtocolError(StageError):
    """A reply could not be decoded (garbled bytes, wrong message, wrong length)."""


class StageLimitError(StageError):
    """The stage hit a limit switch or reports an end-of-run error (it was told to stop)."""


class StageNotReferencedError(StageError):
    """The controller refuses to move before it is homed: call ``home()`` first."""


class StageCommandError(StageError):
    """The controller reported an error for the last command (its code and text are kept).

    Parameters
    ----------
    message : str
        The controller's text.
    code : str
        Its error code.
    """

    def __init__(self, message: str, code: str = ""):
        super().__init__(message)
        self.code = code


class StageClosedError(StageError):
    """The stage was used after ``close()`` (or after its ``with`` block): open it again."""


class StagePortBusyError(StageError):
    """The serial port is held by another program (or another clholo run): two programs on
    one controller interleave their bytes, so the port is opened exclusively and refused."""


class StagePositionError(StageError):
    """A move ended away from the requested position (the stage stopped at the end of its
    travel, or a controller reports a position that cannot be right)."""


def open_port(port: str, **settings) -> Any:
    """``serial.serial_for_url(port, **settings)``, opened, exclusively where that means
    something.

    A device path (``/dev/ttyUSB0``, ``COM3``, a pty's name) is opened with
    ``exclusive=True``: on POSIX pyserial then takes an ``flock`` on it, so a second program
    (or a second ``clholo capture``) on the same controller is refused at once instead of
    interleaving its bytes with ours; Windows ports are always exclusive. A pyserial URL
    (``loop://``, ``socket://host:port``) is not a device: it keeps pyserial's default.

    Raises
    ------
    StagePortBusyError
        Another program holds the port.
    clholo.errors.InputError
        ``port`` is a URL whose protocol pyserial does not know (``foo://x``).
    serial.SerialException
        Any other failure to open (no such port, no permission): an ``OSError``.
    """
    import errno

    import serial

    from clholo.errors import InputError

    if "://" not in port:
        settings["exclusive"] = True
    try:
        handle = serial.serial_for_url(port, do_not_open=True, **settings)
    except ValueError as exc:   # pyserial: "invalid URL, protocol 'foo' not known"
        raise InputError(f"port = {port!r} is not a serial port pyserial can open ({exc}): "
                         f"give a device such as /dev/ttyUSB0 or COM3, or a pyserial URL such "
                         f"as socket://host:port") from None
    try:
        handle.open()
    except serial.SerialException as exc:
        # pyserial's flock(LOCK_EX | LOCK_NB) failing: "Could not exclusively lock port"
        if getattr(exc, "errno", None) in (errno.EAGAIN, errno.EWOULDBLOCK):
            raise StagePortBusyError(
                f"port {port} is busy: another program (or another clholo run) holds it; "
                f"close that program and run again") from None
        raise
    return handle


def wait_for(predicate: Callable[[], bool], *, timeout: float, poll: float,
             what: str, on_timeout: Optional[Callable[[], None]] = None,
             error: type = StageTimeoutError,
             on_fault: Optional[Callable[[], None]] = None) -> None:
    """Call ``predicate`` every ``poll`` seconds until it returns True; after ``timeout`` seconds
    call ``on_timeout`` (e.g. stop the motor) and raise ``error`` naming ``what``.

    When ``predicate`` itself raises a :class:`StageError` (the controller stopped answering
    while the motor may still run), ``on_fault`` is called (best effort: e.g. send the stop
    command without waiting for a reply that will not come) and the error is raised again.
    """
    timeout, poll = check_wait("timeout", timeout), check_wait("poll", poll)
    deadline = time.monotonic() + timeout
    while True:
        try:
            done = predicate()
        except StageError:
            if on_fault is not None:
                try:
                    on_fault()
                except (StageError, OSError):
                    pass  # the fault in flight is the one to report; the stop was best effort
            raise
        if done:
            return
        if time.monotonic() >= deadline:
            if on_timeout is not None:
                try:
                    on_timeout()
                except StageError:
                    pass  # the timeout is the fault to report; the stop was best effort
            raise error(f"{what} did not finish within {timeout:g} s; the stage was told to stop")
        time.sleep(poll)


class Stage(abc.ABC):
    """One motorised axis, positions in millimetres.

    Use as a context manager (``with open_stage(...) as z:``) so that ``close()`` runs.
    ``limits`` are the travel range the driver allows, ``(low, high)`` in mm; a target outside
    is refused with ``ValueError`` before anything is sent.
    """

    #: travel range in mm, set by each driver
    _limits: Tuple[float, float] = (float("-inf"), float("inf"))
    #: the port the driver opened and its ``open_stage`` kind, for the message that says how
    #: to open a closed stage again (set by each driver)
    port: str = ""
    kind: str = ""
    #: how far (mm) a measured position may lie from the requested one before a sweep calls
    #: the move short (:data:`TOLERANCE_MM`; the drivers take ``tolerance_mm``)
    tolerance_mm: float = TOLERANCE_MM[0]
    #: a motion command went out and no status has shown the motor stopped since: a query the
    #: controller does not answer meanwhile sends the stop (:meth:`_lost_contact`)
    _motion_unconfirmed: bool = False
    _stopping_blind: bool = False

    @property
    def closed(self) -> bool:
        """True once :meth:`close` has run (the port is released; open the stage again)."""
        return False

    def _check_open(self) -> None:
        """Raise :class:`StageClosedError` when the stage is closed: without it a closed port
        surfaces as pyserial's bare ``PortNotOpenError``, which names neither the stage nor
        the fix."""
        if self.closed:
            raise StageClosedError(
                f"the stage on {self.port} is closed: open it again with "
                f"open_stage({self.port!r}, kind={self.kind!r}, ...)")

    def _stop_blind(self) -> None:
        """Send the stop command without waiting for any reply, ignoring every error.

        For a controller that stopped answering: its motor may still run, and a stop that
        waits for an acknowledgement would only add a second timeout. Drivers override this
        with a bare write; the default asks :meth:`stop`.
        """
        try:
            self.stop()
        except (StageError, OSError):
            pass

    def _lost_contact(self, error: StageError) -> StageError:
        """``error``, for a query the controller did not answer validly, to raise. While a
        motion this driver started may still run (a ``wait=False`` move the user follows with
        ``position()`` or ``is_moving()``), the stop goes out first, blind, and the message
        says so: a controller that stops answering must not leave its motor running until the
        ``with`` block's ``close()``."""
        if self._motion_unconfirmed and not self._stopping_blind:
            self._stopping_blind = True  # a driver whose blind stop queries must not recurse
            try:
                self._stop_blind()
            finally:
                self._stopping_blind = False
            error.args = (f"{error.args[0] if error.args else error}; a motion was under way, "
                          f"so the stop command was sent (no reply awaited)",) + error.args[1:]
        return error

    @property
    def limits(self) -> Tuple[float, float]:
        """``(low, high)``: the travel range in mm."""
        return self._limits

    def _check_target(self, target_mm: float, *, name: str = "position_mm") -> float:
        from clholo.validate import real_scalar

        target = real_scalar(name, target_mm)
        low, high = self.limits
        if not low <= target <= high:
            raise ValueError(f"{name}={target:g} mm is outside the stage's travel "
                             f"[{low:g}, {high:g}] mm: give a position inside it")
        return target

    @abc.abstractmethod
    def home(self, *, timeout: float = 60.0) -> None:
        """Find the reference switch; raises :class:`HomingTimeoutError` after ``timeout`` s."""

    @abc.abstractmethod
    def move_to(self, position_mm: float, *, wait: bool = True, timeout: float = 30.0) -> None:
        """Move to ``position_mm`` (mm); with ``wait`` block until the move completes.

        Parameters
        ----------
        position_mm : float
            Target position, millimetres.
        wait : bool
            Block until the move completes.
        timeout : float
            Seconds to wait at most (then :class:`StageTimeoutError`).
        """

    def move_by(self, distance_mm: float, *, wait: bool = True, timeout: float = 30.0) -> None:
        """Move by ``distance_mm`` (mm) from the current position.

        Parameters
        ----------
        distance_mm : float
            Distance, millimetres (negative moves back).
        wait : bool
            Block until the move completes.
        timeout : float
            Seconds to wait at most (then :class:`StageTimeoutError`).
        """
        from clholo.validate import real_scalar

        distance = real_scalar("distance_mm", distance_mm)
        timeout = check_wait("timeout", timeout)
        self._check_target(self.position() + distance, name="position + distance_mm")
        self._move_relative(distance, wait=wait, timeout=timeout)

    @abc.abstractmethod
    def _move_relative(self, distance_mm: float, *, wait: bool, timeout: float) -> None:
        """Driver's relative move (target already checked against the limits)."""

    @abc.abstractmethod
    def position(self) -> float:
        """The current position in mm."""

    @abc.abstractmethod
    def is_moving(self) -> bool:
        """True while the axis moves or homes."""

    def wait_until_stopped(self, *, timeout: float = 30.0, poll: float = 0.05) -> None:
        """Block until :meth:`is_moving` is False; raise :class:`StageTimeoutError` after
        ``timeout`` s (and stop the stage). A controller that stops answering meanwhile is
        sent the stop command (no reply awaited) before its error is raised.

        Parameters
        ----------
        timeout : float
            Seconds to wait at most.
        poll : float
            Seconds between checks.
        """
        # a controller that stops answering while the motor runs: stop it blind, then raise
        wait_for(lambda: not self.is_moving(), timeout=timeout, poll=poll, what="motion",
                 on_timeout=self.stop, on_fault=self._stop_blind)

    @abc.abstractmethod
    def stop(self) -> None:
        """Stop any motion now."""

    @abc.abstractmethod
    def close(self) -> None:
        """Release the port (the motor is stopped first if it moves; when the controller does
        not answer, the stop is sent anyway). Closing twice is harmless; any other use of a
        closed stage raises :class:`StageClosedError`."""

    def __enter__(self) -> "Stage":
        self._check_open()  # a closed stage in a with block would fail at its first command
        return self

    def __exit__(self, *exc) -> None:
        self.close()
