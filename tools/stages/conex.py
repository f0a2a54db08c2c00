"""Newport CONEX-AGP over its ASCII protocol (921600 8N1, commands end in CR LF).

Every command is ``<address><two letters>[value]``, e.g. ``1PA5.25``; queries answer with the
same prefix (``1TP5.250000``). The driver keeps one query outstanding at a time, asks ``TE``
(last command error, one letter, ``@`` = none) after every action and ``TB`` (its text) when
there is one, and follows the controller's state machine from ``TS`` (four hex digits of error
flags, then a two-character state code): moves only in READY, homing (``OR``) only in NOT
REFERENCED, so re-homing a referenced stage needs ``RS`` (reset) and a wait first.
"""

from __future__ import annotations

import math
import threading
import time
from typing import Optional, Sequence, Tuple

from .base import (TRAVEL_MM, HomingTimeoutError, Stage, StageCommandError, StageError,
                   StageLimitError, StageNotReferencedError, StageProtocolError,
                   StageTimeoutError, check_setting, check_wait, open_port)

__all__ = ["ConexStage", "READY_STATES", "NOT_REFERENCED_STATES", "parse_ts", "format_command"]

READY_STATES = ("32", "33", "34")
NOT_REFERENCED_STATES = ("0A", "0B", "0C", "0D", "0E", "0F", "10")
HOMING, MOVING = "1E", "28"
END_OF_RUN = 0x0003   # negative (0x0001) and positive (0x0002) end-of-run flags


def format_command(address: int, command: str, value: Optional[float] = None) -> bytes:
    """``1PA5.25\\r\\n``: address, two-letter command, optional value, CR LF."""
    text = f"{address}{command}" + ("" if value is None else f"{value:.6g}")
    return (text + "\r\n").encode("ascii")


def parse_ts(reply: str) -> Tuple[int, str]:
    """``'000033'`` (the text after ``1TS``) -> (error flags, state code)."""
    if len(reply) != 6:
        raise StageProtocolError(f"TS reply must be 4 hex flag digits + 2 state characters, "
                                 f"got {reply!r}")
    try:
        flags = int(reply[:4], 16)
    except ValueError:
        raise StageProtocolError(f"TS reply has non-hex error flags: {reply!r}") from None
    return flags, reply[4:].upper()


