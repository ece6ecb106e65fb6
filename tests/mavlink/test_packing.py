"""The fast packer: the very frames, message state and protocol state pymavlink's _pack leaves."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from m4.mavlink import mavlink, new_mav
from m4.mavlink.packing import PYMAVLINK_PACK, fast_pack
from m4.mavlink.signing import setup_signing
from tests.support.packets import PacketSink

KEY = bytes(range(32))
_floats = st.floats(width=32)
_messages = st.one_of(
    st.builds(mavlink.MAVLink_attitude_message, st.integers(0, 2**32 - 1), _floats, _floats, _floats, _floats,
              _floats, _floats),
    st.builds(mavlink.MAVLink_m4_joint_state_message, st.integers(0, 2**32 - 1),
              st.lists(_floats, min_size=4, max_size=4), st.lists(_floats, min_size=4, max_size=4)),
    st.builds(mavlink.MAVLink_statustext_message, st.integers(0, 7),
              st.binary(max_size=50).map(lambda b: b.rstrip(b"\0"))),
    st.builds(mavlink.MAVLink_heartbeat_message, st.integers(0, 20), st.integers(0, 20), st.integers(0, 255),
              st.integers(0, 2**32 - 1), st.integers(0, 8), st.just(3)),
)


def _sent(pack, msgs, key, seq, timestamp):
    """The frames, message states and protocol state after sending `msgs` with _pack = `pack`."""
    sink = PacketSink()
    mav = new_mav(sink, 1, 1)
    mav.seq = seq
    if key is not None:
        setup_signing(mav, key, link_id=3)
        mav.signing.timestamp = timestamp           # far ahead of the wall clock: the same for both
    saved, mavlink.MAVLink_message._pack = mavlink.MAVLink_message._pack, pack
    try:
        for msg in msgs:
            mav.send(msg)
    finally:
        mavlink.MAVLink_message._pack = saved
    states = [(vars(m.get_header()), m.get_payload(), m.get_crc(), m.get_msgbuf()) for m in msgs]
    return sink.packets, states, (mav.seq, mav.total_packets_sent, mav.total_bytes_sent, mav.signing.timestamp)


@given(st.lists(_messages, min_size=1, max_size=6), st.sampled_from([None, KEY]), st.integers(0, 255),
       st.integers(2**47, 2**48))
def test_frames_are_packed_and_signed_as_pymavlink_does(msgs, key, seq, timestamp):
    ours = _sent(fast_pack, msgs, key, seq, timestamp)
    assert ours == _sent(PYMAVLINK_PACK, msgs, key, seq, timestamp)


def test_the_dialect_packs_with_the_fast_packer():
    assert mavlink.MAVLink_message._pack is fast_pack
