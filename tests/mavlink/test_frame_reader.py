"""The datagram reader: the very message objects, and counters, that pymavlink's parser gives."""

from __future__ import annotations

import math

from hypothesis import given
from hypothesis import strategies as st

from m4.mavlink import mavlink, new_mav
from m4.mavlink.frame_reader import read_datagram
from m4.mavlink.signing import setup_signing
from tests.support.packets import packed

KEY = bytes(range(32))
_floats = st.floats(width=32)
_four = st.lists(_floats, min_size=4, max_size=4)



_messages = st.one_of(
    st.builds(mavlink.MAVLink_attitude_message, st.integers(0, 2**32 - 1), _floats, _floats, _floats, _floats,
              _floats, _floats),
    st.builds(mavlink.MAVLink_m4_thruster_status_message, st.integers(0, 2**32 - 1), _four, _four),
    st.builds(mavlink.MAVLink_esc_telemetry_1_to_4_message, st.lists(st.integers(0, 255), min_size=4, max_size=4),
              st.lists(st.integers(0, 65535), min_size=4, max_size=4),
              st.lists(st.integers(0, 65535), min_size=4, max_size=4),
              st.lists(st.integers(0, 65535), min_size=4, max_size=4),
              st.lists(st.integers(0, 65535), min_size=4, max_size=4),
              st.lists(st.integers(0, 65535), min_size=4, max_size=4)),
    st.builds(mavlink.MAVLink_statustext_message, st.integers(0, 7),
              st.binary(max_size=50).map(lambda b: b.rstrip(b"\0"))),
    st.builds(mavlink.MAVLink_heartbeat_message, st.integers(0, 20), st.integers(0, 20), st.integers(0, 255),
              st.integers(0, 2**32 - 1), st.integers(0, 8), st.just(3)),
)


def _datagram(msgs, key=None, link_id=0) -> bytes:
    return b"".join(packed(msgs, key=key, link_id=link_id))


def _same_value(a, b) -> bool:
    if isinstance(a, float) and isinstance(b, float):
        return a == b or math.isnan(a) and math.isnan(b)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(map(_same_value, a, b))
    return type(a) is type(b) and a == b


def _same(a, b) -> bool:
    fields_a = {k: v for k, v in vars(a).items() if k != "_header"}
    fields_b = {k: v for k, v in vars(b).items() if k != "_header"}
    return (type(a) is type(b) and fields_a.keys() == fields_b.keys()
            and all(_same_value(v, fields_b[k]) for k, v in fields_a.items())
            and vars(a.get_header()) == vars(b.get_header()))


def _both(data: bytes, key=None):
    theirs, ours = new_mav(None, 1, 191), new_mav(None, 1, 191)
    if key is not None:
        setup_signing(theirs, key)
        setup_signing(ours, key)
    expected, got = theirs.parse_buffer(data) or [], read_datagram(ours, data)
    counters = ("total_packets_received", "total_bytes_received", "total_receive_errors")
    assert [getattr(ours, c) for c in counters] == [getattr(theirs, c) for c in counters]
    return expected, got


@given(st.lists(_messages, min_size=1, max_size=8))
def test_a_datagram_of_frames_reads_as_pymavlink_reads_it(msgs):
    expected, got = _both(_datagram(msgs))
    assert len(got) == len(msgs) and all(map(_same, got, expected))


@given(st.lists(_messages, min_size=1, max_size=4), st.binary(min_size=1, max_size=20), st.integers(0, 3))
def test_garbage_and_cut_frames_read_as_pymavlink_reads_them(msgs, junk, where):
    data = _datagram(msgs)
    for damaged in (junk + data, data + junk, data[:-where - 1], data[:5] + junk + data[5:]):
        expected, got = _both(damaged)
        assert [m.get_type() for m in got] == [m.get_type() for m in expected]
        assert all(map(_same, [m for m in got if m.get_type() != "BAD_DATA"],
                       [m for m in expected if m.get_type() != "BAD_DATA"]))


