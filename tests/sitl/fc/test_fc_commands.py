"""Every command to the simulated FC is acknowledged; failures and rotor losses reach the plant."""

from __future__ import annotations

import contextlib
import math

import pytest

from m4.airframe import load_airframe
from m4.mavlink import mavlink
from m4.units import RAD_S_TO_RPM
from m4.scenario import Scenario
from sitl.serve import ServeOptions
from sitl.standin_companion import StandInCompanion, served
from sitl.fc.telemetry import Home

m = mavlink


@contextlib.contextmanager
def _fc():
    companion = StandInCompanion()
    with served(companion, ServeOptions(scenario=Scenario(name="hover", duration_s=60.0))):
        yield companion


def _command(companion, command, *params, target_component=1):
    """Send COMMAND_LONG; the COMMAND_ACK for it and the sim time it was handled at."""
    before = len(companion.of_type("COMMAND_ACK"))
    p = [float(x) for x in params] + [0.0] * (7 - len(params))
    companion.send(m.MAVLink_command_long_message(1, target_component, command, 0, *p))
    ack = companion.wait_for("COMMAND_ACK", lambda a: a in companion.of_type("COMMAND_ACK")[before:]
                             and a.command == command, timeout_s=5.0 if target_component == 1 else 0.5)
    return ack


def _rpm(af, thrust_n: float) -> float:
    """The rotor speed at which the propeller gives thrust_n."""
    return math.sqrt(thrust_n / af.thrust_coefficient_n_s2) * RAD_S_TO_RPM


def _after(companion, ack, kind, match, timeout_s=10.0):
    """The first message of `kind` received after `ack` that `match`es."""
    start = next(i for i, msg in enumerate(companion.received) if msg is ack)
    return companion.wait_for(kind, lambda s: s in companion.received[start:] and match(s), timeout_s)


def test_inject_failure_off_stops_the_rotor_and_ok_restores_it():
    af = load_airframe()
    with _fc() as companion:
        ack = _command(companion, m.MAV_CMD_INJECT_FAILURE, m.FAILURE_UNIT_SYSTEM_MOTOR, m.FAILURE_TYPE_OFF, 4)
        assert ack.result == m.MAV_RESULT_ACCEPTED
        assert ack.target_system == 1 and ack.target_component == 191
        off = _after(companion, ack, "ESC_TELEMETRY_1_TO_4", lambda e: e.rpm[3] == 0)
        assert off is not None and min(off.rpm[:3]) > 1000
        status = _after(companion, ack, "M4_THRUSTER_STATUS", lambda s: True)
        assert list(status.thrust_limit_n) == [af.thrust_max_n] * 4   # the FC knows its rating, not the fault
        ack = _command(companion, m.MAV_CMD_INJECT_FAILURE, m.FAILURE_UNIT_SYSTEM_MOTOR, m.FAILURE_TYPE_OK, 4)
        assert ack.result == m.MAV_RESULT_ACCEPTED
        hover_rpm = _rpm(af, af.hover_thrust_per_rotor_n)
        assert _after(companion, ack, "ESC_TELEMETRY_1_TO_4", lambda e: e.rpm[3] > 0.9 * hover_rpm) is not None
        texts = [t.text for t in companion.of_type("STATUSTEXT")]
        assert "rotor 4 motor stop injected" in texts and "rotor 4 restored" in texts


def test_inject_failure_instance_zero_stops_every_rotor():
    with _fc() as companion:
        ack = _command(companion, m.MAV_CMD_INJECT_FAILURE, m.FAILURE_UNIT_SYSTEM_MOTOR, m.FAILURE_TYPE_OFF, 0)
        assert ack.result == m.MAV_RESULT_ACCEPTED
        assert _after(companion, ack, "ESC_TELEMETRY_1_TO_4", lambda e: max(e.rpm) == 0) is not None


@pytest.mark.parametrize("unit, failure_type, instance, result", [
    (m.FAILURE_UNIT_SENSOR_GYRO, m.FAILURE_TYPE_OFF, 1, m.MAV_RESULT_UNSUPPORTED),
    (m.FAILURE_UNIT_SYSTEM_MOTOR, m.FAILURE_TYPE_STUCK, 1, m.MAV_RESULT_UNSUPPORTED),
    (m.FAILURE_UNIT_SYSTEM_MOTOR, m.FAILURE_TYPE_OFF, 5, m.MAV_RESULT_DENIED),
])
def test_inject_failure_it_cannot_do_is_refused(unit, failure_type, instance, result):
    with _fc() as companion:
        assert _command(companion, m.MAV_CMD_INJECT_FAILURE, unit, failure_type, instance).result == result


