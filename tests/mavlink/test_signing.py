"""Signing: setpoints and commands must be signed; only HEARTBEAT and RADIO_STATUS pass unsigned;\nour timestamps follow the wall clock and survive a restart; a refused packet says why; key files."""

from __future__ import annotations

import stat
import struct

import pytest

from m4.mavlink import mavlink, new_mav, signing
from m4.mavlink.signing import SigningCounters, load_key, setup_signing
from m4.toml_fields import ConfigError
from tests.support.packets import PacketSink, packed

KEY = bytes(range(32))



def _setpoint():
    return mavlink.MAVLink_m4_setpoint_message(1, 1, 0, 20, [1.0] * 4, [0.7] * 4, [0.0] * 4, 0)


def _heartbeat():
    return mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_ONBOARD_CONTROLLER, mavlink.MAV_AUTOPILOT_INVALID,
                                             0, 0, 0, 3)


def _packets(key, *msgs):
    return packed(msgs, 1, 191, key)


def _receiver():
    mav = new_mav(None, 1, 1)
    setup_signing(mav, KEY)
    return mav


def _types(mav, packets):
    return [m.get_type() for p in packets for m in mav.parse_buffer(p) or ()]


def test_signed_setpoint_is_accepted():
    rx = _receiver()
    assert _types(rx, _packets(KEY, _setpoint())) == ["M4_SETPOINT"]
    assert SigningCounters.of(rx).signed_ok == 1


def test_unsigned_setpoint_and_command_are_dropped_and_counted():
    rx = _receiver()
    command = mavlink.MAVLink_command_long_message(1, 1, mavlink.MAV_CMD_INJECT_FAILURE, 0, 101, 1, 4, 0, 0, 0, 0)
    assert _types(rx, _packets(None, _setpoint(), command)) == ["BAD_DATA", "BAD_DATA"]
    assert SigningCounters.of(rx).rejected == 2


def test_setpoint_signed_with_another_key_is_dropped():
    rx = _receiver()
    assert _types(rx, _packets(bytes(32), _setpoint())) == ["BAD_DATA"]
    counters = SigningCounters.of(rx)
    assert counters.bad_signature == 1 and counters.rejected == 1


def test_replayed_signed_setpoint_is_dropped():
    rx = _receiver()
    (packet,) = _packets(KEY, _setpoint())
    assert _types(rx, [packet, packet]) == ["M4_SETPOINT", "BAD_DATA"]


def test_a_forged_packet_with_a_far_future_timestamp_does_not_lock_the_stream_out():
    """A genuine packet with its timestamp pushed to the latest there can be (the signature no
    longer matches), then the genuine packets of that stream: they still count."""
    rx = _receiver()
    first, second = _packets(KEY, _setpoint(), _setpoint())
    forged = bytearray(first)
    forged[-12:-6] = struct.pack("<IH", 0xFFFFFFFF, 0xFFFF)
    assert _types(rx, [bytes(forged), first, second]) == ["BAD_DATA", "M4_SETPOINT", "M4_SETPOINT"]
    counters = SigningCounters.of(rx)
    assert (counters.bad_signature, counters.signed_ok) == (1, 2)
    assert _types(rx, [first]) == ["BAD_DATA"]                  # and a replay is still refused


def test_unsigned_heartbeat_passes():
    rx = _receiver()
    assert _types(rx, _packets(None, _heartbeat())) == ["HEARTBEAT"]
    assert SigningCounters.of(rx).unsigned_allowed == 1


def test_key_file_hex_or_raw(tmp_path):
    hex_file, raw_file = tmp_path / "key.hex", tmp_path / "key.bin"
    hex_file.write_text(KEY.hex() + "\n")
    raw_file.write_bytes(KEY)
    assert load_key(hex_file) == KEY == load_key(raw_file)


@pytest.mark.parametrize("content", [b"abcd", bytes(31), b"zz" * 32])
def test_bad_key_file_names_the_problem(tmp_path, content):
    path = tmp_path / "key"
    path.write_bytes(content)
    with pytest.raises(ConfigError, match="32 bytes"):
        load_key(path)


def test_missing_key_file_is_a_config_error(tmp_path):
    with pytest.raises(ConfigError, match="cannot read"):
        load_key(tmp_path / "nope")


def test_a_peer_with_the_wrong_key_does_not_flood_the_log(caplog):
    packets = _packets(bytes(32), *[_setpoint()] * 500)       # signed with another key
    with caplog.at_level("INFO"):
        assert _types(_receiver(), packets) == ["BAD_DATA"] * 500
    assert 1 <= len(caplog.records) <= 2


def _timestamp(packet: bytes) -> int:
    low, high = struct.unpack("<IH", packet[-12:-6])
    return low + (high << 32)


def test_our_timestamps_follow_the_wall_clock_not_only_the_packet_count(monkeypatch):
    """A peer that kept our stream's timestamps across its restart (one wall-clock second
    ahead) must take our packets once that second has passed, not after 100,000 packets."""
    sink = PacketSink()
    tx = new_mav(sink, 1, 191)
    setup_signing(tx, KEY)
    later = signing._wall_timestamp() + 60 * 100_000            # a minute on
    monkeypatch.setattr(signing, "_wall_timestamp", lambda: later)
    tx.send(_heartbeat())
    assert _timestamp(sink.packets[-1]) >= later


