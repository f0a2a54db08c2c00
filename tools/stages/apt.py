"""Thorlabs APT binary protocol (KDC101 / TDC001 DC servo controllers, MTS25-Z8 stage).

Message layout (Thorlabs "APT Communications Protocol", section 2):

* every message starts with a 6-byte header: the message id as a little-endian uint16, then
  either two one-byte parameters (``param1, param2``) or, when a data packet follows, its length
  as a little-endian uint16; then the destination byte and the source byte;
* the destination has bit 0x80 set when a data packet follows; a host talking to a single-channel
  USB controller uses destination 0x50 ("generic USB unit") and source 0x01 ("host");
* data packets are little-endian structures (see :data:`DATA_LENGTHS` and the ``pack_*`` and
  ``unpack_*`` helpers below).

The driver sends the ``MOT_ACK_DCSTATUSUPDATE`` keep-alive at least once a second while it waits
for a motion, polls ``MOT_REQ_DCSTATUSUPDATE`` for the limit switches, and tells the controller
to stop (``MOT_MOVE_STOP``) before it raises any fault.
"""

from __future__ import annotations

import struct
import threading
import time
from typing import Callable, Dict, List, NamedTuple, Optional, Sequence, Tuple

from .base import (TRAVEL_MM, HomingTimeoutError, Stage, StageError, StageLimitError,
                   StageNotReferencedError, StagePositionError, StageProtocolError,
                   StageTimeoutError, check_setting, check_wait, open_port)

__all__ = ["HOST", "USB_UNIT", "MSG", "DATA_LENGTHS", "STATUS", "AptMessage", "AptDecoder",
           "AptStatus", "AptInfo", "encode", "pack_status", "unpack_status", "pack_info",
           "unpack_info", "pack_move", "AptStage", "COUNTS_PER_MM_Z8", "COUNTS_PER_MM_Z8_OLD"]

HOST = 0x01
USB_UNIT = 0x50
HAS_DATA = 0x80

#: encoder counts per mm of an MTS25-Z8 (Z8 motor: 512 counts/rev x 67.49 gearbox / 1 mm lead
#: screw), Thorlabs' current document; older issues of the document give 34304.
COUNTS_PER_MM_Z8 = 34554.96
COUNTS_PER_MM_Z8_OLD = 34304.0

MSG = {
    "HW_REQ_INFO": 0x0005,
    "HW_GET_INFO": 0x0006,
    "HW_NO_FLASH_PROGRAMMING": 0x0018,
    "HW_RESPONSE": 0x0080,
    "HW_RICHRESPONSE": 0x0081,
    "MOD_SET_CHANENABLESTATE": 0x0210,
    "MOT_MOVE_HOME": 0x0443,
    "MOT_MOVE_HOMED": 0x0444,
    "MOT_MOVE_RELATIVE": 0x0448,
    "MOT_MOVE_ABSOLUTE": 0x0453,
    "MOT_MOVE_COMPLETED": 0x0464,
    "MOT_MOVE_STOP": 0x0465,
    "MOT_MOVE_STOPPED": 0x0466,
    "MOT_REQ_DCSTATUSUPDATE": 0x0490,
    "MOT_GET_DCSTATUSUPDATE": 0x0491,
    "MOT_ACK_DCSTATUSUPDATE": 0x0492,
}
MSG_NAME = {v: k for k, v in MSG.items()}

#: data-packet length of each message that carries one (others are header-only). The moves
#: also have a header-only short form (use the stored parameters), which the decoder accepts.
DATA_LENGTHS = {
    0x0006: 84,   # HW_GET_INFO
    0x0081: 68,   # HW_RICHRESPONSE: msg id u16, code u16, 64 chars of text
    0x0448: 6,    # MOVE_RELATIVE: chan u16, distance i32 (counts)
    0x0453: 6,    # MOVE_ABSOLUTE: chan u16, position i32 (counts)
    0x0464: 14,   # MOVE_COMPLETED: DC status structure
    0x0466: 14,   # MOVE_STOPPED: DC status structure
    0x0491: 14,   # GET_DCSTATUSUPDATE
}

