"""Controllers simulated as state machines behind a pseudo-terminal.

Each simulator opens a pty (``os.openpty()``), serves the master side from a thread, and gives
the slave side's name as :attr:`PtySimulator.port`; a driver opens that name with
``serial.serial_for_url`` exactly as it opens ``/dev/ttyUSB0``, so the real code path (termios,
byte framing, timeouts) runs in the tests.

Motion follows a constant-velocity model on a simulated clock that runs ``speedup`` times faster
than the wall clock, so a 10 s homing takes 10 s / speedup in a test.

Injectable faults (attributes, change them at any time):

* ``stale_bytes``: bytes already waiting in the port when the driver opens it;
* ``garble``: ``{reply name: count}``, the next ``count`` such replies are corrupted;
* ``drop``: ``{reply name: count}``, the next ``count`` such replies are never sent;
* ``late``: ``{reply name: count}``, the next ``count`` such replies are sent ``late_s`` wall
  seconds late (after the driver gave up waiting);
* ``latency_s``: every reply is sent this many wall seconds after its request, in order (a
  slow bus: replies to requests sent before a wait ended are still on their way after it);
* ``homing_never_finishes``: homing runs for ever;
* ``limit_switch``: ``(low_mm, high_mm)``, hardware limit switches inside the travel: a motion
  that reaches one stops there with the controller's limit/end-of-run flag set.
"""

from __future__ import annotations

import os
import select
import threading
import time
import tty
from typing import Dict, List, Optional, Tuple

from . import apt

__all__ = ["PtySimulator", "AptSimulator", "ConexSimulator"]


class PtySimulator:
    """Base: a pty, a serving thread, a simulated clock and the fault switches."""

    def __init__(self, *, speedup: float = 100.0, stale_bytes: bytes = b""):
        self.speedup = float(speedup)
        self.garble: Dict[str, int] = {}
        self.drop: Dict[str, int] = {}
        self.late: Dict[str, int] = {}
        self.late_s = 0.5
        self.latency_s = 0.0
        self._outbox: List[Tuple[float, bytes]] = []
        self.homing_never_finishes = False
        self.limit_switch: Optional[Tuple[float, float]] = None
        self.received: List[Tuple[float, str]] = []   # (wall time, request name)
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)  # no echo or CRLF translation before the driver sets its mode
        self.port = os.ttyname(self._slave)
        if stale_bytes:
            os.write(self._master, stale_bytes)
        self._t0 = time.monotonic()
        self._last_tick = self._t0
        self._stop = threading.Event()
        self._lock = threading.RLock()
        self._thread = threading.Thread(target=self._serve, name=type(self).__name__, daemon=True)
        self._thread.start()

    # -- plumbing --------------------------------------------------------------------------
    def sim_time(self) -> float:
        """Simulated seconds since start."""
        return (time.monotonic() - self._t0) * self.speedup

    def _serve(self) -> None:
        while not self._stop.is_set():
            try:
                ready, _, _ = select.select([self._master], [], [], 0.002)
                data = os.read(self._master, 4096) if ready else b""
            except OSError:
                if self._stop.is_set():
                    return
                time.sleep(0.005)
                continue
            with self._lock:
                now = time.monotonic()
                while self._outbox and self._outbox[0][0] <= now:
                    os.write(self._master, self._outbox.pop(0)[1])
                self._advance((now - self._last_tick) * self.speedup)
                self._last_tick = now
                if data:
                    self._on_bytes(data)

    def _fault(self, table: Dict[str, int], name: str) -> bool:
        if table.get(name, 0) > 0:
            table[name] -= 1
            return True
        return False

    def _reply(self, name: str, data: bytes) -> None:
        """Send a reply unless a fault drops or garbles it."""
        if self._fault(self.drop, name):
            return
        if self._fault(self.garble, name):
            data = self._garbled(data)
        if self._fault(self.late, name):
            self._schedule(time.monotonic() + self.late_s, data)
            return
        if self.latency_s > 0:
            self._schedule(time.monotonic() + self.latency_s, data)
            return
        os.write(self._master, data)

    def _schedule(self, when: float, data: bytes) -> None:
        """Queue ``data`` for the wall time ``when``, after everything queued for the same time
        or earlier (the serving loop sends the outbox from its front)."""
        i = len(self._outbox)
        while i > 0 and self._outbox[i - 1][0] > when:
            i -= 1
        self._outbox.insert(i, (when, data))

    @staticmethod
    def _garbled(data: bytes) -> bytes:
        # junk in front and the second byte replaced (the APT message id's high byte, the CONEX
        # command's first letter): the reply is unusable and the decoder must resynchronise.
        # (APT has no checksum: a corrupted data byte would pass undetected on the real bus.)
        return b"\xA5\x00\x13" + data[:1] + b"\xFF" + data[2:]

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2)
        for fd in (self._master, self._slave):
            try:
                os.close(fd)
            except OSError:
                pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    # -- motion model shared by both ---------------------------------------------------------
    def _step_towards(self, position: float, target: float, velocity: float, dt: float
                      ) -> Tuple[float, Optional[str]]:
        """Advance ``position`` towards ``target``; returns (new position, "low"/"high" when a
        limit switch stopped it)."""
        step = velocity * dt
        new = min(target, position + step) if target > position else max(target, position - step)
        if self.limit_switch is not None:
            low, high = self.limit_switch
            if target > position and new >= high:
                return high, "high"
            if target < position and new <= low:
                return low, "low"
        return new, None

    def _advance(self, dt: float) -> None:  # pragma: no cover - overridden
        pass

    def _on_bytes(self, data: bytes) -> None:  # pragma: no cover - overridden
        pass


