"""The companion's control step: safe setpoints whatever comes in, hover, fault bound, hips, thrust cut,
the FC's modes followed."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from m4.airframe import ROTOR_COUNT, load_airframe
from m4.fc_mode import FcMode
from companion.config import parse_config
from companion.controller import Controller, ControllerSettings
from companion.core import rom
from companion.core.esc_evidence import EscSample, PropellerModel
from companion.core.control_types import FaultState, safe_setpoint, thrust_bounds
from companion.core.fault_detector import FaultDetector
from companion.core.nmpc import Nmpc
from companion.core.reference import MissionReference
from companion.core.com_offset import ComOffset
from companion.telemetry import VehicleSnapshot, rom_state
from m4.mission import Landing, Mission, Waypoint
from m4.setpoint import Setpoint

AF = load_airframe()
COM = ComOffset(AF)
CONFIG = parse_config({"control": {"rate_hz": 50.0}}, "test")
SETTINGS = ControllerSettings.of(CONFIG)
PERIOD = CONFIG.control_period_s
HOVER_N = AF.hover_thrust_per_rotor_n
_NMPC = None


def controller(**changes) -> Controller:
    """A fresh controller sharing one NMPC (its warm start dropped)."""
    global _NMPC
    if _NMPC is None:
        _NMPC = Nmpc(AF, CONFIG.nmpc)
    _NMPC.reset()
    return Controller(dataclasses.replace(SETTINGS, **changes), nmpc=_NMPC)


def step(c: Controller, time_s: float, x, *telemetry):
    """One step as the app takes it: the flight starts at the first plausible state."""
    if not c.started:
        c.start(time_s, x)
    return c.step(time_s, x, *telemetry)


def assert_safe(sp: Setpoint, thrust_bound_n) -> None:
    """Finite and within every bound, also as the float32 values MAVLink carries."""
    values = np.r_[sp.thrust_n, sp.hip_rad, sp.hip_rate_rad_s]
    assert values.shape == (12,) and np.all(np.isfinite(values))
    assert np.array_equal(values.astype(np.float32).astype(float), values)
    bound = thrust_bounds(AF, thrust_bound_n)
    assert np.all(sp.thrust_n >= (0.0 if sp.thrust_cut else AF.thrust_min_n))
    assert np.all(sp.thrust_n <= bound + 1e-9)
    assert np.all(sp.hip_rad >= AF.hip_min_rad) and np.all(sp.hip_rad <= AF.hip_max_rad)
    for a, b in AF.same_side_pairs:
        assert sp.hip_rad[a] + sp.hip_rad[b] <= AF.same_side_sum_max_rad + 1e-9
    assert np.all(np.abs(sp.hip_rate_rad_s) <= AF.hip_rate_max_rad_s)


anything = st.floats(allow_nan=True, allow_infinity=True)
four = st.lists(anything, min_size=4, max_size=4)


@settings(max_examples=500, deadline=None)
@given(thrust=four, hip=four, rate=four, thrust_bound=four, measured=st.none() | four, cut=st.booleans())
def test_safe_setpoint_is_finite_and_within_every_bound_whatever_goes_in(thrust, hip, rate, thrust_bound, measured,
                                                                          cut):
    sp = safe_setpoint(AF, thrust, hip, rate, thrust_bound, measured, thrust_cut=cut)
    assert_safe(sp, thrust_bound)
    if cut:
        assert np.all(sp.thrust_n == 0.0)


def _state(draw_values):
    """A ROM state near hover with some entries replaced (NaN, inf, wild values)."""
    x = rom.hover_state(AF)
    for i, v in draw_values:
        x[i] = v
    return x


replacements = st.lists(st.tuples(st.integers(0, rom.NX - 1),
                                  st.floats(allow_nan=True, allow_infinity=True) | st.floats(-3.0, 3.0)),
                        max_size=6)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(steps=st.lists(st.tuples(replacements, four, four), min_size=1, max_size=5))
def test_every_control_step_gives_a_finite_setpoint_within_bounds(steps):
    c = controller()
    for k, (changes, rpm, limits) in enumerate(steps):
        esc = EscSample(k * PERIOD, np.asarray(rpm, dtype=float), np.full(4, 10.0), np.full(4, 14.8))
        out = step(c, k * PERIOD, _state(changes), esc, limits)
        assert_safe(out.setpoint, out.fault.thrust_bound_n)


SNAPSHOT_FIELDS = ("euler_rad", "rates_frd_rad_s", "pos_ned_m", "vel_ned_m_s", "hip_rad", "hip_rate_rad_s")


def _snapshot(changes) -> VehicleSnapshot:
    """A snapshot of a hovering robot with some telemetry values replaced."""
    values = {"euler_rad": np.zeros(3), "rates_frd_rad_s": np.zeros(3), "pos_ned_m": np.array([0.0, 0.0, -2.0]),
              "vel_ned_m_s": np.zeros(3), "hip_rad": np.full(4, AF.nominal_hip_rad), "hip_rate_rad_s": np.zeros(4)}
    for name, i, v in changes:
        values[name][i % values[name].size] = v
    return VehicleSnapshot(time_ms=0, times_ms={}, thrust_cmd_n=np.full(4, HOVER_N),
                           thrust_limit_n=np.full(4, np.nan), **values)


snapshot_changes = st.lists(st.tuples(st.sampled_from(SNAPSHOT_FIELDS), st.integers(0, 3),
                                      anything | st.floats(-10.0, 10.0)), max_size=5)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(steps=st.lists(st.tuples(snapshot_changes, four), min_size=1, max_size=4))
def test_every_snapshot_through_the_frame_conversion_gives_a_safe_setpoint(steps):
    c = controller()
    for k, (changes, limits) in enumerate(steps):
        snap = _snapshot(changes)
        out = step(c, k * PERIOD, rom_state(snap, COM), None, limits)
        assert_safe(out.setpoint, out.fault.thrust_bound_n)


def test_hover_at_rest_gives_hover_thrust_and_still_legs():
    c = controller()
    for k in range(5):
        out = step(c, k * PERIOD, rom.hover_state(AF), None, [AF.thrust_max_n] * 4)
    sp = out.setpoint
    assert np.allclose(sp.thrust_n, HOVER_N, atol=0.2)
    assert np.allclose(sp.hip_rad, AF.nominal_hip_rad, atol=math.radians(1.0))
    assert np.allclose(sp.hip_rate_rad_s, 0.0, atol=0.05)
    assert not sp.thrust_cut and out.nmpc.ok


def test_hip_goal_is_a_continuous_trajectory_from_setpoint_to_setpoint():
    c = controller()
    x = rom.hover_state(AF)
    x[rom.P] += (0.5, 0.0, 0.0)          # an offset the legs help with
    x[rom.EULER] = (0.2, -0.1, 0.0)
    previous = None
    for k in range(6):
        sp = step(c, k * PERIOD, x).setpoint
        if previous is not None:
            assert np.allclose(sp.hip_rad, previous.hip_rad + previous.hip_rate_rad_s * PERIOD)
        previous = sp


def test_a_rotor_delivering_nothing_is_confirmed_once_and_bounds_the_nmpc():
    """The ROM as plant with the motors' first-order lag, rotor 4 delivering nothing from
    t = 0.1 s; no ESC telemetry: the model residual finds it."""
    c = controller()
    plant = rom.build_rom(AF, PERIOD, substeps=4).step
    decay = math.exp(-PERIOD / AF.motor_time_constant_s)
    x, delivered = rom.hover_state(AF), np.full(4, HOVER_N)
    announced, out = [], None
    for k in range(25):
        if out is not None:
            sp = out.setpoint
            target = sp.thrust_n * np.array([1.0, 1.0, 1.0, 0.0 if k * PERIOD > 0.1 else 1.0])
            average = target + (delivered - target) * AF.motor_time_constant_s / PERIOD * (1 - decay)
            delivered = target + (delivered - target) * decay
            x = np.array(plant(x, np.r_[average, np.zeros(4)], np.zeros(rom.ND))).ravel()
            x[rom.HIP], x[rom.HIP_RATE] = sp.hip_rad + sp.hip_rate_rad_s * PERIOD, sp.hip_rate_rad_s
        out = step(c, k * PERIOD, x, None, [AF.thrust_max_n] * 4)
        announced += [k * PERIOD] if out.fault_confirmed_now else []
    assert len(announced) == 1 and announced[0] <= 0.1 + 0.2
    assert out.fault.state is FaultState.CONFIRMED and out.fault.rotor == 4
    assert out.fault.message == "thrust loss rotor 4"
    assert out.fault.thrust_max_estimate_n[3] < 1.0
    assert out.setpoint.thrust_n[3] <= out.fault.thrust_bound_n[3]


def test_one_rotor_limit_dropping_at_the_fc_is_not_taken_as_known():
    """The FC's per-rotor limit counts only as a common cap: a lowered single limit is what
    the detector must find, so the bound stays at the cap until it does."""
    c = controller()
    out = step(c, 0.0, rom.hover_state(AF), None, [AF.thrust_max_n] * 3 + [0.0])
    out = step(c, PERIOD, rom.hover_state(AF), None, [AF.thrust_max_n] * 3 + [0.0])
    assert np.allclose(out.fault.thrust_max_estimate_n, AF.thrust_max_n)
    capped = step(c, 2 * PERIOD, rom.hover_state(AF), None, [24.0] * 4)
    assert np.allclose(capped.fault.thrust_max_estimate_n, 24.0)


def test_thrust_is_cut_after_touchdown_during_the_landing():
    c = controller(mission=Mission(land=Landing(at_s=0.0, descent_speed_m_s=0.5)))
    step(c, 0.0, rom.hover_state(AF, p_ned_m=(0.0, 0.0, -1.0)))
    ground = rom.hover_state(AF, p_ned_m=(0.0, 0.0, c.flight.reference.ground_com_z_ned_m))
    outs = [step(c, k * PERIOD, ground) for k in range(1, 30)]
    cut = [o.setpoint.thrust_cut for o in outs]
    assert not cut[0] and cut[-1]
    first = cut.index(True)
    assert all(cut[first:])
    assert (first + 1) * PERIOD >= CONFIG.touchdown.dwell_s - 1e-9
    assert np.all(outs[-1].setpoint.thrust_n == 0.0)


def test_a_robot_the_ground_holds_during_the_landing_is_no_evidence_of_a_lost_rotor():
    """At ground height in the landing, the FC reports rotor 4 at full thrust while the robot
    stays still (the ground's support and friction hold it): in free flight a rotor 4 short
    of 15 N; on the ground, forces the model does not have. No suspicion, no alarm."""
    c = controller(mission=Mission(land=Landing(at_s=0.0, descent_speed_m_s=0.5)))
    step(c, 0.0, rom.hover_state(AF, p_ned_m=(0.0, 0.0, -1.0)))
    ground = rom.hover_state(AF, p_ned_m=(0.0, 0.0, c.flight.reference.ground_com_z_ned_m))
    lopsided = [HOVER_N, HOVER_N, HOVER_N, AF.thrust_max_n]
    outs = [c.step(k * PERIOD, ground, None, None, 0.0, lopsided) for k in range(1, 15)]
    assert all(o.fault.state is FaultState.HEALTHY for o in outs)
    assert not outs[-1].setpoint.thrust_cut          # still before the touchdown's dwell


def test_resume_restarts_the_hip_goal_at_the_measured_joints():
    c = controller()
    x = rom.hover_state(AF)
    x[rom.P] += (0.5, 0.3, 0.0)
    for k in range(3):
        step(c, k * PERIOD, x)
    moved = x.copy()
    moved[rom.HIP] = np.radians([30.0, 60.0, 35.0, 55.0])
    c.resume()
    sp = step(c, 10.0, moved).setpoint
    assert np.allclose(sp.hip_rad, moved[rom.HIP])


def test_the_fixed_posture_variant_holds_its_angle_from_anywhere():
    fixed = math.radians(30.0)
    nmpc = Nmpc(AF, dataclasses.replace(CONFIG.nmpc, fixed_hip_rad=fixed))
    c = Controller(SETTINGS, nmpc=nmpc)
    x = rom.hover_state(AF)
    x[rom.HIP] = np.radians([40.0, 35.0, 25.0, 38.0])
    for k in range(3):
        sp = step(c, k * PERIOD, x).setpoint
        assert np.allclose(sp.hip_rad, fixed, atol=1e-6) and np.allclose(sp.hip_rate_rad_s, 0.0)


@pytest.mark.parametrize("bad", [math.nan, math.inf])
def test_an_unusable_state_gives_hover_thrust_and_held_legs(bad):
    c = controller()
    x = rom.hover_state(AF)
    x[rom.V.start] = bad
    out = step(c, 0.0, x)
    assert out.nmpc is None
    assert np.allclose(out.setpoint.thrust_n, HOVER_N)
    assert np.allclose(out.setpoint.hip_rate_rad_s, 0.0)
    assert_safe(out.setpoint, [AF.thrust_max_n] * ROTOR_COUNT)


def test_before_the_flight_starts_no_solve_runs_and_the_answer_is_the_fallback():
    c = controller()
    out = c.step(0.0, rom.hover_state(AF))
    assert not c.started and out.nmpc is None and out.reference is None
    assert np.allclose(out.setpoint.thrust_n, HOVER_N)


def test_an_implausible_state_does_not_start_the_flight():
    c = controller()
    x = rom.hover_state(AF)
    x[rom.P.start] = math.nan
    assert not c.start(0.0, x) and not c.started
    assert c.start(0.1, rom.hover_state(AF)) and c.started


def test_the_injected_reference_and_detector_are_the_ones_flown_and_a_restart_builds_new_ones():
    anchors, detectors = [], []
    mission = Mission(waypoints=(Waypoint((5.0, 0.0, -2.0), 2.0, 0.0),))

    def new_reference(t0_s, start_ned_m):
        anchors.append((t0_s, tuple(start_ned_m)))
        return MissionReference(mission, start_ned_m, AF, t0_s=t0_s)

    def new_detector():
        detectors.append(FaultDetector(AF, CONFIG.fault_detector))
        return detectors[-1]

    _NMPC.reset()
    c = Controller(SETTINGS, nmpc=_NMPC, new_detector=new_detector, new_reference=new_reference)
    x = rom.hover_state(AF, p_ned_m=(0.0, 0.0, -2.0))
    assert c.start(3.0, x)
    out = c.step(3.0 + PERIOD, x)
    assert anchors == [(0.0, (0.0, 0.0, -2.0))] and c.detector is detectors[0]   # the mission's clock starts at the start
    assert c.flight.mission_time_s(3.0 + PERIOD) == pytest.approx(PERIOD)
    assert out.reference[-1, rom.P.start] > 0.0          # heading for the waypoint
    c.restart()
    assert not c.started and len(detectors) == 2 and c.detector is detectors[1]


def test_with_a_lead_the_nmpc_plans_from_the_state_predicted_to_when_the_setpoint_acts():
    """Flying at 1 m/s with setpoints acting 0.1 s after their instant: the state planned from
    is about 0.1 m further on, and without a lead it is the measured one."""
    c = controller()
    x = rom.hover_state(AF)
    x[rom.V] = (1.0, 0.0, 0.0)
    c.start(0.0, x)
    for k in range(8):
        measured = x.copy()
        measured[rom.P.start] += k * PERIOD
        out = c.step(k * PERIOD, measured, None, [AF.thrust_max_n] * 4, lead_s=0.1)
    assert out.lead_s == pytest.approx(0.1)
    assert out.state[rom.P.start] - measured[rom.P.start] == pytest.approx(0.1, abs=0.01)
    assert np.array_equal(c.step(8 * PERIOD, measured).state[rom.P], measured[rom.P])


@pytest.mark.parametrize("fc_says_rotor_4_n, torque_expected", [(HOVER_N, False), (0.0, True)])
def test_the_disturbance_estimate_compares_the_robot_with_what_the_fc_reports_it_commanded(fc_says_rotor_4_n,
                                                                                         torque_expected):
    """Our setpoints say hover; the FC reports what it actually commanded (a lost setpoint, a
    held one): a robot that stays level under a reported rotor 4 at 0 N needs a torque the
    model does not know, under the reported hover thrust it needs none."""
    c = controller()
    x = rom.hover_state(AF)
    reported = np.r_[np.full(3, HOVER_N), fc_says_rotor_4_n]
    for k in range(4):
        s = step(c, k * PERIOD, x, None, None, 0.0, reported)
    torque = np.abs(s.disturbance[3:5]).max()
    assert (torque > 0.05) == torque_expected, s.disturbance


@pytest.mark.parametrize("lead_s, moves", [(0.0, True), (None, False), (math.nan, False)])
def test_the_disturbance_estimate_waits_until_the_link_has_measured_the_lead(lead_s, moves):
    """A robot that stays level under a reported rotor 4 at 0 N needs a torque the model does
    not know; while the lead is unknown the estimate cannot tell which command the motion
    answers nor how slowly to move behind the delay, so it stays where it is."""
    c = controller()
    x = rom.hover_state(AF)
    reported = np.r_[np.full(3, HOVER_N), 0.0]
    for k in range(4):
        s = step(c, k * PERIOD, x, None, None, lead_s, reported)
    assert np.any(s.disturbance != 0.0) == moves, s.disturbance
    assert s.lead_s == 0.0


def test_the_real_time_iteration_feeds_back_what_prepare_built_after_the_last_send():
    rti = dataclasses.replace(SETTINGS, nmpc=dataclasses.replace(CONFIG.nmpc, scheme="rti"))
    c = Controller(rti)
    x = rom.hover_state(AF)
    x[rom.V] += (0.2, -0.1, 0.1)
    assert step(c, 0.0, x).nmpc.status == "rti_unprepared"        # nothing prepared before the first step
    c.prepare()
    prepared = step(c, PERIOD, x)
    assert prepared.nmpc.status == "rti" and prepared.nmpc.ok
    assert_safe(prepared.setpoint, [AF.thrust_max_n] * ROTOR_COUNT)
    assert step(c, 2 * PERIOD, x).nmpc.status == "rti_unprepared"  # no prepare() since the last step
    c.prepare()
    bad = x.copy()
    bad[rom.V.start] = np.nan
    assert step(c, 3 * PERIOD, bad).nmpc is None                  # no solve: what was prepared is stale
    c.prepare()
    assert step(c, 4 * PERIOD, x).nmpc.status == "rti_unprepared"


def test_the_fcs_hold_is_flown_where_the_robot_stops_and_the_mission_waits_for_it():
    c = controller(mission=Mission(waypoints=(Waypoint(ned_m=(10.0, 0.0, -2.0), speed_m_s=2.0, hold_s=0.0),)))
    moving = rom.hover_state(AF, p_ned_m=(1.0, 0.0, -2.0))
    moving[rom.V] = (1.0, 0.0, 0.0)
    modes = [FcMode.COMPANION] * 3 + [FcMode.HOLD] * 10 + [FcMode.COMPANION]
    outs = [step(c, k * PERIOD, moving, None, None, 0.0, None, False, mode) for k, mode in enumerate(modes)]
    assert [o.followed for o in outs] == [None] * 3 + [FcMode.HOLD] + [None] * 9 + [FcMode.COMPANION]
    held, last_held = outs[3], outs[12]
    stop_m = 1.0 + 1.0**2 / (2 * CONFIG.reference.accel_max_m_s2)        # braking from 1 m/s
    assert held.reference[0, rom.V][0] == pytest.approx(1.0)           # a brake, not a step
    np.testing.assert_allclose(last_held.reference[-1, rom.P], (stop_m, 0.0, -2.0), atol=1e-9)
    np.testing.assert_allclose(last_held.reference[-1, rom.V], 0.0, atol=1e-12)
    assert c.mission_progress(13 * PERIOD).time_s == pytest.approx(3 * PERIOD)     # the mission waited
    np.testing.assert_allclose(outs[13].reference[0, rom.P], c.flight.reference.state(3 * PERIOD)[0], atol=1e-12)


def test_the_fcs_land_is_flown_from_where_the_robot_is():
    c = controller()
    at = rom.hover_state(AF, p_ned_m=(3.0, 1.0, -2.0))
    step(c, 0.0, at)
    out = step(c, 0.02, at, None, None, 0.0, None, False, FcMode.LAND)
    assert out.followed is FcMode.LAND and c.flight.reference.landing_started(0.02)
    end = out.reference[-1]
    assert end[rom.P][:2] == pytest.approx((3.0, 1.0)) and end[rom.P][2] > -2.0 and end[rom.V][2] > 0.0


def test_after_prepare_the_next_step_finds_the_fcs_rate_feedback_and_cover_designed(monkeypatch):
    """prepare() designs them for the hip goal the next step starts from: that step's answer
    designs nothing, and sends what a step designing them itself sends."""
    c = controller()
    x = rom.hover_state(AF)
    x[rom.EULER] = (0.2, -0.1, 0.0)
    step(c, 0.0, x)
    c.prepare()
    fresh = controller()
    step(fresh, 0.0, x)
    designed = []
    for name in ("_design_gain", "_design_cover"):
        design = getattr(type(c.rate_feedback), name)
        monkeypatch.setattr(type(c.rate_feedback), name,
                            lambda self, *a, _design=design, _name=name: designed.append(_name) or _design(self, *a))
    sp = step(c, PERIOD, x).setpoint
    assert designed == []
    assert sp.rate_feedback is not None and sp.shortfall_cover is not None
    expected = step(fresh, PERIOD, x).setpoint
    assert designed == ["_design_gain", "_design_cover"]              # no prepare(): designed in the step
    assert np.array_equal(sp.rate_feedback.gain_n_per_rad_s, expected.rate_feedback.gain_n_per_rad_s)
    assert np.array_equal(sp.shortfall_cover.gain, expected.shortfall_cover.gain)


def test_what_only_the_next_step_needs_is_recorded_after_the_send():
    """A step's command (the history the next step's in-force command and prediction read) waits
    until its setpoint has left: prepare() records it, or else the next step first."""
    c = controller()
    x = rom.hover_state(AF)
    step(c, 0.0, x)
    assert c.sent.newest is None
    c.prepare()
    assert c.sent.newest.time_s == 0.0
    step(c, PERIOD, x)
    assert c.sent.newest.time_s == 0.0
    step(c, 2 * PERIOD, x)                       # no prepare() since the last step: recorded first
    assert c.sent.newest.time_s == PERIOD


def test_resume_drops_the_command_not_yet_recorded():
    """A command whose step came before the gap is stale: resume() forgets it rather than letting
    the next step or prepare() record it into the history."""
    c = controller()
    x = rom.hover_state(AF)
    step(c, 0.0, x)                              # no prepare(): its command is not recorded yet
    c.resume()
    step(c, PERIOD, x)
    c.prepare()
    assert c.sent.newest.time_s == PERIOD
    assert c.sent.in_force(0.0, 0.0) is None     # nothing from before the resume

def test_the_frame_left_for_after_the_send_is_read_once_by_read_deferred_not_by_prepare():
    c = controller()
    x = rom.hover_state(AF)
    step(c, 0.0, x, None, [AF.thrust_max_n] * 4)
    step(c, PERIOD, x, None, [AF.thrust_max_n] * 4)
    assert c.frame_unread                                          # a healthy frame at 50 Hz: left for later
    c.prepare()
    assert c.frame_unread                                          # the preparation does not read it
    status = c.read_deferred()
    assert status is not None and status.state is FaultState.HEALTHY and not c.frame_unread
    assert c.read_deferred() is None


class _EveryFrameBeforeTheSolve(FaultDetector):
    def cannot_confirm(self, *_args) -> bool:
        return False


def _rotor_4_lost(c: Controller, steps: int = 25):
    """The ROM flown by the controller's setpoints, step, read_deferred and prepare as the app
    calls them; rotor 4 delivers nothing from 0.1 s. Each step's (setpoint, confirmed now, status
    read_deferred() returned)."""
    plant = rom.build_rom(AF, PERIOD, substeps=4).step
    x, out, answers = rom.hover_state(AF), None, []
    for k in range(steps):
        if out is not None:
            sp = out.setpoint
            u = sp.thrust_n * np.array([1.0, 1.0, 1.0, 0.0 if k * PERIOD > 0.1 else 1.0])
            x = np.array(plant(x, np.r_[u, np.zeros(4)], np.zeros(rom.ND))).ravel()
            x[rom.HIP], x[rom.HIP_RATE] = sp.hip_rad + sp.hip_rate_rad_s * PERIOD, sp.hip_rate_rad_s
        out = step(c, k * PERIOD, x, None, [AF.thrust_max_n] * 4)
        answers.append((out.setpoint, out.fault_confirmed_now, c.read_deferred()))
        c.prepare()
    return answers


def test_a_frame_that_cannot_confirm_is_read_after_the_send_and_the_confirmation_stays_the_same():
    """The detector reads a frame that cannot confirm a fault after the send (read_deferred()
    returns its status then): the healthy frames and every frame after the confirmation. The step at
    which the fault is confirmed and bounds the NMPC, and the setpoints up to it, are those of
    a controller that reads every frame before the solve."""
    late = _rotor_4_lost(controller())
    _NMPC.reset()
    early = _rotor_4_lost(Controller(SETTINGS, nmpc=_NMPC, new_detector=lambda: _EveryFrameBeforeTheSolve(
        AF, SETTINGS.fault_detector, PropellerModel.from_airframe(AF), SETTINGS.nmpc.codegen)))
    read_after = [k for k, (_, _, status) in enumerate(late) if status is not None]
    assert read_after and read_after[0] <= 1 and all(status is None for _, _, status in early)
    confirmed = [k for k, (_, now, _) in enumerate(late) if now]
    assert confirmed == [k for k, (_, now, _) in enumerate(early) if now] and len(confirmed) == 1
    assert list(range(confirmed[0] + 1, len(late))) == [k for k in read_after if k > confirmed[0]]
    assert all(late[k][2].state is FaultState.CONFIRMED for k in range(confirmed[0] + 1, len(late)))
    for (a, _, _), (b, _, _) in zip(late[:confirmed[0] + 1], early):
        assert np.array_equal(a.thrust_n, b.thrust_n) and np.array_equal(a.hip_rad, b.hip_rad)