class ConexStage(Stage):
    """A Newport CONEX-AGP stage (the pupil stage at the Fourier plane).

    Parameters
    ----------
    port : str
        Anything ``serial.serial_for_url`` opens.
    address : int
        Controller address (1 unless daisy-chained).
    limits : (float, float) or None
        Travel in mm; None takes the controller's (``SL?``, ``SR?``). Given limits must lie
        within the controller's: a move beyond them would be refused by the controller only
        once the sweep runs (``TE`` C), so they are refused here
        (:class:`~clholo.errors.InputError` naming the controller's travel).
    reply_timeout : float
        Seconds to wait for one reply line; queries are retried ``retries`` times.
    reset_wait : float
        Seconds to wait after ``RS`` before the controller answers again (it reboots).
    poll : float
        Seconds between ``TS`` polls while moving.
    retries : int
        How many times a lost reply is asked for again (0..100).
    tolerance_mm : float
        How far (mm) a measured position may lie from the requested one in a capture sweep
        (default 0.005).

    Every setting is checked before the port opens, with the bench file's ranges
    (:func:`~clholo.tools.stages.base.check_setting`); NaN, infinities and values outside
    are refused with :class:`~clholo.errors.InputError` naming the argument.
    """

    def __init__(self, port: str, *, address: int = 1, limits: Optional[Sequence[float]] = None,
                 reply_timeout: float = 0.5, retries: int = 2, reset_wait: float = 10.0,
                 poll: float = 0.02, tolerance_mm: float = 0.005):
        from clholo.errors import InputError

        # checked before the port opens, by the bench file's own check (check_setting)
        self.address = check_setting("address", address)
        self.reply_timeout = check_setting("reply_timeout", reply_timeout)
        self.retries = check_setting("retries", retries)
        self.reset_wait = check_setting("reset_wait", reset_wait)
        self.poll = check_setting("poll", poll)
        self.tolerance_mm = check_setting("tolerance_mm", tolerance_mm)
        if limits is not None:
            limits = check_setting("limits", limits)
        self.port, self.kind = port, "conex"
        self._lock = threading.RLock()
        # exclusive: a second program on the controller is refused (StagePortBusyError)
        self._serial = open_port(port, baudrate=921600, bytesize=8, parity="N", stopbits=1,
                                 timeout=0.01, xonxoff=False)
        try:
            self._serial.reset_input_buffer()
            self._serial.reset_output_buffer()
            travel = self._controller_travel()
            if limits is None:
                low, high = travel
            else:
                low, high = (float(v) for v in limits)
                if low < travel[0] or high > travel[1]:
                    raise InputError(
                        f"limits = [{low:g}, {high:g}] mm (limits_mm in the bench file) reach "
                        f"beyond the travel of the CONEX controller on {port}, "
                        f"[{travel[0]:g}, {travel[1]:g}] mm (its SL?/SR?): give limits within "
                        f"it, or leave limits out to use the controller's")
            self._limits = (low, high)
        except BaseException:
            self._serial.close()
            raise

    # -- transport -------------------------------------------------------------------------
    @property
    def closed(self) -> bool:
        """True once :meth:`close` has run."""
        return not self._serial.is_open

    def _write(self, command: str, value: Optional[float] = None) -> None:
        self._check_open()
        self._serial.write(format_command(self.address, command, value))
        self._serial.flush()

    def _readline(self, timeout: float) -> Optional[str]:
        deadline = time.monotonic() + timeout
        buf = bytearray()
        while time.monotonic() < deadline:
            buf += self._serial.read(max(1, self._serial.in_waiting))
            if buf.endswith(b"\r\n"):
                return buf[:-2].decode("ascii", "replace")
        return None

    def _query(self, command: str, prefix: str) -> str:
        """Send a query and return the text after ``<address><prefix>``; lost or garbled
        replies are asked for again ``retries`` times (one query outstanding at a time)."""
        head = f"{self.address}{prefix}"
        with self._lock:
            self._check_open()   # before the buffer reset, which a closed port refuses
            for _attempt in range(self.retries + 1):
                self._serial.reset_input_buffer()   # a late reply to a lost query goes too
                self._write(command)
                line = self._readline(self.reply_timeout)
                if line is not None and line.startswith(head) and line.isprintable():
                    return line[len(head):]
            raise self._lost_contact(StageTimeoutError(
                f"no valid reply to {self.address}{command} on {self.port} within "
                f"reply_timeout = {self.reply_timeout:g} s ({self.retries + 1} tries); check "
                f"the cable, the baud rate (921600) and the controller address (a slow "
                f"controller: raise reply_timeout)"))

    def _controller_travel(self) -> Tuple[float, float]:
        """The controller's software limits (``SL?``, ``SR?``), mm, checked: a travel that is
        empty or beyond a bench stage's (a garbled line, a controller not configured) is a
        device fault, :class:`StageProtocolError` naming the answers."""
        low, high = self._query_float("SL?", "SL"), self._query_float("SR?", "SR")
        if not (low < high and max(abs(low), abs(high)) <= TRAVEL_MM):
            raise StageProtocolError(
                f"the CONEX controller on {self.port} gives its travel as SL {low:g} mm, "
                f"SR {high:g} mm: not a stage's travel (low < high, within "
                f"+-{TRAVEL_MM:g} mm); check the controller's configuration (SL, SR) and the "
                f"cable")
        return low, high

    def _query_float(self, command: str, prefix: str) -> float:
        """A query whose answer is a finite number; any other answer (text, ``nan``, ``inf``)
        is asked for again, then :class:`StageProtocolError` naming it: a position of NaN or
        infinity would pass every comparison and end up in the sweep's log."""
        for _attempt in range(self.retries + 1):
            text = self._query(command, prefix)
            try:
                value = float(text)
            except ValueError:
                continue
            if math.isfinite(value):
                return value
        raise self._lost_contact(
            StageProtocolError(f"the CONEX controller on {self.port} answered "
                               f"{self.address}{command} with {text!r}, not a finite number: a "
                               f"garbled line or a controller fault; check the cable"))

    def _check_error(self, what: str) -> None:
        """``TE`` after an action; when it reports an error, ``TB`` gives its text."""
        code = self._query("TE", "TE").strip()
        if len(code) != 1:
            raise StageProtocolError(f"TE reply must be one letter, got {code!r}")
        if code == "@":
            return
        text = CONEX_TEXT.get(code, "unknown error")
        if code == "H":
            raise StageNotReferencedError(f"{what}: the CONEX stage is NOT REFERENCED: call "
                                          f"home() first")
        if code in ("G", "N"):
            raise StageLimitError(f"{what}: {text} (TE {code})")
        raise StageCommandError(f"{what}: controller error {code}: {text}", code)

    def _action(self, command: str, value: Optional[float], what: str) -> None:
        """A motion command (``OR``, ``PA``, ``PR``) and its ``TE``. When ``TE`` gets no valid
        reply the command may have started a motion that nobody follows: the stop goes out
        blind before the error is raised."""
        with self._lock:
            self._motion_unconfirmed = True  # until a state reply shows the motor stopped
            self._write(command, value)
            try:
                self._check_error(what)
            except (StageTimeoutError, StageProtocolError):
                self._stop_blind()
                raise

    # -- queries ---------------------------------------------------------------------------
    def state(self) -> Tuple[int, str]:
        """(error flags, state code) from ``TS``."""
        for _attempt in range(self.retries + 1):
            try:
                flags, code = parse_ts(self._query("TS", "TS"))
            except StageProtocolError:
                continue
            if code not in (HOMING, MOVING):
                self._motion_unconfirmed = False  # the motor is seen stopped
            return flags, code
        try:
            return parse_ts(self._query("TS", "TS"))
        except StageProtocolError as exc:
            raise self._lost_contact(exc) from None

    def position(self) -> float:
        return self._query_float("TP", "TP")

    def is_moving(self) -> bool:
        return self.state()[1] in (HOMING, MOVING)

    # -- motion ----------------------------------------------------------------------------
    def stop(self) -> None:
        with self._lock:
            self._write("ST")
            self._check_error("stop")

    def _stop_blind(self) -> None:
        """``ST`` written without asking ``TE`` (a controller that stopped answering will not
        reply); any error is ignored."""
        try:
            self._serial.write(format_command(self.address, "ST"))
            self._serial.flush()
        except (OSError, ValueError):
            pass  # a port that is gone: nothing more can be sent

    def _wait_state(self, wanted: Sequence[str], *, timeout: float, what: str,
                    homing: bool) -> None:
        deadline = time.monotonic() + timeout
        while True:
            try:
                flags, code = self.state()
            except StageError:
                # the controller stopped answering mid-motion: the motor may still run
                self._stop_blind()
                raise
            if flags & END_OF_RUN:
                self._safe_stop()
                side = "negative" if flags & 0x0001 else "positive"
                raise StageLimitError(f"{what}: the stage reached its {side} end of run "
                                      f"(TS flags {flags:04X}, state {code}); reset and home it")
            if code in wanted:
                return
            if code not in (HOMING, MOVING):
                raise StageCommandError(f"{what}: the controller left the motion in state "
                                        f"{code} instead of READY", code)
            if time.monotonic() >= deadline:
                self._safe_stop()
                error = HomingTimeoutError if homing else StageTimeoutError
                raise error(f"{what} did not finish within {timeout:g} s; the stage was told "
                            f"to stop")
            time.sleep(self.poll)

    def _safe_stop(self) -> None:
        try:
            self.stop()
        except (StageTimeoutError, StageProtocolError, StageCommandError):
            pass  # the fault being reported matters more than the stop's own reply

    def home(self, *, timeout: float = 60.0) -> None:
        """``OR``; a referenced (or disabled) controller is reset (``RS``) first, because it
        accepts ``OR`` only in NOT REFERENCED."""
        timeout = check_wait("timeout", timeout)
        with self._lock:
            _flags, code = self.state()
            if code not in NOT_REFERENCED_STATES:
                self._write("RS")
                time.sleep(self.reset_wait)
                deadline = time.monotonic() + max(timeout, self.reply_timeout)
                while True:
                    try:
                        _flags, code = self.state()
                        break
                    except StageTimeoutError:
                        if time.monotonic() >= deadline:
                            raise StageTimeoutError("the CONEX controller did not answer after "
                                                    "reset (RS); raise reset_wait") from None
            self._action("OR", None, "homing")
            self._wait_state(READY_STATES, timeout=timeout, what="homing", homing=True)

    def move_to(self, position_mm: float, *, wait: bool = True, timeout: float = 30.0) -> None:
        target = self._check_target(position_mm)
        timeout = check_wait("timeout", timeout)
        with self._lock:
            self._action("PA", target, f"move to {target:g} mm")
            if wait:
                self._wait_state(READY_STATES, timeout=timeout, what=f"move to {target:g} mm",
                                 homing=False)

    def _move_relative(self, distance_mm: float, *, wait: bool, timeout: float) -> None:
        with self._lock:
            self._action("PR", distance_mm, f"move by {distance_mm:g} mm")
            if wait:
                self._wait_state(READY_STATES, timeout=timeout,
                                 what=f"move by {distance_mm:g} mm", homing=False)

    def close(self) -> None:
        """Stop the motor if it moves and release the port; closing twice is harmless."""
        if not self._serial.is_open:
            return
        try:
            if self.is_moving():
                self._safe_stop()
        except (StageError, OSError):
            # the controller did not answer: its motor may still run, so the stop goes out
            # blind; closing does not raise (it runs on the way out of a fault or a Ctrl-C)
            self._stop_blind()
        finally:
            self._serial.close()


CONEX_TEXT = {
    "A": "unknown message code or floating point controller address",
    "B": "controller address not correct", "C": "parameter missing or out of range",
    "D": "command not allowed", "E": "home sequence already started",
    "G": "displacement out of limits", "H": "command not allowed in NOT REFERENCED state",
    "I": "command not allowed in CONFIGURATION state",
    "J": "command not allowed in DISABLE state", "K": "command not allowed in READY state",
    "L": "command not allowed in HOMING state", "M": "command not allowed in MOVING state",
    "N": "current position out of software limit", "S": "communication time out",
    "U": "error during EEPROM access", "V": "error during command execution",
}