#: status bits of the DC status structure
STATUS = {
    "FORWARD_LIMIT": 0x00000001,
    "REVERSE_LIMIT": 0x00000002,
    "MOVING_FORWARD": 0x00000010,
    "MOVING_REVERSE": 0x00000020,
    "JOGGING_FORWARD": 0x00000040,
    "JOGGING_REVERSE": 0x00000080,
    "HOMING": 0x00000200,
    "HOMED": 0x00000400,
    "TRACKING": 0x00001000,
    "SETTLED": 0x00002000,
    "MOTION_ERROR": 0x00004000,
    "CURRENT_LIMIT": 0x01000000,
    "ENABLED": 0x80000000,
}
_MOVING_BITS = (STATUS["MOVING_FORWARD"] | STATUS["MOVING_REVERSE"] | STATUS["JOGGING_FORWARD"]
                | STATUS["JOGGING_REVERSE"] | STATUS["HOMING"])
#: the messages that end a motion: none names the command it answers, so one left unread from
#: an earlier motion (a ``wait=False`` move, a home that ended by status) would be taken for
#: the next motion's end
_MOTION_ENDS = (MSG["MOT_MOVE_HOMED"], MSG["MOT_MOVE_COMPLETED"], MSG["MOT_MOVE_STOPPED"])
#: request -> its reply, for the requests whose replies the driver counts (:meth:`AptStage._send`)
_REPLY_TO = {MSG["HW_REQ_INFO"]: MSG["HW_GET_INFO"],
             MSG["MOT_REQ_DCSTATUSUPDATE"]: MSG["MOT_GET_DCSTATUSUPDATE"]}


class AptMessage(NamedTuple):
    msg_id: int
    param1: int = 0
    param2: int = 0
    dest: int = USB_UNIT
    source: int = HOST
    data: Optional[bytes] = None

    @property
    def name(self) -> str:
        return MSG_NAME.get(self.msg_id, f"0x{self.msg_id:04x}")


def encode(msg_id: int, param1: int = 0, param2: int = 0, *, data: Optional[bytes] = None,
           dest: int = USB_UNIT, source: int = HOST) -> bytes:
    """One APT message as bytes: a header-only message with ``param1, param2``, or a header
    with the length of ``data`` (destination | 0x80) followed by ``data``."""
    if data is None:
        return struct.pack("<HBBBB", msg_id, param1 & 0xFF, param2 & 0xFF, dest, source)
    return struct.pack("<HHBB", msg_id, len(data), dest | HAS_DATA, source) + bytes(data)


class AptStatus(NamedTuple):
    channel: int
    position: int       # encoder counts
    velocity: int       # controller units
    bits: int

    @property
    def moving(self) -> bool:
        return bool(self.bits & _MOVING_BITS)

    @property
    def homed(self) -> bool:
        return bool(self.bits & STATUS["HOMED"])

    @property
    def homing(self) -> bool:
        return bool(self.bits & STATUS["HOMING"])


def pack_status(channel: int, position: int, velocity: int, bits: int) -> bytes:
    """The 14-byte DC status structure: chan u16, position i32, velocity u16, reserved u16,
    status bits u32."""
    return struct.pack("<HiHHI", channel, position, velocity & 0xFFFF, 0, bits & 0xFFFFFFFF)


def unpack_status(data: bytes) -> AptStatus:
    if len(data) != 14:
        raise StageProtocolError(f"DC status needs 14 bytes, got {len(data)}")
    channel, position, velocity, _reserved, bits = struct.unpack("<HiHHI", data)
    return AptStatus(channel, position, velocity, bits)


class AptInfo(NamedTuple):
    serial: int
    model: str
    hw_type: int
    firmware: Tuple[int, int, int]
    notes: str
    hw_version: int
    mod_state: int
    channels: int


