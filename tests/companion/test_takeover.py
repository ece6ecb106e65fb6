"""Taking control from the flight controller's own controller (issue 20): thrusts ramp from
what the FC commands, the mission goes on where it was (a gap, a restart with what the FC
kept) and a landing FC is joined, not cancelled."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from companion.config import parse_config
from companion.controller import Controller, ControllerSettings
from companion.core import rom
from companion.core.nmpc import Nmpc
from companion.core.takeover import SLEW_N_S, TakeoverRamp
from m4.airframe import load_airframe
from m4.mission import Landing, Mission, Waypoint
from m4.mission_plan import MissionProgress, PlanProgress, PlanState

AF = load_airframe()
CONFIG = parse_config({"control": {"rate_hz": 50.0}, "nmpc": {"time_budget_share": 0.0}}, "test")
PERIOD = CONFIG.control_period_s
STEP_N = SLEW_N_S * PERIOD
HOVER_N = AF.hover_thrust_per_rotor_n
_NMPC = Nmpc(AF, CONFIG.nmpc)


def controller(mission: Mission = Mission(on_fault="hold")) -> Controller:
    _NMPC.reset()
    return Controller(dataclasses.replace(ControllerSettings.of(CONFIG), mission=mission), nmpc=_NMPC)


def at(z_ned_m: float, x_ned_m: float = 0.0) -> np.ndarray:
    return rom.hover_state(AF, p_ned_m=(x_ned_m, 0.0, z_ned_m))


def test_the_ramp_moves_each_rotor_one_step_at_a_time_and_ends_within_reach():
    ramp = TakeoverRamp(PERIOD)
    ramp.begin([20.0, 0.0, 10.0, np.nan])
    bound = np.full(4, 30.0)
    first = ramp.limit(np.array([10.0, 10.0, 10.5, 25.0]), bound)
    assert first == pytest.approx([20.0 - STEP_N, STEP_N, 10.5, 25.0])    # NaN: the FC did not say, no limit
    second = ramp.limit(np.array([10.0, 10.0, 10.5, 25.0]), bound)
    assert second == pytest.approx([20.0 - 2 * STEP_N, 2 * STEP_N, 10.5, 25.0]) and ramp.active
    for _ in range(3):
        ramp.limit(np.array([10.0, 10.0, 10.5, 25.0]), bound)
    assert not ramp.active
    assert ramp.limit(np.array([1.0, 29.0, 0.0, 0.0]), bound) == pytest.approx([1.0, 29.0, 0.0, 0.0])


def test_a_rotor_the_bound_says_is_dead_is_not_ramped_down_from_what_the_fc_commands():
    ramp = TakeoverRamp(PERIOD)
    ramp.begin([15.0, 15.0, 15.0, 20.0])
    out = ramp.limit(np.array([15.0, 15.0, 15.0, 0.0]), np.array([30.0, 30.0, 30.0, 0.0]))
    assert out == pytest.approx([15.0, 15.0, 15.0, 0.0])


def test_the_first_setpoint_starts_from_the_fcs_thrusts_and_reaches_the_nmpcs_without_a_step():
    c = controller()
    fc_n = np.array([HOVER_N + 8.0, HOVER_N - 8.0, HOVER_N, HOVER_N])      # the FC's hold, far from ours
    x = at(-2.0)
    assert c.start(0.0, x)
    thrusts, k = [fc_n], 0
    while k == 0 or c.ramp.active:
        thrusts.append(c.step(k * PERIOD, x, thrust_cmd_n=thrusts[-1]).setpoint.thrust_n)
        k += 1
    assert 2 <= k <= 5 and np.max(np.abs(np.diff(thrusts, axis=0))) <= STEP_N + 1e-9


def test_after_a_gap_the_fcs_failsafe_flew_the_thrusts_ramp_again_and_after_a_short_one_they_do_not():
    c = controller()
    x = at(-2.0)
    c.start(0.0, x)
    for k in range(5):
        c.step(k * PERIOD, x, thrust_cmd_n=np.full(4, HOVER_N))
    fc_n = np.full(4, HOVER_N + 10.0)
    short = c.step(5 * PERIOD + 0.2, x, thrust_cmd_n=fc_n)             # the FC flew our last setpoint
    assert not short.took_over and np.max(np.abs(short.setpoint.thrust_n - fc_n)) > STEP_N
    long = c.step(5 * PERIOD + 0.2 + 0.5, x, thrust_cmd_n=fc_n)       # its failsafe flew
    assert long.took_over and np.max(np.abs(long.setpoint.thrust_n - fc_n)) <= STEP_N + 1e-9


def test_the_mission_clock_stands_still_while_the_fcs_failsafe_flies():
    """Heading for a waypoint 10 m ahead: after 2 s in the FC's hands the reference goes on
    from where it was left, not 2 s further along."""
    c = controller(Mission(waypoints=(Waypoint((10.0, 0.0, -2.0), 1.0, 0.0),)))
    x = at(-2.0)
    c.start(0.0, x)
    for k in range(50):
        out = c.step(k * PERIOD, x)
    left_at = out.reference[0, rom.P]
    back = c.step(49 * PERIOD + 2.0, x)
    assert back.reference[0, rom.P] == pytest.approx(left_at, abs=0.03)
    assert c.mission_progress(49 * PERIOD + 2.0).time_s == pytest.approx(50 * PERIOD, abs=1e-9)


def test_a_restart_resumes_the_kept_hold_instead_of_anchoring_where_it_finds_the_robot():
    first = controller()
    first.start(0.0, at(-2.0))
    first.flight.reference.fault_detected(1.0, (0.0, 0.0, -2.0))
    kept = first.mission_progress(3.0)
    assert kept.plan.state is PlanState.FAULT_HOLD and kept.time_s == 3.0
    second = controller()
    assert second.start(4.0, at(-1.8), kept)                        # the robot sagged 0.2 m meanwhile
    out = second.step(4.0, at(-1.8))
    assert out.reference[0, rom.P] == pytest.approx([0.0, 0.0, -2.0])
    assert second.mission_progress(4.0).time_s == pytest.approx(3.0)


def test_taking_over_from_a_landing_fc_lands_from_where_the_robot_is():
    c = controller()
    kept = MissionProgress(3.0, PlanProgress(PlanState.AS_PLANNED, 0.0, (0.0, 0.0, -2.0)))
    c.start(4.0, at(-1.2), kept)
    out = c.step(4.0, at(-1.2), fc_landing=True)
    assert out.took_over and c.flight.reference.landing_started(c.flight.mission_time_s(4.0))
    later = c.step(4.0 + PERIOD, at(-1.2))
    assert later.reference[0, rom.P][2] == pytest.approx(-1.2, abs=0.01)
    assert later.reference[-1, rom.P][2] > -1.2                        # on the way down, not back up to 2 m
    assert c.mission_progress(4.02).plan.state is PlanState.LANDING


def test_a_restart_during_a_landing_goes_on_down_from_where_the_fcs_landing_brought_the_robot():
    """Not back up to where the last run's landing had got to when it was killed."""
    c = controller()
    kept = MissionProgress(9.0, PlanProgress(PlanState.LANDING, 0.0, (0.0, 0.0, -5.0), 4.0, (0.0, 0.0, -3.7)))
    c.start(12.6, at(-1.5), kept)
    out = c.step(12.6, at(-1.5), fc_landing=True)
    assert out.reference[0, rom.P][2] == pytest.approx(-1.5, abs=0.01)
    assert np.all(np.diff(out.reference[:, rom.P][:, 2]) >= -1e-9)           # down only


def test_the_mission_clock_starts_at_the_first_setpoint_whatever_the_fcs_clock_reads():
    """ArduPilot's clock runs from its boot: a flight begun 54 s after it neither starts landing
    at once (land at 22 s of the mission) nor finds its waypoints 54 s along."""
    c = controller(Mission(waypoints=(Waypoint((10.0, 0.0, -2.0), 1.0, 0.0),), land=Landing(22.0, 0.5)))
    x = at(-2.0)
    assert c.start(54.0, x)
    out = c.step(54.0, x)
    assert c.mission_progress(54.0).time_s == 0.0
    assert not c.flight.reference.landing_started(c.flight.mission_time_s(54.02))
    assert out.reference[0, rom.P][0] == pytest.approx(0.0, abs=0.05)
