"""Authority by default (docs/authority.md): the companion signs unless its config says not to,
and then says so; a restarted companion keeps its signing timestamps and refuses what was
captured before it restarted (over real loopback sockets); a second sender claiming the flight
controller's ids is counted and reported (on a socket-free transport)."""

from __future__ import annotations

import json
import logging
import socket
import threading
import time

import pytest

from companion.app import CompanionApp, close_app, open_app
from companion.config import parse_config
from companion.controller import Controller, ControllerSettings
from companion.fc_link import FcLink
from m4.airframe import load_airframe
from m4.mavlink import FC_COMPONENT_ID, FC_SYSTEM_ID, mavlink, new_mav, signing
from m4.mavlink.signing import load_key, write_new_key
from m4.toml_fields import ConfigError
from support.fake_transport import FakeTransport
from tests.support.packets import packed

AF = load_airframe()
FC_ADDRESS = ("127.0.0.1", 9)


def _fc_frame(t_ms: int) -> list:
    """A heartbeat and a telemetry frame of a flight controller hovering at 2 m."""
    return [mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_GENERIC, 0, 0, 4, 3),
            mavlink.MAVLink_attitude_message(t_ms, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
            mavlink.MAVLink_local_position_ned_message(t_ms, 0.0, 0.0, -2.0, 0.0, 0.0, 0.0),
            mavlink.MAVLink_m4_joint_state_message(t_ms, [AF.nominal_hip_rad] * 4, [0.0] * 4),
            mavlink.MAVLink_m4_thruster_status_message(t_ms, [AF.hover_thrust_per_rotor_n] * 4,
                                                       [AF.thrust_max_n] * 4)]


def _send(sock: socket.socket, packets: list[bytes], app, until=None) -> None:
    """Send the packets to the app and poll it: until `until()` holds (at most 5 s: a busy machine),
    or for 0.3 s when nothing is awaited (what must not happen has had its chance). Polling on a
    fixed time after the awaited state would let the link-loss deadline pass and undo it."""
    for packet in packets:
        sock.sendto(packet, ("127.0.0.1", app.fc.link.local_port))
    deadline = time.monotonic() + (0.3 if until is None else 5.0)
    while time.monotonic() < deadline:
        app.poll()
        if until is not None and until():
            return
        time.sleep(0.01)


def _signed_config(tmp_path):
    write_new_key(tmp_path / "mavlink.key")
    return parse_config({"link": {"fc_url": "udpin:127.0.0.1:0", "signing_key_file": "mavlink.key"},
                         "log": {"enabled": False}}, "companion.toml", tmp_path)


def test_without_a_key_the_companion_does_not_start_unless_signing_is_turned_off():
    config = parse_config({"link": {"fc_url": "udpin:127.0.0.1:0"}, "log": {"enabled": False}}, "test")
    with pytest.raises(ConfigError, match="signing is on .*m4-companion keygen.*signing = false"):
        close_app(open_app(config))


def test_signing_turned_off_with_a_key_named_is_refused_as_ambiguous(tmp_path):
    with pytest.raises(ConfigError, match="signing = false but a signing key"):
        parse_config({"link": {"signing": False, "signing_key_file": "k"}}, "test", tmp_path)


def test_unsigned_by_choice_is_said_at_start_and_to_the_fc_at_every_lock_on(caplog):
    config = parse_config({"link": {"fc_url": "udpin:127.0.0.1:0", "signing": False}, "log": {"enabled": False}},
                          "test")
    with caplog.at_level(logging.WARNING, logger="m4-companion"):
        close_app(open_app(config))
    assert [r.getMessage() for r in caplog.records if "signing is OFF" in r.getMessage()]
    link = FakeTransport(FC_SYSTEM_ID, 191)
    app = CompanionApp(config, FcLink(link), Controller(ControllerSettings.of(config)), clock=lambda: 100.0)
    link.deliver(FC_ADDRESS, *_fc_frame(0)[:1], mav=new_mav(None, FC_SYSTEM_ID, FC_COMPONENT_ID))
    app.poll()
    texts = [(m.severity, m.text) for m in link.sent_messages() if m.get_type() == "STATUSTEXT"]
    assert texts == [(mavlink.MAV_SEVERITY_WARNING, "companion: MAVLink signing OFF")]


def test_a_restarted_companion_refuses_fc_packets_captured_before_it_restarted(tmp_path, monkeypatch):
    """The probe: a companion restarted while an attacker replays a captured signed HEARTBEAT and
    telemetry locked on to it and took its mission altitude from it. Kept timestamps refuse the
    replay; the genuine FC, signing at the time of day, is taken at once."""
    config = _signed_config(tmp_path)
    key = load_key(tmp_path / "mavlink.key")
    captured = packed(_fc_frame(5000), FC_SYSTEM_ID, FC_COMPONENT_ID, key)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as fc, \
            socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as attacker:
        first = open_app(config)
        try:
            _send(fc, captured, first, until=lambda: first.fc.locked and first.fc.connected)
            assert first.fc.locked and first.fc.connected
        finally:
            close_app(first)
        second = open_app(config)
        try:
            _send(attacker, captured, second)
            assert not second.fc.locked and second.telemetry.snapshot() is None
            assert second.fc.health().bad_signature == len(captured) - 1     # the heartbeat passes unsigned
            restart_s = 2.0                                                  # what a restart takes
            now = signing._wall_timestamp() + round(restart_s * 100_000)
            monkeypatch.setattr(signing, "_wall_timestamp", lambda: now)
            _send(fc, packed(_fc_frame(7000), FC_SYSTEM_ID, FC_COMPONENT_ID, key), second,
                  until=lambda: second.fc.locked and second.fc.connected)
            assert second.fc.locked and second.fc.connected
        finally:
            close_app(second)