def test_rotor_loss_command_caps_the_rotor_relative_to_hover_thrust():
    af = load_airframe()
    with _fc() as companion:
        ack = _command(companion, m.MAV_CMD_M4_ROTOR_LOSS, 2, 0.5)
        assert ack.result == m.MAV_RESULT_ACCEPTED
        expected = 0.5 * af.hover_thrust_per_rotor_n
        capped = _after(companion, ack, "ESC_TELEMETRY_1_TO_4", lambda e: abs(e.rpm[1] - _rpm(af, expected)) < 20)
        status = _after(companion, capped, "M4_THRUSTER_STATUS", lambda s: True)
        assert capped is not None and status.thrust_cmd_n[1] > expected      # the command is what was asked
        assert _command(companion, m.MAV_CMD_M4_ROTOR_LOSS, 2, 1.5).result == m.MAV_RESULT_DENIED
        assert _command(companion, m.MAV_CMD_M4_ROTOR_LOSS, 2.5, 0.5).result == m.MAV_RESULT_DENIED


def test_rotor_loss_command_takes_the_failure_kind_and_refuses_an_unknown_one():
    af = load_airframe()
    with _fc() as companion:
        ack = _command(companion, m.MAV_CMD_M4_ROTOR_LOSS, 3, 1.0, m.M4_FAULT_KIND_PROPELLER)
        assert ack.result == m.MAV_RESULT_ACCEPTED
        hover_rpm = _rpm(af, af.hover_thrust_per_rotor_n)
        assert _after(companion, ack, "ESC_TELEMETRY_1_TO_4", lambda e: e.rpm[2] > 1.15 * hover_rpm) is not None   # unloaded
        assert _command(companion, m.MAV_CMD_M4_ROTOR_LOSS, 3, 1.0, 9).result == m.MAV_RESULT_DENIED
        assert _command(companion, m.MAV_CMD_M4_ROTOR_LOSS, 3, 1.0, m.M4_FAULT_KIND_UNKNOWN).result == \
            m.MAV_RESULT_ACCEPTED                                              # the default: degraded
        assert _command(companion, m.MAV_CMD_M4_ROTOR_LOSS, 3, 1.0, 1.5).result == m.MAV_RESULT_DENIED
        assert "rotor 3 propeller loss injected" in [t.text for t in companion.of_type("STATUSTEXT")]


def test_set_message_interval_changes_and_stops_a_stream():
    gpi = m.MAVLINK_MSG_ID_GLOBAL_POSITION_INT
    with _fc() as companion:
        ack = _command(companion, m.MAV_CMD_SET_MESSAGE_INTERVAL, gpi, 10_000)     # 100 Hz
        assert ack.result == m.MAV_RESULT_ACCEPTED
        t0 = max(getattr(x, "time_boot_ms", 0) for x in companion.received[:companion.received.index(ack)]) + 100
        assert companion.wait_for("ATTITUDE", lambda a: a.time_boot_ms > t0 + 1100)
        in_second = [g for g in companion.of_type("GLOBAL_POSITION_INT") if t0 <= g.time_boot_ms < t0 + 1000]
        assert len(in_second) == 100
        ack = _command(companion, m.MAV_CMD_SET_MESSAGE_INTERVAL, gpi, -1)
        assert ack.result == m.MAV_RESULT_ACCEPTED
        t1 = max(getattr(x, "time_boot_ms", 0) for x in companion.received[:companion.received.index(ack)]) + 50
        assert companion.wait_for("ATTITUDE", lambda a: a.time_boot_ms > t1 + 500)
        assert not [g for g in companion.of_type("GLOBAL_POSITION_INT") if g.time_boot_ms > t1]
        assert _command(companion, m.MAV_CMD_SET_MESSAGE_INTERVAL, 9999, 10_000).result == m.MAV_RESULT_DENIED


