"""Restarts over real loopback sockets: a flight controller that comes back on a new source
port with its clock at 0 is found again within its heartbeat period and control resumes; a
restarted companion takes the confirmed fault the FC kept (M4_FAULT_STATUS) as its own."""

from __future__ import annotations

import logging
import time

import numpy as np

from companion.app import CompanionApp
from companion.config import parse_config
from companion.controller import Controller, ControllerSettings
from companion.core.control_types import FaultState
from companion.fc_link import FcLink
from m4.airframe import load_airframe
from m4.mavlink import COMPANION_COMPONENT_ID, FC_SYSTEM_ID, mavlink
from m4.mavlink.link import UdpLink
from support.loopback_fc import LoopbackFc

AF = load_airframe()
CONFIG = parse_config({"control": {"rate_hz": 50.0}, "link": {"fc_url": "udpin:127.0.0.1:0"}}, "test")


def _app():
    link = UdpLink("udpin:127.0.0.1:0", FC_SYSTEM_ID, COMPANION_COMPONENT_ID)
    return CompanionApp(CONFIG, FcLink(link), Controller(ControllerSettings.of(CONFIG))), link


def _fly(app, fc, t0_ms: int, frames: int) -> list:
    got = []
    for k in range(frames):
        fc.frame(t0_ms + 20 * k)
        time.sleep(0.005)
        app.poll()
        got += fc.received()
    return got


def test_a_restarted_fc_on_a_new_port_is_found_again_within_a_second_and_flown(caplog):
    app, link = _app()
    first = LoopbackFc(link.local_port, AF)
    second = None
    try:
        first.heartbeat()
        assert [m.time_boot_ms for m in _fly(app, first, 5000, 5) if m.get_type() == "M4_SETPOINT"]
        first.close()                                   # the FC process dies ...
        deadline = time.monotonic() + 0.4
        while time.monotonic() < deadline:
            app.poll()
            time.sleep(0.01)
        assert not app.fc.connected
        second = LoopbackFc(link.local_port, AF)        # ... and a new one starts on another port
        restarted = time.monotonic()
        with caplog.at_level(logging.INFO, logger="m4-companion"):
            second.heartbeat()
            got = _fly(app, second, 0, 10)
        assert time.monotonic() - restarted < 1.0
        assert app.fc.fc_address[1] == second.port and app.fc.previous_address[1] != second.port
        assert [m.time_boot_ms for m in got if m.get_type() == "M4_SETPOINT"] == list(range(0, 200, 20))
        assert any("found again" in r.message for r in caplog.records)
        assert any("rebooted" in r.message for r in caplog.records)
    finally:
        for fc in (first, second):
            if fc is not None:
                fc.close()
        link.close()


def test_a_restarted_companion_takes_the_confirmed_fault_the_fc_kept():
    app, link = _app()
    fc = LoopbackFc(link.local_port, AF)
    asked = []
    try:
        fc.heartbeat()
        for k in range(30):
            fc.frame(20 * k)
            time.sleep(0.005)
            app.poll()
            for m in fc.received():
                if m.get_type() == "COMMAND_LONG" and m.command == mavlink.MAV_CMD_REQUEST_MESSAGE:
                    asked.append(int(m.param1))
                    fc.link.send_all([
                        mavlink.MAVLink_command_ack_message(m.command, mavlink.MAV_RESULT_ACCEPTED, 0, 0, 1, 191),
                        mavlink.MAVLink_m4_fault_status_message(0, 4, [30.0, 30.0, 30.0, 0.0], 300,
                                                                int(FaultState.CONFIRMED))])
                elif m.get_type() == "M4_SETPOINT":
                    last = m
        status = app.controller.detector.status
        assert asked == [mavlink.MAVLINK_MSG_ID_M4_FAULT_STATUS]
        assert status.state is FaultState.CONFIRMED and status.rotor == 4 and status.detected_at_s == 0.3
        assert np.array(last.thrust_n)[3] <= status.thrust_bound_n[3] + 1e-4
    finally:
        fc.close()
        link.close()
