"""Restarts over real loopback sockets: a flight controller that comes back on a new source
port with its clock at 0 is found again and control resumes; a restarted companion takes the
confirmed fault the FC kept (M4_FAULT_STATUS) as its own before it says anything of its own,
resumes the mission the FC kept, joins the FC's landing, and takes control within 0.3 s of
the FC's telemetry."""

from __future__ import annotations

import logging
import time

import numpy as np
import pytest

from companion.app import CompanionApp
from companion.config import parse_config
from companion.controller import Controller, ControllerSettings
from companion.core.control_types import FaultState
from companion.fc_link import FcLink
from m4.airframe import load_airframe
from m4.mavlink import COMPANION_COMPONENT_ID, FC_SYSTEM_ID, mavlink
from m4.mission_plan import PlanState
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
        first.join(app)
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
            got = second.join(app) + _fly(app, second, 0, 10)
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
    fc.kept = mavlink.MAVLink_m4_fault_status_message(0, 4, [30.0, 30.0, 30.0, 0.0], 300, int(FaultState.CONFIRMED))
    try:
        sent = fc.join(app) + _fly(app, fc, 0, 30)
        asked = [int(m.param1) for m in sent if m.get_type() == "COMMAND_LONG"
                 and m.command == mavlink.MAV_CMD_REQUEST_MESSAGE]
        last = [m for m in sent if m.get_type() == "M4_SETPOINT"][-1]
        status = app.controller.detector.status
        assert asked == [mavlink.MAVLINK_MSG_ID_M4_FAULT_STATUS, mavlink.MAVLINK_MSG_ID_CURRENT_MODE]
        assert status.state is FaultState.CONFIRMED and status.rotor == 4 and status.detected_at_s == 0.3
        assert np.array(last.thrust_n)[3] <= status.thrust_bound_n[3] + 1e-4
    finally:
        fc.close()
        link.close()


def _kept(rotor: int = 0, mission_state: int = 0, start=(0.0, 0.0, 0.0), change=(0.0, 0.0, 0.0)):
    """What the FC kept of an earlier run: an M4_FAULT_STATUS (rotor 0: healthy), the mission
    at 2.98 s of its clock, started at 0, changed at 1.06 s."""
    estimate = [30.0] * 4
    if rotor:
        estimate[rotor - 1] = 0.0
    return mavlink.MAVLink_m4_fault_status_message(
        2980, rotor, estimate, 1040 if rotor else 0,
        int(FaultState.CONFIRMED if rotor else FaultState.HEALTHY), 1, mission_state, 2980, 0, list(start), 1060,
        list(change))


def test_a_restarted_companion_says_nothing_of_a_fault_before_it_learns_the_one_the_fc_kept():
    """Today's order overwrote the kept fault with "healthy" 1 ms before asking for it."""
    app, link = _app()
    fc = LoopbackFc(link.local_port, AF)
    fc.kept = _kept(rotor=4)
    try:
        fc.heartbeat()
        sent = _fly(app, fc, 4000, 10)
    finally:
        fc.close()
        link.close()
    kinds = [m.get_type() for m in sent]
    statuses = [m for m in sent if m.get_type() == "M4_FAULT_STATUS"]
    assert kinds.index("M4_SETPOINT") > max(i for i, k in enumerate(kinds) if k == "COMMAND_LONG" and i < 3)
    assert statuses and all(m.state == FaultState.CONFIRMED and m.rotor == 4 for m in statuses)
    first = next(m for m in sent if m.get_type() == "M4_SETPOINT")
    assert first.thrust_n[3] < 0.2 * AF.hover_thrust_per_rotor_n        # the dead rotor is not driven


def test_a_restarted_companion_takes_control_within_0_3_s_of_the_fcs_telemetry_without_its_heartbeat():
    """0.3 s of the FC's clock: 15 frames, each answered before the next goes (the wall clock
    is the machine's load's; the FC's next HEARTBEAT is up to 1 s away)."""
    app, link = _app()
    fc = LoopbackFc(link.local_port, AF)
    try:
        setpoints = []
        for k in range(15):
            setpoints += [m for m in _fly(app, fc, 4000 + 20 * k, 1) if m.get_type() == "M4_SETPOINT"]
            if setpoints:
                break
    finally:
        fc.close()
        link.close()
    assert setpoints and setpoints[0].time_boot_ms < 4000 + 300


def test_a_restarted_companion_resumes_the_hold_the_fc_kept_instead_of_anchoring_where_it_finds_the_robot():
    app, link = _app()
    fc = LoopbackFc(link.local_port, AF)
    fc.kept = _kept(rotor=4, mission_state=PlanState.FAULT_HOLD, start=(0.0, 0.0, -2.0), change=(0.0, 0.0, -2.0))
    try:
        fc.join(app)
        for k in range(10):
            fc.frame(4000 + 20 * k, z_ned_m=-1.8)        # it sagged 0.2 m while the FC flew
            time.sleep(0.005)
            app.poll()
            fc.received()
    finally:
        fc.close()
        link.close()
    flight = app.controller.flight
    assert flight.reference.progress.state is PlanState.FAULT_HOLD
    assert flight.reference.state(flight.mission_time_s(4.2))[0] == pytest.approx([0.0, 0.0, -2.0])


def test_a_restarted_companion_joins_the_landing_of_the_fc_instead_of_cancelling_it():
    app, link = _app()
    fc = LoopbackFc(link.local_port, AF)
    fc.kept = _kept(rotor=4, mission_state=PlanState.FAULT_HOLD, start=(0.0, 0.0, -2.0), change=(0.0, 0.0, -2.0))
    fc.standard_mode = mavlink.MAV_STANDARD_MODE_LAND
    try:
        fc.join(app)
        _fly(app, fc, 4000, 5)
    finally:
        fc.close()
        link.close()
    flight = app.controller.flight
    assert flight.reference.progress.state is PlanState.LANDING
    below = flight.reference.state(flight.mission_time_s(6.0))[0][2]
    assert below > -1.2                                 # on its way down from 2 m at 0.5 m/s