def pack_info(serial: int, model: str, *, hw_type: int = 16, firmware=(3, 1, 0),
              notes: str = "", hw_version: int = 1, mod_state: int = 0, channels: int = 1) -> bytes:
    """The 84-byte HW_GET_INFO packet: serial u32, model 8 chars, type u16, firmware
    (minor, interim, major, unused) 4 bytes, notes 48 chars, 12 empty bytes, hardware version
    u16, modification state u16, channel count u16. ``firmware`` is (major, interim, minor)."""
    major, interim, minor = firmware
    return struct.pack("<I8sH4B48s12sHHH", serial, model.encode("ascii"), hw_type, minor,
                       interim, major, 0, notes.encode("ascii"), b"", hw_version, mod_state,
                       channels)


def unpack_info(data: bytes) -> AptInfo:
    if len(data) != 84:
        raise StageProtocolError(f"HW_GET_INFO needs 84 bytes, got {len(data)}")
    (serial, model, hw_type, minor, interim, major, _u, notes, _empty, hw_version, mod_state,
     channels) = struct.unpack("<I8sH4B48s12sHHH", data)
    text = lambda b: b.split(b"\0", 1)[0].decode("ascii", "replace")  # noqa: E731
    return AptInfo(serial, text(model), hw_type, (major, interim, minor), text(notes), hw_version,
                   mod_state, channels)


def pack_move(channel: int, counts: int) -> bytes:
    """The 6-byte data of MOVE_ABSOLUTE / MOVE_RELATIVE: chan u16, counts i32."""
    return struct.pack("<Hi", channel, counts)


class AptDecoder:
    """Split a byte stream into :class:`AptMessage` objects, resynchronising on garbage.

    A header is accepted only when its message id is known, its destination (less the data
    bit) and source are the expected ones, and a data length matches the message's; otherwise
    one byte is dropped and the search goes on. ``discarded`` counts the dropped bytes.
    """

    def __init__(self, *, dest: int = HOST, source: int = USB_UNIT):
        self.dest, self.source = dest, source
        self._buffer = bytearray()
        self.discarded = 0

    def _plausible(self, header: bytes) -> Optional[int]:
        msg_id, length = struct.unpack_from("<HH", header)
        dest, source = header[4], header[5]
        if msg_id not in MSG_NAME or (dest & ~HAS_DATA) != self.dest or source != self.source:
            return None
        if dest & HAS_DATA:
            return length if DATA_LENGTHS.get(msg_id) == length else None
        return 0

    @property
    def pending(self) -> int:
        """Bytes held back as the start of a message not yet complete."""
        return len(self._buffer)

    def discard_partial(self) -> int:
        """Forget the bytes of an incomplete message (counted in ``discarded``); returns how
        many. For a reply cut short on the line: its rest never comes, and without this the
        next reply's bytes would complete it (a mis-framed message that decodes as valid)."""
        n = len(self._buffer)
        self.discarded += n
        self._buffer.clear()
        return n

    def feed(self, data: bytes) -> List[AptMessage]:
        self._buffer += data
        out = []
        while len(self._buffer) >= 6:
            length = self._plausible(bytes(self._buffer[:6]))
            if length is None:
                del self._buffer[0]
                self.discarded += 1
                continue
            if len(self._buffer) < 6 + length:
                break
            header = bytes(self._buffer[:6])
            msg_id = struct.unpack_from("<H", header)[0]
            if length:
                out.append(AptMessage(msg_id, 0, 0, header[4], header[5],
                                      bytes(self._buffer[6:6 + length])))
            else:
                out.append(AptMessage(msg_id, header[2], header[3], header[4], header[5], None))
            del self._buffer[:6 + length]
        return out


