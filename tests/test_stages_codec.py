"""Byte-level codec tests for the APT and CONEX protocols.

Every expected byte string is worked out by hand from the protocol documents (Thorlabs "APT
Communications Protocol": 6-byte header = message id u16 little-endian, then param1, param2 or
a u16 data length, then destination (| 0x80 when data follows) and source; host = 0x01, generic
USB unit = 0x50. Newport CONEX-AGP: ``<address><command>[value]\\r\\n``), not produced by the
code under test.
"""

import struct

import pytest

from clholo.tools.stages import apt, conex
from clholo.tools.stages.base import StageProtocolError


@pytest.mark.parametrize("args, expected", [
    # 0x0018 -> 18 00; params 00 00; dest 50; source 01
    (("HW_NO_FLASH_PROGRAMMING",), b"\x18\x00\x00\x00\x50\x01"),
    # 0x0005 -> 05 00
    (("HW_REQ_INFO",), b"\x05\x00\x00\x00\x50\x01"),
    # 0x0210 -> 10 02; param1 = channel 1, param2 = 0x01 (enable)
    (("MOD_SET_CHANENABLESTATE", 1, 1), b"\x10\x02\x01\x01\x50\x01"),
    # 0x0443 -> 43 04; param1 = channel 1
    (("MOT_MOVE_HOME", 1), b"\x43\x04\x01\x00\x50\x01"),
    # 0x0465 -> 65 04; channel 1, stop mode 0x02 (profiled)
    (("MOT_MOVE_STOP", 1, 2), b"\x65\x04\x01\x02\x50\x01"),
    # 0x0490 -> 90 04; channel 1
    (("MOT_REQ_DCSTATUSUPDATE", 1), b"\x90\x04\x01\x00\x50\x01"),
    # 0x0492 -> 92 04; no parameters
    (("MOT_ACK_DCSTATUSUPDATE",), b"\x92\x04\x00\x00\x50\x01"),
])
def test_apt_header_only_messages(args, expected):
    name, *params = args
    assert apt.encode(apt.MSG[name], *params) == expected


def test_apt_absolute_move_with_data():
    # 10 mm x 34554.96 counts/mm = 345549.6 -> 345550 = 0x000545CE -> CE 45 05 00.
    # Header: 53 04 (0x0453), length 06 00, dest 0x50 | 0x80 = D0, source 01; data: chan 01 00.
    counts = int(round(10 * apt.COUNTS_PER_MM_Z8))
    got = apt.encode(apt.MSG["MOT_MOVE_ABSOLUTE"], data=apt.pack_move(1, counts))
    assert got == b"\x53\x04\x06\x00\xD0\x01" + b"\x01\x00" + b"\xCE\x45\x05\x00"


def test_apt_relative_move_negative():
    # -1 mm x 34304 (older document) = -34304 = -0x8600 -> two's complement 0xFFFF7A00
    # -> 00 7A FF FF. Header 48 04 06 00 D0 01.
    got = apt.encode(apt.MSG["MOT_MOVE_RELATIVE"],
                     data=apt.pack_move(1, int(-1 * apt.COUNTS_PER_MM_Z8_OLD)))
    assert got == b"\x48\x04\x06\x00\xD0\x01\x01\x00\x00\x7A\xFF\xFF"


# A controller's status reply: header 91 04, length 0E 00 (14), dest 0x01 | 0x80 = 81, source 50;
# data: chan 01 00; position 100000 = 0x000186A0 -> A0 86 01 00; velocity 00 00; reserved 00 00;
# status 0x80000400 (ENABLED | HOMED) -> 00 04 00 80.
STATUS_REPLY = (b"\x91\x04\x0E\x00\x81\x50" + b"\x01\x00" + b"\xA0\x86\x01\x00" + b"\x00\x00"
                + b"\x00\x00" + b"\x00\x04\x00\x80")
# MOVE_HOMED from the controller: 44 04, channel 01, 00, dest 01, source 50.
HOMED_REPLY = b"\x44\x04\x01\x00\x01\x50"


def test_apt_decode_status_and_homed():
    msgs = apt.AptDecoder().feed(STATUS_REPLY + HOMED_REPLY)
    assert [m.msg_id for m in msgs] == [0x0491, 0x0444]
    st = apt.unpack_status(msgs[0].data)
    assert (st.channel, st.position, st.bits) == (1, 100000, 0x80000400)
    assert st.homed and not st.moving
    assert msgs[1].param1 == 1 and msgs[1].data is None
    # and the encoder reproduces the controller's bytes
    assert apt.encode(0x0491, data=apt.pack_status(1, 100000, 0, 0x80000400), dest=apt.HOST,
                      source=apt.USB_UNIT) == STATUS_REPLY


def test_apt_decoder_resynchronises_on_garbage_byte_by_byte():
    # garbage, a header-looking fragment with a wrong destination (0x50 instead of 0x01/0x81),
    # a status header whose length is wrong (0x0D), then two valid messages
    garbage = b"\x00\xFF\x91" + b"\x44\x04\x01\x00\x50\x50" + b"\x91\x04\x0D\x00\x81\x50"
    stream = garbage + STATUS_REPLY + HOMED_REPLY
    dec = apt.AptDecoder()
    msgs = []
    for i in range(len(stream)):
        msgs += dec.feed(stream[i:i + 1])
    assert [m.msg_id for m in msgs] == [0x0491, 0x0444]
    assert apt.unpack_status(msgs[0].data).position == 100000
    assert dec.discarded == len(garbage)


def test_apt_info_layout():
    # 84 bytes: serial u32 (4) + model (8) + type (2) + firmware (4) + notes (48) + empty (12)
    # + hw version (2) + mod state (2) + channels (2)
    data = apt.pack_info(83000123, "KDC101", firmware=(3, 1, 7), notes="hello", channels=1)
    assert len(data) == 4 + 8 + 2 + 4 + 48 + 12 + 2 + 2 + 2 == 84
    assert data[:4] == struct.pack("<I", 83000123) and data[4:12] == b"KDC101\0\0"
    assert data[14:18] == bytes([7, 1, 3, 0])   # minor, interim, major, unused
    info = apt.unpack_info(data)
    assert (info.serial, info.model, info.firmware, info.notes, info.channels) == (
        83000123, "KDC101", (3, 1, 7), "hello", 1)
    with pytest.raises(StageProtocolError, match="84 bytes"):
        apt.unpack_info(data[:-1])


@pytest.mark.parametrize("address, command, value, expected", [
    (1, "OR", None, b"1OR\r\n"),
    (1, "PA", 5.25, b"1PA5.25\r\n"),
    (1, "PR", -0.5, b"1PR-0.5\r\n"),
    (2, "TP", None, b"2TP\r\n"),
    (1, "TS", None, b"1TS\r\n"),
])
def test_conex_command_bytes(address, command, value, expected):
    assert conex.format_command(address, command, value) == expected


def test_conex_ts_parse():
    # "1TS000033": flags 0x0000, state 33 (READY from MOVING); "1TS00020A": flags 0x0002
    # (positive end of run), state 0A (NOT REFERENCED from RESET)
    assert conex.parse_ts("000033") == (0, "33")
    assert conex.parse_ts("00020A") == (2, "0A")
    for bad in ("00033", "00G033", ""):
        with pytest.raises(StageProtocolError):
            conex.parse_ts(bad)