def test_our_own_timestamp_survives_a_restart_whose_clock_is_behind(tmp_path, monkeypatch):
    """A computer without a real-time clock boots in the past: what we signed before the
    restart must not be signed again after it (the peer would take it for a replay)."""
    sink = PacketSink()
    before = new_mav(sink, 1, 191)
    setup_signing(before, KEY)
    state = signing.StreamTimestamps([before], tmp_path / "ts")
    before.send(_heartbeat())
    state.save()
    last = _timestamp(sink.packets[-1])
    monkeypatch.setattr(signing, "_wall_timestamp", lambda: last - 3600 * 100_000)    # an hour behind
    after = new_mav(sink, 1, 191)
    setup_signing(after, KEY)
    signing.StreamTimestamps([after], tmp_path / "ts")
    after.send(_heartbeat())
    assert _timestamp(sink.packets[-1]) > last


def _signed_at(timestamp: int, system: int) -> bytes:
    """A setpoint signed with KEY by `system` at `timestamp` (pymavlink's own signing: no wall
    clock)."""
    sink = PacketSink()
    tx = new_mav(sink, system, 191)
    tx.signing.secret_key, tx.signing.sign_outgoing, tx.signing.timestamp = KEY, True, timestamp
    tx.send(_setpoint())
    return sink.packets[0]


def _ours_and_pymavlinks():
    """Two receivers with our signing state: one with our check, one with pymavlink's own
    (MAVLink.check_signature: the same verdicts on good signatures, our timestamp set through
    the getter)."""
    ours, theirs = _receiver(), _receiver()
    del theirs.check_signature
    return ours, theirs


def _judged_alike(ours, theirs, packet: bytes) -> str:
    """The type both make of `packet`, once their signing states are seen to agree."""
    got, expected = _types(ours, [packet]), _types(theirs, [packet])
    assert got == expected
    assert (ours.signing.timestamp, ours.signing.stream_timestamps) == \
        (theirs.signing.timestamp, theirs.signing.stream_timestamps)
    return got[0]


def test_a_clock_stepped_back_leaves_the_new_stream_window_where_pymavlinks_check_leaves_it(monkeypatch):
    """A receive-only link accepts a peer 50 s behind our clock, then the clock steps back an
    hour (NTP, a board without a real-time clock): a new stream 100 s behind where the clock
    was is still refused, as pymavlink's own check refuses it."""
    now = signing._wall_timestamp()
    clock = [now]
    monkeypatch.setattr(signing, "_wall_timestamp", lambda: clock[0])
    ours, theirs = _ours_and_pymavlinks()
    assert _judged_alike(ours, theirs, _signed_at(now - 50 * 100_000, system=1)) == "M4_SETPOINT"
    clock[0] = now - 3600 * 100_000
    assert _judged_alike(ours, theirs, _signed_at(now - 100 * 100_000, system=2)) == "BAD_DATA"


def test_a_packet_far_ahead_of_the_clock_raises_our_timestamp_and_refuses_a_new_stream_behind_it(monkeypatch):
    """A good packet an hour ahead of our clock is a new stream we accept; our own timestamp
    rises to it, and a new stream at the clock's time (an hour behind it) is then refused, as
    pymavlink's own check refuses it."""
    now = signing._wall_timestamp()
    monkeypatch.setattr(signing, "_wall_timestamp", lambda: now)
    ours, theirs = _ours_and_pymavlinks()
    assert _judged_alike(ours, theirs, _signed_at(now + 3600 * 100_000, system=1)) == "M4_SETPOINT"
    assert _judged_alike(ours, theirs, _signed_at(now, system=2)) == "BAD_DATA"


@pytest.mark.parametrize("key, tamper, reason", [
    (None, False, "unsigned"), (bytes(32), False, "bad signature"), (KEY, False, "replayed"), (KEY, True, "bad signature"),
], ids=["unsigned", "another key", "replayed", "tampered"])
def test_a_refused_packet_says_why(key, tamper, reason):
    (packet,) = _packets(key, _setpoint())
    if tamper:
        packet = packet[:-1] + bytes([packet[-1] ^ 1])
    rx = _receiver()
    if reason == "replayed":
        _types(rx, [packet])
    assert _types(rx, [packet]) == ["BAD_DATA"]
    assert signing.refusal(KEY, packet) == reason


def test_a_new_key_file_is_random_and_for_its_owner_only(tmp_path):
    first, second = tmp_path / "a.key", tmp_path / "b.key"
    key = signing.write_new_key(first)
    assert load_key(first) == key != signing.write_new_key(second)
    assert stat.S_IMODE(first.stat().st_mode) == 0o600


def test_a_key_from_a_passphrase_is_the_one_mavproxy_sets_on_the_fc(tmp_path):
    """MAVProxy's `signing setup PASSPHRASE` sends the passphrase's SHA-256 (its passphrase_to_key)."""
    key = signing.write_new_key(tmp_path / "m.key", passphrase="abc")
    assert key.hex() == "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"


def test_a_key_file_is_never_overwritten(tmp_path):
    path = tmp_path / "m.key"
    key = signing.write_new_key(path)
    with pytest.raises(ConfigError, match="cannot create"):
        signing.write_new_key(path)
    assert load_key(path) == key