class AptSimulator(PtySimulator):
    """A KDC101 + MTS25-Z8 speaking the APT binary protocol (single channel, destination 0x50).

    Implements HW_NO_FLASH_PROGRAMMING, HW_REQ_INFO, MOD_SET_CHANENABLESTATE, MOVE_HOME,
    MOVE_ABSOLUTE / MOVE_RELATIVE (long form), MOVE_STOP, REQ_DCSTATUSUPDATE and records
    ACK_DCSTATUSUPDATE keep-alives in :attr:`acks` (wall times). Moves are allowed before homing
    (as on the real controller); the HOMED bit tells whether it was homed.
    """

    def __init__(self, *, counts_per_mm: float = apt.COUNTS_PER_MM_Z8, velocity_mm_s: float = 2.4,
                 travel_mm: Tuple[float, float] = (0.0, 25.0), start_mm: float = 12.0,
                 serial_number: int = 27000001, **kwargs):
        self.counts_per_mm = counts_per_mm
        self.velocity = velocity_mm_s
        self.travel = travel_mm
        self.serial_number = serial_number
        self.position_mm = float(start_mm)
        self.target_mm: Optional[float] = None
        self.mode = "idle"            # idle, moving, homing
        self.homed = False
        self.enabled = False
        self.limit_bits = 0
        self.acks: List[float] = []
        self.flash_programming_off = False
        self._decoder = apt.AptDecoder(dest=apt.USB_UNIT, source=apt.HOST)
        super().__init__(**kwargs)

    def _counts(self) -> int:
        return int(round(self.position_mm * self.counts_per_mm))

    def _bits(self) -> int:
        bits = self.limit_bits
        if self.mode == "homing":
            bits |= apt.STATUS["HOMING"]
        elif self.mode == "moving" and self.target_mm is not None:
            bits |= (apt.STATUS["MOVING_FORWARD"] if self.target_mm > self.position_mm
                     else apt.STATUS["MOVING_REVERSE"])
        if self.homed:
            bits |= apt.STATUS["HOMED"]
        if self.enabled:
            bits |= apt.STATUS["ENABLED"]
        if self.mode == "idle":
            bits |= apt.STATUS["SETTLED"]
        return bits

    def _status_data(self) -> bytes:
        velocity = 0 if self.mode == "idle" else 1000
        return apt.pack_status(1, self._counts(), velocity, self._bits())

    def _send_msg(self, name: str, param1: int = 0, data: Optional[bytes] = None) -> None:
        self._reply(name, apt.encode(apt.MSG[name], param1, 0, data=data, dest=apt.HOST,
                                     source=apt.USB_UNIT))

    def _advance(self, dt: float) -> None:
        if self.mode == "homing":
            self.position_mm, _ = self._step_towards(self.position_mm, self.travel[0],
                                                     self.velocity, dt)
            if self.position_mm == self.travel[0] and not self.homing_never_finishes:
                self.mode, self.homed, self.limit_bits = "idle", True, 0
                self._send_msg("MOT_MOVE_HOMED", 1)
        elif self.mode == "moving" and self.target_mm is not None:
            self.position_mm, hit = self._step_towards(self.position_mm, self.target_mm,
                                                       self.velocity, dt)
            if hit:
                # a limit switch: the controller stops the motor; no MOVE_COMPLETED
                self.mode, self.target_mm = "idle", None
                self.limit_bits = (apt.STATUS["FORWARD_LIMIT"] if hit == "high"
                                   else apt.STATUS["REVERSE_LIMIT"])
            elif self.position_mm == self.target_mm:
                self.mode, self.target_mm = "idle", None
                self._send_msg("MOT_MOVE_COMPLETED", data=self._status_data())

    def _start_move(self, target_mm: float) -> None:
        self.target_mm = min(max(target_mm, self.travel[0]), self.travel[1])
        self.mode = "moving"
        self.limit_bits = 0

    def _on_bytes(self, data: bytes) -> None:
        for msg in self._decoder.feed(data):
            self.received.append((time.monotonic(), msg.name))
            mid = msg.msg_id
            if mid == apt.MSG["HW_NO_FLASH_PROGRAMMING"]:
                self.flash_programming_off = True
            elif mid == apt.MSG["HW_REQ_INFO"]:
                self._send_msg("HW_GET_INFO", data=apt.pack_info(
                    self.serial_number, "KDC101", notes="APT DC Motor Controller (simulated)"))
            elif mid == apt.MSG["MOD_SET_CHANENABLESTATE"]:
                self.enabled = msg.param2 == 0x01
            elif mid == apt.MSG["MOT_MOVE_HOME"]:
                self.mode, self.target_mm, self.limit_bits = "homing", None, 0
                self.homed = False
            elif mid == apt.MSG["MOT_MOVE_ABSOLUTE"] and msg.data is not None:
                _chan, counts = apt.struct.unpack("<Hi", msg.data)
                self._start_move(counts / self.counts_per_mm)
            elif mid == apt.MSG["MOT_MOVE_RELATIVE"] and msg.data is not None:
                _chan, counts = apt.struct.unpack("<Hi", msg.data)
                self._start_move(self.position_mm + counts / self.counts_per_mm)
            elif mid == apt.MSG["MOT_MOVE_STOP"]:
                self.mode, self.target_mm = "idle", None
                self._send_msg("MOT_MOVE_STOPPED", data=self._status_data())
            elif mid == apt.MSG["MOT_REQ_DCSTATUSUPDATE"]:
                self._send_msg("MOT_GET_DCSTATUSUPDATE", data=self._status_data())
            elif mid == apt.MSG["MOT_ACK_DCSTATUSUPDATE"]:
                self.acks.append(time.monotonic())


