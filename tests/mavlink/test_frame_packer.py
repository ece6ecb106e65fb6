"""The fast frame packer: the very bytes pymavlink packs, which pymavlink parses back."""

from __future__ import annotations

import subprocess
import sys

import pytest
from hypothesis import given
from hypothesis import strategies as st

from m4.mavlink import COMPANION_COMPONENT_ID, FC_SYSTEM_ID, mavlink, new_mav
from m4.mavlink.frame_packer import FramePacker, x25_crc
from tests.support.packets import PacketSink



@given(st.binary(max_size=300), st.integers(0, 0xFFFF))
def test_the_checksum_is_mavlinks(data, crc):
    slow = mavlink._x25crc_slow()              # pymavlink's own, byte by byte
    slow.crc = crc
    slow.accumulate(data)
    assert x25_crc(data, crc) == slow.crc
    assert x25_crc(data) == mavlink._x25crc_slow(data).crc


def test_the_dialect_checks_crcs_in_c_with_fastcrc_where_pymavlink_has_it():
    fastcrc = pytest.importorskip("fastcrc")
    assert mavlink.x25crc is mavlink._x25crc_fast and mavlink.mcrf4xx is fastcrc.crc16.mcrf4xx


def test_without_fastcrc_the_dialect_checks_crcs_with_binascii():
    probe = ("import sys; sys.modules['fastcrc'] = None\n"          # as if pymavlink had found no fastcrc
             "from m4.mavlink import mavlink\n"
             "from m4.mavlink.frame_packer import x25_crc\n"
             "assert mavlink.mcrf4xx is x25_crc and mavlink.x25crc is mavlink._x25crc_fast\n"
             "assert mavlink.x25crc(b'123456789').crc == 0x6F91\n")    # CRC-16/MCRF4XX's check value
    subprocess.run([sys.executable, "-c", probe], check=True, timeout=60)


@given(st.integers(0, 2**32 - 1), st.floats(width=32, allow_nan=False),
       st.binary(max_size=10).map(lambda b: b.rstrip(b"\0")), st.integers(0, 1000))
def test_named_value_floats_are_packed_as_pymavlink_packs_them(time_ms, value, name, seq):
    sink = PacketSink()
    mav = new_mav(sink, FC_SYSTEM_ID, COMPANION_COMPONENT_ID)
    mav.seq = seq % 256
    mav.named_value_float_send(time_ms, name, value)
    frame = FramePacker(mavlink.MAVLink_named_value_float_message, FC_SYSTEM_ID, COMPANION_COMPONENT_ID).pack(
        seq, time_ms, value, name)
    assert frame == sink.packets[0]
    msg = new_mav(None, 1, 1).parse_char(frame)
    assert msg.get_type() == "NAMED_VALUE_FLOAT" and msg.time_boot_ms == time_ms