class AptStage(Stage):
    """A Thorlabs KDC101/TDC001 + MTS25-Z8 z stage over the APT binary protocol.

    Parameters
    ----------
    port : str
        Anything ``serial.serial_for_url`` opens: ``/dev/ttyUSB0``, a pty's name, ``loop://``.
    counts_per_mm : float
        Encoder counts per millimetre (34554.96 for the Z8 motor in Thorlabs' current document,
        34304 in older ones): take it from the bench configuration.
    limits : (float, float)
        Travel in mm that the driver allows (MTS25: 0..25).
    channel : int
        Controller channel (1 on the single-channel KDC101/TDC001).
    reply_timeout : float
        Seconds to wait for one reply; a query is retried ``retries`` times before
        :class:`StageTimeoutError`.
    poll : float
        Seconds between status requests while a motion runs.
    keepalive : float
        Seconds between ``MOT_ACK_DCSTATUSUPDATE`` keep-alives while a motion runs (the
        controller wants at least one a second).
    require_homed : bool
        Refuse absolute moves before the controller reports HOMED.
    retries : int
        How many times a lost reply is asked for again (0..100).
    purge_dwell : float
        Seconds to dwell around the start-up purge.
    tolerance_mm : float
        How far (mm) a finished move may end from its target: farther is
        :class:`~clholo.tools.stages.base.StagePositionError` (default 0.005).

    Every setting is checked before the port opens, with the bench file's ranges
    (:func:`~clholo.tools.stages.base.check_setting`: seconds > 0 and plausible,
    ``counts_per_mm`` 100..1e6, ``limits`` within +-1000 mm, ``retries`` 0..100, ``channel``
    1..16); NaN, infinities and values outside are refused with
    :class:`~clholo.errors.InputError` naming the argument.
    """

    def __init__(self, port: str, *, counts_per_mm: float = COUNTS_PER_MM_Z8,
                 limits: Sequence[float] = (0.0, 25.0), channel: int = 1,
                 reply_timeout: float = 1.0, poll: float = 0.05, keepalive: float = 0.5,
                 retries: int = 2, require_homed: bool = True, purge_dwell: float = 0.05,
                 tolerance_mm: float = 0.005):
        # every setting checked before the port opens, by the bench file's own check
        # (clholo.tools.stages.base.check_setting): NaN, infinities and out-of-range values are
        # refused naming the argument and its range
        self.counts_per_mm = check_setting("counts_per_mm", counts_per_mm)
        low, high = check_setting("limits", limits)
        self._limits = (low, high)
        self.channel = check_setting("channel", channel)
        self.reply_timeout = check_setting("reply_timeout", reply_timeout)
        self.poll = check_setting("poll", poll)
        self.keepalive = check_setting("keepalive", keepalive)
        self.retries = check_setting("retries", retries)
        self.require_homed = check_setting("require_homed", require_homed)
        purge_dwell = check_setting("purge_dwell", purge_dwell)
        self.tolerance_mm = check_setting("tolerance_mm", tolerance_mm)
        self.port, self.kind = port, "apt"
        self._lock = threading.RLock()
        self._decoder = AptDecoder()
        self._pending: List[AptMessage] = []
        # replies still owed to requests already sent (reply id -> count): a status asked
        # while a motion ran may answer after the wait ended, and APT replies do not name
        # their request, so the next query would take it (an old position, "not moving")
        self._owed: Dict[int, int] = {}
        self._owed_until: Dict[int, float] = {}   # reply id -> when the last one is due
        self._last_ack = 0.0
        self._last_byte = time.monotonic()   # when bytes last came: a partial message older
        # than reply_timeout is the rest of a reply cut short, and is dropped (_read_some)
        self.log: List[Tuple[float, str]] = []   # (time, message name) sent, for diagnosis
        # exclusive: a second program on the controller is refused (StagePortBusyError)
        self._serial = open_port(port, baudrate=115200, bytesize=8, parity="N", stopbits=1,
                                 timeout=0.01, rtscts=True)
        try:
            self._purge_and_reset(purge_dwell)
            self._send(MSG["HW_NO_FLASH_PROGRAMMING"])
            self.info = unpack_info(self._query(MSG["HW_REQ_INFO"], MSG["HW_GET_INFO"]).data)
            self._send(MSG["MOD_SET_CHANENABLESTATE"], self.channel, 0x01)
        except BaseException:
            self._serial.close()
            raise

    # -- transport -------------------------------------------------------------------------
    def _purge_and_reset(self, dwell: float) -> None:
        """Thorlabs' FTDI start-up: dwell, purge both buffers, dwell, reset, RTS/CTS flow
        control with RTS set. Setting RTS on a pseudo-terminal raises OSError (ENOTTY), so the
        RTS toggle is best effort and the same code runs on a pty and on the USB port."""
        time.sleep(dwell)
        self._serial.reset_input_buffer()
        self._serial.reset_output_buffer()
        time.sleep(dwell)
        for level in (False, True):
            try:
                self._serial.rts = level
            except (OSError, ValueError):
                break
        self._serial.reset_input_buffer()
        self._decoder = AptDecoder()

    @property
    def closed(self) -> bool:
        """True once :meth:`close` has run."""
        return not self._serial.is_open

    def _send(self, msg_id: int, param1: int = 0, param2: int = 0, *,
              data: Optional[bytes] = None) -> None:
        self._check_open()   # every command and query starts here
        self._serial.write(encode(msg_id, param1, param2, data=data))
        self._serial.flush()
        self.log.append((time.monotonic(), MSG_NAME.get(msg_id, hex(msg_id))))
        reply = _REPLY_TO.get(msg_id)
        if reply is not None:
            self._owed[reply] = self._owed.get(reply, 0) + 1
            self._owed_until[reply] = time.monotonic() + self.reply_timeout

    def _read_some(self) -> None:
        chunk = self._serial.read(max(1, self._serial.in_waiting))
        now = time.monotonic()
        if self._decoder.pending and now - self._last_byte > self.reply_timeout:
            # the start of a message whose rest has not come for a reply timeout (a reply cut
            # short): the next bytes would complete it, mis-framed, into a valid-looking one
            self._decoder.discard_partial()
        if chunk:
            self._last_byte = now
            for msg in self._decoder.feed(chunk):
                if self._owed.get(msg.msg_id, 0) > 0:
                    self._owed[msg.msg_id] -= 1
                self._pending.append(msg)

    def _drop(self, msg_ids: Sequence[int]) -> None:
        """Read what is waiting and forget every message in ``msg_ids``: replies that belong
        to an earlier command, which a wait for the next one would take for its own."""
        while self._serial.in_waiting:
            self._read_some()
        self._pending = [m for m in self._pending if m.msg_id not in msg_ids]

    def _settle(self, reply: int) -> None:
        """Forget the ``reply`` messages of earlier requests: wait for those still owed (until
        ``reply_timeout`` after the last such request: a status poll's reply, ms after a
        motion's wait ends), then drop them with any already read. Replies that do not come by
        then (lost, garbled) are written off, so a lost reply costs one wait, once."""
        deadline = self._owed_until.get(reply, 0.0)
        while self._owed.get(reply, 0) > 0 and time.monotonic() < deadline:
            self._read_some()
        self._owed[reply] = 0
        self._drop([reply])

    def _start_motion(self, msg_id: int, param1: int = 0, *,
                      data: Optional[bytes] = None) -> None:
        """Send a motion command once the status replies of earlier requests are in and
        dropped, with any motion end of an earlier motion, so that the wait that follows sees
        only this motion's."""
        self._check_open()
        self._settle(MSG["MOT_GET_DCSTATUSUPDATE"])
        self._drop(_MOTION_ENDS)
        self._motion_unconfirmed = True  # until a status shows the motor stopped
        self._send(msg_id, param1, data=data)

    def _take(self, msg_ids: Sequence[int]) -> Optional[AptMessage]:
        for i, msg in enumerate(self._pending):
            if msg.msg_id in msg_ids:
                return self._pending.pop(i)
        return None

    def _await(self, msg_ids: Sequence[int], timeout: float) -> Optional[AptMessage]:
        deadline = time.monotonic() + timeout
        while True:
            msg = self._take(msg_ids)
            if msg is not None or time.monotonic() >= deadline:
                return msg
            self._read_some()

    def _resync(self) -> None:
        """After a reply timeout: drop the bytes of any message cut short, so that the next
        reply is framed from its own header (its bytes would otherwise complete the cut one
        and decode as a valid message with a made-up position)."""
        while self._serial.in_waiting:
            self._read_some()
        self._decoder.discard_partial()

    def _query(self, request: int, reply: int, param1: int = 0,
               check: Optional[Callable[[AptMessage], Optional[str]]] = None) -> AptMessage:
        """Send ``request`` and wait for ``reply``; a lost or garbled reply is asked for again
        ``retries`` times, then :class:`StageTimeoutError`. ``check`` returns why a decoded
        reply cannot be right (None when it can): such a reply is asked for again too, and
        when every try gives one, :class:`StageProtocolError` says what came."""
        with self._lock:
            self._check_open()
            self._settle(reply)   # replies to earlier requests would be taken for this one's
            problem = None
            for _attempt in range(self.retries + 1):
                self._send(request, param1)
                msg = self._await([reply], self.reply_timeout)
                if msg is None:
                    self._resync()
                    continue
                problem = None if check is None else check(msg)
                if problem is None:
                    return msg
                self._resync()
            if problem is not None:
                raise self._lost_contact(StageProtocolError(
                    f"the APT controller on {self.port} answered {MSG_NAME[request]} with "
                    f"{problem} ({self.retries + 1} tries): a garbled line; check the cable, "
                    f"and that no other program talks to the controller"))
            raise self._lost_contact(StageTimeoutError(
                f"no valid {MSG_NAME[reply]} reply to {MSG_NAME[request]} on {self.port} "
                f"within reply_timeout = {self.reply_timeout:g} s ({self.retries + 1} tries); "
                f"check the cable and that the controller is powered (a slow controller: "
                f"raise reply_timeout)"))

    # -- queries ---------------------------------------------------------------------------
    def _implausible(self, st: AptStatus) -> Optional[str]:
        """Why a decoded status cannot be this stage's (None when it can): another channel, or
        a position far outside the travel. APT has no checksum, so this is the only guard
        against a mis-framed reply. Before homing the count is relative to wherever the
        controller powered up, so a real position can lie up to one travel outside
        ``limits``: the window is the limits widened by their span (at least 100 mm), and
        never beyond a bench stage's travel."""
        if st.channel != self.channel:
            return f"a status of channel {st.channel} (this stage is channel {self.channel})"
        low, high = self._limits
        margin = max(high - low, 100.0)
        mm = st.position / self.counts_per_mm
        if not (max(low - margin, -2 * TRAVEL_MM) <= mm <= min(high + margin, 2 * TRAVEL_MM)):
            return (f"a position of {mm:.4f} mm ({st.position} counts), far outside the travel "
                    f"[{low:g}, {high:g}] mm")
        return None

    def status(self) -> AptStatus:
        """The controller's DC status (position in counts, status bits).

        Raises
        ------
        StageProtocolError
            Every try gave a status that cannot be this stage's (another channel, a position
            far outside the travel: a garbled line).
        StageTimeoutError
            No reply within ``reply_timeout`` on any try.
        """
        msg = self._query(MSG["MOT_REQ_DCSTATUSUPDATE"], MSG["MOT_GET_DCSTATUSUPDATE"],
                          self.channel,
                          check=lambda m: self._implausible(unpack_status(m.data)))
        st = unpack_status(msg.data)
        if not st.moving:
            self._motion_unconfirmed = False  # the motor is seen stopped
        return st

    def position(self) -> float:
        return self.status().position / self.counts_per_mm

    def is_moving(self) -> bool:
        with self._lock:
            moving = self.status().moving
            if not moving:
                # the motion has ended: its MOVE_COMPLETED / MOVE_HOMED (read before this
                # status) belongs to no later command
                self._pending = [m for m in self._pending if m.msg_id not in _MOTION_ENDS]
            return moving

    # -- motion ----------------------------------------------------------------------------
    def _counts(self, mm: float) -> int:
        return int(round(mm * self.counts_per_mm))

    def stop(self) -> None:
        """Profiled stop; waits (briefly) for MOVE_STOPPED and ignores its absence."""
        with self._lock:
            # no wait before a stop (not even for owed replies): only what was read is dropped
            self._check_open()
            self._drop([MSG["MOT_MOVE_STOPPED"]])
            self._send(MSG["MOT_MOVE_STOP"], self.channel, 0x02)
            self._await([MSG["MOT_MOVE_STOPPED"]], self.reply_timeout)

    def _stop_blind(self) -> None:
        """MOVE_STOP written without waiting for MOVE_STOPPED (a controller that stopped
        answering will not send it); any error is ignored."""
        try:
            self._serial.write(encode(MSG["MOT_MOVE_STOP"], self.channel, 0x02))
            self._serial.flush()
            self.log.append((time.monotonic(), "MOT_MOVE_STOP"))
        except (OSError, ValueError):
            pass  # a port that is gone: nothing more can be sent

    def _wait_motion(self, done_ids: Sequence[int], *, timeout: float, what: str,
                     direction: int, target: Optional[int], homing: bool) -> None:
        """Wait for one of ``done_ids`` while sending keep-alives and polling the status for
        limit switches; stop the stage before raising.

        A ``done_ids`` message ends the wait only once a status reply (asked after the motion
        command) says the motor no longer moves: these messages do not name their command,
        and one from an earlier motion can still arrive after this motion's command was sent.

        A move (``target`` given) that ends farther than ``tolerance_mm`` from its target
        raises :class:`StagePositionError` (the controller ends a move at the end of its
        travel with MOVE_COMPLETED). No valid status for ``retries + 1`` reply timeouts
        raises :class:`StageTimeoutError` saying the controller stopped answering (the stop
        goes out blind), not the motion's own timeout much later.
        """
        error = HomingTimeoutError if homing else StageTimeoutError
        start = time.monotonic()
        deadline = start + timeout
        next_poll = 0.0
        ended = False    # a done_ids message came: confirm with the next status
        last_status = start   # when a valid status last came
        # a status is asked every poll: retries + 1 requests in a row unanswered (each given
        # its reply_timeout) is a controller that stopped answering, not a slow motion
        silent_limit = ((self.retries + 1) * max(self.poll, self.reply_timeout)
                        + self.reply_timeout)
        bad: Optional[str] = None   # why the last status could not be right
        with self._lock:
            while True:
                now = time.monotonic()
                if now - last_status > silent_limit:
                    self._stop_blind()
                    if bad is not None:
                        raise StageProtocolError(
                            f"{what}: the APT controller on {self.port} answered status "
                            f"requests with {bad} for {now - last_status:.1f} s: a garbled "
                            f"line; the stop command was sent (no reply awaited); check the "
                            f"cable, and that no other program talks to the controller")
                    raise StageTimeoutError(
                        f"{what}: the APT controller on {self.port} stopped answering status "
                        f"requests (none answered for {now - last_status:.1f} s: "
                        f"{self.retries + 1} tries, reply_timeout = {self.reply_timeout:g} s)"
                        f"; the stop command was sent (no reply awaited); check the cable and "
                        f"that the controller is powered (a slow controller: raise "
                        f"reply_timeout)")
                if now - self._last_ack >= self.keepalive:
                    self._send(MSG["MOT_ACK_DCSTATUSUPDATE"])
                    self._last_ack = now
                if self._take(done_ids) is not None:
                    ended, next_poll = True, now    # ask the status now
                if now >= next_poll:
                    next_poll = now + self.poll
                    self._send(MSG["MOT_REQ_DCSTATUSUPDATE"], self.channel)
                reply = self._await([MSG["MOT_GET_DCSTATUSUPDATE"]] + list(done_ids),
                                    min(self.poll, max(0.0, deadline - now)))
                if reply is not None and reply.msg_id in done_ids:
                    ended, next_poll = True, 0.0
                    continue
                if reply is not None:
                    st = unpack_status(reply.data)
                    bad = self._implausible(st)
                    if bad is not None:
                        self._resync()   # a mis-framed reply: frame the next one afresh
                        continue
                    last_status = time.monotonic()
                    if not st.moving:
                        self._motion_unconfirmed = False
                    if ended and not st.moving:
                        self._check_arrival(st, target, what)
                        return
                    hit = ((direction > 0 and st.bits & STATUS["FORWARD_LIMIT"])
                           or (direction < 0 and st.bits & STATUS["REVERSE_LIMIT"]))
                    if hit and not homing:
                        self.stop()
                        raise StageLimitError(
                            f"{what}: the stage hit its {'forward' if direction > 0 else 'reverse'}"
                            f" limit switch at {st.position / self.counts_per_mm:.4f} mm")
                    if st.bits & STATUS["MOTION_ERROR"]:
                        self.stop()
                        raise StageLimitError(f"{what}: the controller reports a motion error "
                                              f"(position error too large)")
                    # A lost MOVE_COMPLETED must not hang the bench: a stopped motor at the
                    # target (or homed, for a home) is a finished move.
                    if not st.moving and (
                            (homing and st.homed)
                            or (target is not None and abs(st.position - target) <= 2)):
                        return
                if time.monotonic() >= deadline:
                    self.stop()
                    raise error(f"{what} did not finish within {timeout:g} s; the stage was "
                                f"told to stop")

    def _check_arrival(self, st: AptStatus, target: Optional[int], what: str) -> None:
        """Raise :class:`StagePositionError` when a finished move stopped farther than
        ``tolerance_mm`` from its target (None: homing, nothing to compare)."""
        if target is None:
            return
        off = (st.position - target) / self.counts_per_mm
        if abs(off) > self.tolerance_mm:
            raise StagePositionError(
                f"{what} ended at {st.position / self.counts_per_mm:.4f} mm, {off:+.4f} mm from "
                f"the target (tolerance_mm = {self.tolerance_mm:g}): the stage stopped at the "
                f"end of its travel? Check that limits are within what the stage travels")

    def home(self, *, timeout: float = 60.0) -> None:
        timeout = check_wait("timeout", timeout)
        with self._lock:
            self._start_motion(MSG["MOT_MOVE_HOME"], self.channel)
            self._wait_motion([MSG["MOT_MOVE_HOMED"]], timeout=timeout, what="homing",
                              direction=-1, target=None, homing=True)

    def move_to(self, position_mm: float, *, wait: bool = True, timeout: float = 30.0) -> None:
        target_mm = self._check_target(position_mm)
        timeout = check_wait("timeout", timeout)
        with self._lock:
            st = self.status()
            self._require_homed(st)
            target = self._counts(target_mm)
            self._start_motion(MSG["MOT_MOVE_ABSOLUTE"], data=pack_move(self.channel, target))
            if wait:
                self._wait_motion([MSG["MOT_MOVE_COMPLETED"]], timeout=timeout,
                                  what=f"move to {target_mm:g} mm",
                                  direction=1 if target > st.position else -1, target=target,
                                  homing=False)

    def _require_homed(self, st: AptStatus) -> None:
        if self.require_homed and not st.homed:
            raise StageNotReferencedError(
                "the APT controller has not been homed since power-up: call home() first "
                "(or open the stage with require_homed=False)")

    def _move_relative(self, distance_mm: float, *, wait: bool, timeout: float) -> None:
        with self._lock:
            st = self.status()
            # before homing the count is relative to wherever the controller powered up, and
            # the limits check on it meant nothing: refused as move_to is
            self._require_homed(st)
            counts = self._counts(distance_mm)
            self._start_motion(MSG["MOT_MOVE_RELATIVE"], data=pack_move(self.channel, counts))
            if wait:
                self._wait_motion([MSG["MOT_MOVE_COMPLETED"]], timeout=timeout,
                                  what=f"move by {distance_mm:g} mm",
                                  direction=1 if counts > 0 else -1,
                                  target=st.position + counts, homing=False)

    def close(self) -> None:
        """Stop the motor if it moves and release the port; closing twice is harmless."""
        if not self._serial.is_open:
            return
        try:
            if self.is_moving():
                self.stop()
        except (StageError, OSError):
            # the controller did not answer: its motor may still run, so the stop goes out
            # blind; closing does not raise (it runs on the way out of a fault or a Ctrl-C)
            self._stop_blind()
        finally:
            self._serial.close()