# CONEX state codes (two hex digits after the four error-flag digits of the TS reply)
CONEX_STATES = {
    "0A": "NOT REFERENCED from RESET", "0B": "NOT REFERENCED from HOMING",
    "0C": "NOT REFERENCED from CONFIGURATION", "0D": "NOT REFERENCED from DISABLE",
    "0E": "NOT REFERENCED from READY", "0F": "NOT REFERENCED from MOVING",
    "10": "NOT REFERENCED - NO PARAMETERS", "14": "CONFIGURATION", "1E": "HOMING",
    "28": "MOVING", "32": "READY from HOMING", "33": "READY from MOVING",
    "34": "READY from DISABLE", "3C": "DISABLE from READY", "3D": "DISABLE from MOVING",
}
CONEX_ERRORS = {
    "@": "No error", "A": "Unknown message code or floating point controller address",
    "B": "Controller address not correct", "C": "Parameter missing or out of range",
    "D": "Command not allowed", "E": "Home sequence already started",
    "G": "Displacement out of limits", "H": "Command not allowed in NOT REFERENCED state",
    "I": "Command not allowed in CONFIGURATION state", "J": "Command not allowed in DISABLE state",
    "K": "Command not allowed in READY state", "L": "Command not allowed in HOMING state",
    "M": "Command not allowed in MOVING state", "N": "Current position out of software limit",
    "S": "Communication time out", "V": "Error during command execution",
}
#: TS error flags (four hex digits)
CONEX_FLAGS = {"NEGATIVE_END_OF_RUN": 0x0001, "POSITIVE_END_OF_RUN": 0x0002,
               "FOLLOWING_ERROR": 0x0020, "HOMING_TIME_OUT": 0x0040}