def test_in_lockstep_a_stream_of_the_frame_stopped_on_its_link_leaves_the_frame_but_the_thruster_status():
    """As an FC that honours the stop: the companion's stopped ATTITUDE_QUATERNION no longer comes
    in its frames; M4_THRUSTER_STATUS, which marks a frame to answer, comes whatever is asked."""
    quat, status = m.MAVLINK_MSG_ID_ATTITUDE_QUATERNION, m.MAVLINK_MSG_ID_M4_THRUSTER_STATUS
    with _fc() as companion:
        for msg_id in (quat, status):
            ack = _command(companion, m.MAV_CMD_SET_MESSAGE_INTERVAL, msg_id, -1)
            assert ack.result == m.MAV_RESULT_ACCEPTED
        t1 = max(getattr(x, "time_boot_ms", 0) for x in companion.received[:companion.received.index(ack)]) + 50
        assert companion.wait_for("M4_THRUSTER_STATUS", lambda s: s.time_boot_ms > t1 + 500)
        assert not [q for q in companion.of_type("ATTITUDE_QUATERNION") if q.time_boot_ms > t1]
        assert [a for a in companion.of_type("ATTITUDE") if a.time_boot_ms > t1]


def test_request_message_sends_autopilot_version_and_home_position():
    home = Home()
    with _fc() as companion:
        ack = _command(companion, m.MAV_CMD_REQUEST_MESSAGE, m.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
        assert ack.result == m.MAV_RESULT_ACCEPTED
        version = companion.wait_for("AUTOPILOT_VERSION")
        assert version.capabilities & m.MAV_PROTOCOL_CAPABILITY_MAVLINK2
        ack = _command(companion, m.MAV_CMD_REQUEST_MESSAGE, m.MAVLINK_MSG_ID_HOME_POSITION)
        assert ack.result == m.MAV_RESULT_ACCEPTED
        home_msg = companion.wait_for("HOME_POSITION")
        assert home_msg.latitude == round(home.lat_deg * 1e7) and home_msg.longitude == round(home.lon_deg * 1e7)
        assert _command(companion, m.MAV_CMD_REQUEST_MESSAGE, 9999).result == m.MAV_RESULT_DENIED


def test_unknown_command_is_acknowledged_unsupported():
    with _fc() as companion:
        ack = _command(companion, m.MAV_CMD_NAV_TAKEOFF, 0)
        assert ack.result == m.MAV_RESULT_UNSUPPORTED
        before = len(companion.of_type("COMMAND_ACK"))
        companion.send(m.MAVLink_command_int_message(1, 1, 0, m.MAV_CMD_DO_SET_HOME, 0, 0, 1, 0, 0, 0, 0, 0, 0))
        ack = companion.wait_for("COMMAND_ACK", lambda a: a in companion.of_type("COMMAND_ACK")[before:])
        assert ack.command == m.MAV_CMD_DO_SET_HOME and ack.result == m.MAV_RESULT_UNSUPPORTED


def test_command_for_another_component_is_left_to_it():
    with _fc() as companion:
        assert _command(companion, m.MAV_CMD_COMPONENT_ARM_DISARM, 1, target_component=191) is None


def test_the_modes_are_told_by_the_standard_modes_protocol():
    with _fc() as companion:
        assert _command(companion, m.MAV_CMD_REQUEST_MESSAGE, m.MAVLINK_MSG_ID_AVAILABLE_MODES, 0).result \
            == m.MAV_RESULT_ACCEPTED
        companion.wait_for("AVAILABLE_MODES", lambda a: a.mode_index == a.number_modes)
        assert [(a.custom_mode, a.mode_name, a.properties) for a in companion.of_type("AVAILABLE_MODES")] == [
            (4, "COMPANION", 0), (5, "", 0), (9, "", 0), (100, "LANDED", m.MAV_MODE_PROPERTY_NOT_USER_SELECTABLE)]
        assert _command(companion, m.MAV_CMD_REQUEST_MESSAGE, m.MAVLINK_MSG_ID_AVAILABLE_MODES, 9).result \
            == m.MAV_RESULT_DENIED
        current = companion.wait_for("CURRENT_MODE", lambda c: c.custom_mode == 4)      # flying our setpoints
        assert current.standard_mode == m.MAV_STANDARD_MODE_NON_STANDARD
        assert companion.of_type("CURRENT_MODE")[0].standard_mode == m.MAV_STANDARD_MODE_POSITION_HOLD   # at start