def test_signed_frames_are_judged_by_pymavlink():
    data = _datagram([mavlink.MAVLink_heartbeat_message(18, 8, 0, 0, 4, 3)], key=KEY)
    expected, got = _both(data, key=KEY)
    assert [m.get_type() for m in got] == ["HEARTBEAT"] and got[0].get_signed() and _same(got[0], expected[0])


def test_a_signed_frames_link_id_is_its_messages_and_keys_its_streams_timestamp():
    """Signed on link id 7: pymavlink's own decode and check give each message that link id and
    keep the stream's timestamp under (7, system, component); so does the reader."""
    data = _datagram([mavlink.MAVLink_heartbeat_message(18, 8, 0, 0, 4, 3),
                      mavlink.MAVLink_attitude_message(20, 0.1, 0.2, 0.3, 0, 0, 0)], key=KEY, link_id=7)
    theirs, ours = new_mav(None, 1, 191), new_mav(None, 1, 191)
    setup_signing(theirs, KEY)
    setup_signing(ours, KEY)
    del theirs.check_signature                  # pymavlink's own (MAVLink.check_signature)
    expected, got = theirs.parse_buffer(data), read_datagram(ours, data)
    assert [m.get_link_id() for m in got] == [7, 7] and all(map(_same, got, expected))
    assert list(ours.signing.stream_timestamps) == [(7, 1, 1)]
    assert ours.signing.stream_timestamps == theirs.signing.stream_timestamps


@given(st.lists(_messages, min_size=1, max_size=6), st.sampled_from([KEY, bytes(32)]), st.booleans())
def test_signed_datagrams_read_as_pymavlink_reads_them(msgs, sender_key, replayed):
    """Signed with the key (good), with another (refused but HEARTBEAT), or sent twice (the
    second a replay): the same messages, BAD_DATA and signing counters as pymavlink's."""
    data = _datagram(msgs, key=sender_key)
    theirs, ours = new_mav(None, 1, 191), new_mav(None, 1, 191)
    setup_signing(theirs, KEY)
    setup_signing(ours, KEY)
    for datagram in (data, data) if replayed else (data,):
        expected, got = theirs.parse_buffer(datagram) or [], read_datagram(ours, datagram)
        assert [m.get_type() for m in got] == [m.get_type() for m in expected]
        assert all(_same(a, b) if a.get_type() != "BAD_DATA" else (a.data, a.reason) == (b.data, b.reason)
                   for a, b in zip(got, expected))
    counters = ("total_packets_received", "total_bytes_received", "total_receive_errors")
    assert [getattr(ours, c) for c in counters] == [getattr(theirs, c) for c in counters]
    # our own timestamp follows the wall clock, and each holds its own SHA-256 state of the key (signing.py)
    own = ("_timestamp", "keyed")
    assert ({k: v for k, v in vars(ours.signing).items() if k not in own}
            == {k: v for k, v in vars(theirs.signing).items() if k not in own})


def test_a_signed_datagram_is_read_without_pymavlinks_parser():
    mav = new_mav(None, 1, 191)
    setup_signing(mav, KEY)
    mav.parse_buffer = None                     # the fast path never calls it
    msgs = read_datagram(mav, _datagram([mavlink.MAVLink_attitude_message(20, 0.1, 0.2, 0.3, 0, 0, 0)] * 3, key=KEY))
    assert [(m.get_type(), m.get_signed(), m.time_boot_ms) for m in msgs] == [("ATTITUDE", True, 20)] * 3


def test_a_frame_cut_by_one_datagram_is_finished_by_the_next():
    data = _datagram([mavlink.MAVLink_heartbeat_message(18, 8, 0, 0, 4, 3)] * 2)
    mav = new_mav(None, 1, 191)
    first, second = read_datagram(mav, data[:15]), read_datagram(mav, data[15:])
    assert [m.get_type() for m in first + second] == ["HEARTBEAT", "HEARTBEAT"]