class ConexSimulator(PtySimulator):
    """A Newport CONEX-AGP at address 1: ASCII commands ending in CR LF.

    Implements ``OR``, ``PA``, ``PR``, ``TP``, ``TS``, ``ST``, ``TE``, ``TB``, ``RS``, ``SL?``,
    ``SR?`` with the state rules: moves only in READY (``H`` in NOT REFERENCED), ``OR`` only in
    NOT REFERENCED (``K`` in READY: re-homing needs ``RS`` first), no reply at all for
    ``reset_s`` simulated seconds after ``RS``.
    """

    def __init__(self, *, velocity_mm_s: float = 0.4,
                 travel_mm: Tuple[float, float] = (-13.5, 13.5), start_mm: float = 3.0,
                 reset_s: float = 10.0, address: int = 1, **kwargs):
        self.velocity = velocity_mm_s
        self.travel = travel_mm
        self.address = str(address)
        self.position_mm = float(start_mm)
        self.target_mm: Optional[float] = None
        self.state = "0A"
        self.flags = 0
        self.error = "@"
        self.reset_s = reset_s
        self._reset_until: Optional[float] = None
        self._line = bytearray()
        super().__init__(**kwargs)

    def _send_line(self, name: str, text: str) -> None:
        self._reply(name, (self.address + text + "\r\n").encode("ascii"))

    def _advance(self, dt: float) -> None:
        if self._reset_until is not None and self.sim_time() >= self._reset_until:
            self._reset_until, self.state, self.flags, self.error = None, "0A", 0, "@"
        if self.state == "1E":
            self.position_mm, _ = self._step_towards(self.position_mm, 0.0, self.velocity, dt)
            if self.position_mm == 0.0 and not self.homing_never_finishes:
                self.state = "32"
        elif self.state == "28" and self.target_mm is not None:
            self.position_mm, hit = self._step_towards(self.position_mm, self.target_mm,
                                                       self.velocity, dt)
            if hit:
                self.state, self.target_mm = "3D", None
                self.flags |= CONEX_FLAGS["POSITIVE_END_OF_RUN" if hit == "high"
                                          else "NEGATIVE_END_OF_RUN"]
            elif self.position_mm == self.target_mm:
                self.state, self.target_mm = "33", None

    def _ready(self) -> bool:
        return self.state in ("32", "33", "34")

    def _not_referenced(self) -> bool:
        return self.state in ("0A", "0B", "0C", "0D", "0E", "0F", "10")

    def _on_bytes(self, data: bytes) -> None:
        self._line += data
        while b"\n" in self._line:
            raw, _, rest = bytes(self._line).partition(b"\n")
            self._line = bytearray(rest)
            self._command(raw.rstrip(b"\r").decode("ascii", "replace").strip())

    def _move(self, target: float) -> None:
        if self._not_referenced():
            self.error = "H"
        elif self.state == "28":
            self.error = "M"
        elif not self._ready():
            self.error = "J" if self.state.startswith("3") else "D"
        elif not self.travel[0] <= target <= self.travel[1]:
            self.error = "C"
        else:
            self.target_mm, self.state, self.flags = target, "28", 0

    def _command(self, line: str) -> None:
        if self._reset_until is not None:
            return  # rebooting: deaf
        self.received.append((time.monotonic(), line))
        if not line.startswith(self.address) or len(line) < len(self.address) + 2:
            self.error = "A"
            return
        body = line[len(self.address):]
        name, arg = body[:2].upper(), body[2:].strip()
        try:
            value = float(arg) if arg and arg != "?" else None
        except ValueError:
            self.error = "C"
            return
        if name == "TE":
            self._send_line("TE", "TE" + self.error)
            self.error = "@"
        elif name == "TB":
            self._send_line("TB", f"TB{self.error} {CONEX_ERRORS[self.error]}")
            self.error = "@"
        elif name == "TP":
            self._send_line("TP", f"TP{self.position_mm:.6f}")
        elif name == "TS":
            self._send_line("TS", f"TS{self.flags:04X}{self.state}")
        elif name == "SL" and arg == "?":
            self._send_line("SL", f"SL{self.travel[0]:g}")
        elif name == "SR" and arg == "?":
            self._send_line("SR", f"SR{self.travel[1]:g}")
        elif name == "OR":
            if self.state == "1E":
                self.error = "E"
            elif self._not_referenced():
                self.state, self.flags = "1E", 0
            else:
                self.error = "K" if self._ready() else "D"
        elif name == "PA":
            if value is None:
                self.error = "C"
            else:
                self._move(value)
        elif name == "PR":
            if value is None:
                self.error = "C"
            else:
                self._move(self.position_mm + value)
        elif name == "ST":
            if self.state == "28":
                self.state, self.target_mm = "33", None
            elif self.state == "1E":
                self.state = "0B"
        elif name == "RS":
            self._reset_until = self.sim_time() + self.reset_s
            self.target_mm = None
        else:
            self.error = "A"