# -- a second sender claiming the flight controller's ids -------------------------------------------
KEY = bytes(range(32))
STRAY = ("10.0.0.66", 14555)


def _signed_fc_mav():
    mav = new_mav(None, FC_SYSTEM_ID, FC_COMPONENT_ID)
    signing.setup_signing(mav, KEY)
    return mav


def _flowing(key=None):
    """An FcLink locked on to FC_ADDRESS with its telemetry flowing (signed with `key`)."""
    transport = FakeTransport(FC_SYSTEM_ID, 191, key=key)
    fc_link = FcLink(transport, telemetry_timeout_s=0.3)
    fc_mav = _signed_fc_mav() if key else new_mav(None, FC_SYSTEM_ID, FC_COMPONENT_ID)
    transport.deliver(FC_ADDRESS, *_fc_frame(100), mav=fc_mav)
    fc_link.receive(10.0)
    assert fc_link.locked and fc_link.connected
    return fc_link, transport, fc_mav


def _warnings(transport) -> list[str]:
    return [m.text for m in transport.sent_messages()
            if m.get_type() == "STATUSTEXT" and m.severity == mavlink.MAV_SEVERITY_WARNING]


def test_the_fc_ids_from_another_address_are_reported_once_counted_always(caplog):
    fc_link, transport, _ = _flowing()
    stray = new_mav(None, FC_SYSTEM_ID, FC_COMPONENT_ID)
    with caplog.at_level(logging.WARNING, logger="m4-companion"):
        for k in range(100):
            transport.deliver(STRAY, *_fc_frame(120 + k)[1:2], mav=stray)
            fc_link.receive(10.01)
    assert fc_link.health().second_sender == 100
    assert _warnings(transport) == ["companion: second sender as 1/1 (other address)"]
    lines = [r.getMessage() for r in caplog.records if "second sender" in r.getMessage()]
    assert len(lines) == 1 and "10.0.0.66:14555" in lines[0] and "127.0.0.1:9" in lines[0]


def test_with_signing_a_replayed_fc_packet_is_refused_and_reported_from_any_address():
    """A timestamp stream that goes backwards: a second sender (or a relay) replaying the FC."""
    fc_link, transport, fc_mav = _flowing(KEY)
    captured = _fc_frame(120)[1]
    transport.deliver(FC_ADDRESS, captured, mav=fc_mav)
    fc_link.receive(10.01)
    transport.inbox.append((bytes(captured.get_msgbuf()), FC_ADDRESS))      # the same bytes again
    assert fc_link.receive(10.02).messages == []
    assert fc_link.health().second_sender == 1 and _warnings(transport) == ["companion: second sender as 1/1 (replayed)"]


def test_with_signing_an_unsigned_heartbeat_with_the_fc_ids_is_reported():
    fc_link, transport, _ = _flowing(KEY)
    transport.deliver(FC_ADDRESS, _fc_frame(0)[0], mav=new_mav(None, FC_SYSTEM_ID, FC_COMPONENT_ID))
    fc_link.receive(10.01)
    assert fc_link.health().second_sender == 1 and _warnings(transport) == ["companion: second sender as 1/1 (unsigned)"]


def test_the_signing_timestamps_are_saved_off_the_control_loop_and_once_more_at_exit(tmp_path, monkeypatch):
    """The loop that answers the FC never writes the timestamps file; a thread of its own does,
    and close_app saves the newest timestamps."""
    monkeypatch.setattr(signing, "SAVE_PERIOD_S", 0.05)
    saved_by: list[str] = []
    save = signing.StreamTimestamps.save

    def spy(self, *args, **kwargs):
        saved_by.append(threading.current_thread().name)
        save(self, *args, **kwargs)

    monkeypatch.setattr(signing.StreamTimestamps, "save", spy)
    config = _signed_config(tmp_path)
    key = load_key(tmp_path / "mavlink.key")
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as fc:
        app = open_app(config)
        try:
            del saved_by[:]                                   # the save on load
            _send(fc, packed(_fc_frame(5000), FC_SYSTEM_ID, FC_COMPONENT_ID, key), app, until=lambda: app.fc.locked)
            assert app.fc.locked
            deadline = time.monotonic() + 5.0                 # a busy machine may hold the thread back
            while not saved_by and time.monotonic() < deadline:
                time.sleep(0.01)
            loop = threading.current_thread().name
            assert saved_by and loop not in saved_by
            own_before_exit = app.fc.link.mav.signing.timestamp
        finally:
            close_app(app)
    assert saved_by[-1] == loop
    kept = json.loads((tmp_path / "mavlink.key.companion-timestamps").read_text())
    assert kept["own"] >= own_before_exit
    assert list(kept["streams"]) == [f"0,{FC_SYSTEM_ID},{FC_COMPONENT_ID}"]
