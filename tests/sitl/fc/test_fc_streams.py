"""The simulated FC's telemetry in lockstep: required rates, the frame, setpoints applied."""

from __future__ import annotations

import math

import numpy as np
import pytest

from m4.airframe import load_airframe
from m4.mavlink import mavlink
from m4.scenario import Scenario
from sitl.serve import ServeOptions
from sitl.standin_companion import StandInCompanion, served

HOVER = Scenario(name="hover", duration_s=60.0)
FRAME_NAMES = ["ATTITUDE", "ATTITUDE_QUATERNION", "LOCAL_POSITION_NED", "M4_JOINT_STATE", "M4_THRUSTER_STATUS"]


def _run(companion: StandInCompanion, seconds: float, **options):
    """Serve in lockstep for `seconds` simulated; the messages the companion received."""
    with served(companion, ServeOptions(scenario=options.pop("scenario", HOVER), duration_s=seconds, **options)):
        last = round(seconds * 1000)
        assert companion.wait_for("M4_THRUSTER_STATUS", lambda m: m.time_boot_ms >= last, 60.0)
    return list(companion.received)


def test_streams_reach_the_required_rates_over_one_simulated_second():
    msgs = _run(StandInCompanion(period_ms=20), 2.0)
    in_second = [m for m in msgs if 1000 <= getattr(m, "time_boot_ms", -1) < 2000]
    counts = {name: sum(m.get_type() == name for m in in_second)
              for name in ("ATTITUDE", "ATTITUDE_QUATERNION", "LOCAL_POSITION_NED", "GLOBAL_POSITION_INT",
                           "M4_JOINT_STATE", "M4_THRUSTER_STATUS")}
    assert counts["ATTITUDE"] >= 100 and counts["ATTITUDE_QUATERNION"] >= 100
    assert counts["LOCAL_POSITION_NED"] >= 50
    assert counts["GLOBAL_POSITION_INT"] >= 10 and counts["M4_JOINT_STATE"] >= 50 and counts["M4_THRUSTER_STATUS"] >= 50
    outputs = [m for m in msgs if m.get_type() == "ACTUATOR_OUTPUT_STATUS" and 1e6 <= m.time_usec < 2e6]
    assert len(outputs) >= 10
    heartbeats = [m for m in msgs if m.get_type() == "HEARTBEAT"]
    assert len(heartbeats) >= 2
    assert {(m.get_srcSystem(), m.get_srcComponent(), m.type) for m in heartbeats} == {(1, 1, mavlink.MAV_TYPE_QUADROTOR)}
    assert any(m.get_type() == "SYS_STATUS" for m in msgs)


def test_each_control_instant_sends_the_frame_in_contract_order():
    msgs = _run(StandInCompanion(period_ms=40), 1.0)
    for t_ms in range(0, 1001, 40):
        stamped = [m.get_type() for m in msgs if m.get_type() in FRAME_NAMES and m.time_boot_ms == t_ms]
        assert stamped == FRAME_NAMES, t_ms


def test_setpoint_thrust_and_hips_show_up_in_the_fc_status():
    af = load_airframe()
    thrust = np.array([14.0, 15.0, 16.0, 14.5])
    hip = np.radians([60.0, 40.0, 50.0, 45.0])
    companion = StandInCompanion(answer=lambda t_ms: (thrust, hip, np.zeros(4), 0))
    msgs = _run(companion, 0.6)
    status = next(m for m in msgs if m.get_type() == "M4_THRUSTER_STATUS" and m.time_boot_ms == 600)
    assert np.allclose(status.thrust_cmd_n, thrust, atol=1e-4)
    assert np.allclose(status.thrust_limit_n, af.thrust_max_n)
    joints = next(m for m in msgs if m.get_type() == "M4_JOINT_STATE" and m.time_boot_ms == 600)
    assert np.allclose(joints.hip_angle_rad, hip, atol=math.radians(1.0))
    output = [m for m in msgs if m.get_type() == "ACTUATOR_OUTPUT_STATUS"][-1]
    assert np.allclose(output.actuator[:4], thrust / af.thrust_max_n, atol=1e-4)
    assert output.active == 0b1111
    texts = [m.text for m in msgs if m.get_type() == "STATUSTEXT"]
    assert texts == ["FC failsafe HOLD: no fresh setpoints", "FC: flying companion setpoints"]


def test_out_of_range_setpoint_is_clamped_to_the_airframe():
    af = load_airframe()
    companion = StandInCompanion(answer=lambda t_ms: ([99.0, 14.7, 14.7, -5.0], [3.0, 0.78, 0.78, 0.78],
                                                      [0.0] * 4, 0))
    msgs = _run(companion, 0.2)
    status = [m for m in msgs if m.get_type() == "M4_THRUSTER_STATUS"][-1]
    assert status.thrust_cmd_n[0] == pytest.approx(af.thrust_max_n)
    assert status.thrust_cmd_n[3] == pytest.approx(af.thrust_min_n)


def test_thrust_cut_flag_stops_the_motors():
    cut = mavlink.M4_SETPOINT_FLAG_THRUST_CUT
    companion = StandInCompanion(answer=lambda t_ms: ([14.7] * 4, [0.78] * 4, [0.0] * 4, cut))
    msgs = _run(companion, 0.3)
    status = [m for m in msgs if m.get_type() == "M4_THRUSTER_STATUS"][-1]
    assert list(status.thrust_cmd_n) == [0.0] * 4


def test_in_lockstep_thruster_status_marks_only_the_control_instants():
    msgs = _run(StandInCompanion(period_ms=100), 1.0)
    stamps = [m.time_boot_ms for m in msgs if m.get_type() == "M4_THRUSTER_STATUS"]
    assert sorted(set(stamps)) == list(range(0, 1001, 100))
    assert len([m for m in msgs if m.get_type() == "ATTITUDE" and 0 <= m.time_boot_ms < 1000]) == 100


def test_actuator_outputs_are_normalised_by_the_limit_the_fc_is_configured_with():
    from m4.scenario import PlantOptions
    capped = Scenario(name="capped", duration_s=60.0, plant=PlantOptions(thrust_max_n=24.0))
    companion = StandInCompanion(answer=lambda t_ms: (np.full(4, 30.0), np.full(4, math.radians(45.0)),
                                                      np.zeros(4), 0))
    msgs = _run(companion, 0.3, scenario=capped)
    output = [m for m in msgs if m.get_type() == "ACTUATOR_OUTPUT_STATUS"][-1]
    assert np.allclose(output.actuator[:4], 1.0)              # saturated at the configured 24 N: full output
    status = [m for m in msgs if m.get_type() == "M4_THRUSTER_STATUS"][-1]
    assert np.allclose(status.thrust_limit_n, 24.0)
