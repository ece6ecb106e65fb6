import math

import numpy as np
import pytest

from m4.airframe import load_airframe
from companion.core import rom
from companion.core.reference import MissionReference, ReferenceConfig
from companion.core.touchdown import TouchdownConfig, TouchdownDetector
from m4.mission import Landing, Mission, Waypoint
from m4.mission_plan import FC_LAND_SPEED_M_S, LANDING_SINK_M_S, PlanProgress, PlanState, ground_com_height_m

AF = load_airframe()
START = (0.0, 0.0, -2.0)
A_MAX = ReferenceConfig().accel_max_m_s2


def mission(*waypoints, on_fault="hold", land=None):
    return Mission(on_fault=on_fault, waypoints=tuple(Waypoint(*w) for w in waypoints), land=land)


def sunk_m(since_s):
    """How far below the standing height the landing's reference is since_s after it got there."""
    return LANDING_SINK_M_S * (since_s - 0.5 * LANDING_SINK_M_S / A_MAX)


def sample(ref, t_end, dt=0.01):
    t = np.arange(0.0, t_end, dt)
    states = [ref.state(tk) for tk in t]
    return t, np.array([s[0] for s in states]), np.array([s[1] for s in states])


def test_long_leg_cruises_at_the_leg_speed_along_the_leg():
    ref = MissionReference(mission(((12.0, 0.0, -2.0), 3.0, 1.0)), START, AF)
    _t, p, v = sample(ref, 8.0)
    speed = np.linalg.norm(v, axis=1)
    assert speed.max() == pytest.approx(3.0, abs=1e-9)
    cruise = speed > 3.0 - 1e-9
    # 12 m, 3 m/s, 2 m/s^2: 0.75 s ramps of 2.25 m each, 7.5 m of cruise = 2.5 s
    assert cruise.sum() * 0.01 == pytest.approx(2.5, abs=0.02)
    assert np.allclose(p[:, 1:], [0.0, -2.0])
    assert np.all(v[:, 0] >= 0)


def test_short_leg_peaks_below_the_leg_speed_with_bounded_acceleration():
    ref = MissionReference(mission(((1.0, 0.0, -2.0), 5.0, 0.0)), START, AF)
    _t, _p, v = sample(ref, 3.0)
    assert np.linalg.norm(v, axis=1).max() <= math.sqrt(A_MAX * 1.0) + 1e-9
    assert ref.state(math.sqrt(1.0 / A_MAX))[1][0] == pytest.approx(math.sqrt(A_MAX * 1.0))   # peak mid-leg
    assert np.abs(np.diff(v, axis=0) / 0.01).max() <= A_MAX + 1e-6


def test_holds_each_waypoint_for_its_hold_time_then_flies_the_next_leg():
    ref = MissionReference(mission(((2.0, 0.0, -2.0), 2.0, 1.5), ((2.0, 2.0, -3.0), 2.0, 0.0)), START, AF)
    _t, p, v = sample(ref, 10.0)
    at_first = np.all(np.isclose(p, [2.0, 0.0, -2.0]), axis=1) & (np.linalg.norm(v, axis=1) == 0)
    assert at_first.sum() * 0.01 == pytest.approx(1.5, abs=0.02)
    assert np.allclose(p[-1], [2.0, 2.0, -3.0]) and np.allclose(v[-1], 0.0)


def test_after_the_last_waypoint_the_reference_holds_it():
    ref = MissionReference(mission(((3.0, 4.0, -2.0), 2.0, 0.0)), START, AF)
    p, v = ref.state(1e3)
    assert np.allclose(p, [3.0, 4.0, -2.0]) and np.allclose(v, 0.0)


def test_reference_is_continuous_and_acceleration_limited_over_a_whole_mission():
    m = mission(((12.0, 0.0, -2.0), 3.0, 1.0), ((12.0, 6.0, -4.0), 3.0, 0.5), ((0.0, 0.0, -2.0), 2.0, 0.0),
                land=Landing(at_s=20.0, descent_speed_m_s=0.5))
    ref = MissionReference(m, START, AF)
    dt = 0.005
    _t, p, v = sample(ref, 30.0, dt)
    assert np.abs(np.diff(p, axis=0)).max() <= 3.0 * dt + 1e-9          # no position jump
    assert np.linalg.norm(np.diff(v, axis=0), axis=1).max() <= A_MAX * dt + 1e-9  # no velocity jump
    assert np.allclose(np.diff(p, axis=0), 0.5 * (v[1:] + v[:-1]) * dt, atol=A_MAX * dt**2)  # v is dp/dt


def test_reference_rows_carry_position_velocity_and_nominal_hips():
    ref = MissionReference(mission(((12.0, 0.0, -2.0), 3.0, 0.0)), START, AF)
    rows = ref.reference(1.0, 5, 0.1)
    assert rows.shape == (6, rom.NX)
    for k in range(6):
        p, v = ref.state(1.0 + 0.1 * k)
        assert np.allclose(rows[k, rom.P], p) and np.allclose(rows[k, rom.V], v)
    assert np.allclose(rows[:, rom.HIP], AF.nominal_hip_rad)
    assert np.all(rows[:, rom.EULER] == 0) and np.all(rows[:, rom.RATES] == 0)


def test_hold_on_fault_brakes_from_the_measured_position_then_holds():
    ref = MissionReference(mission(((12.0, 0.0, -2.0), 3.0, 0.0)), START, AF)
    _, v_before = ref.state(2.0)
    assert v_before[0] == pytest.approx(3.0)
    measured = np.array([4.0, 0.3, -1.8])
    ref.fault_detected(2.0, measured)
    p, v = ref.state(2.0)
    assert np.allclose(p, measured) and np.allclose(v, v_before)      # no demand of an instant stop
    stop = measured + np.array([3.0**2 / (2 * A_MAX), 0.0, 0.0])
    p_end, v_end = ref.state(2.0 + 3.0 / A_MAX + 5.0)
    assert np.allclose(p_end, stop) and np.allclose(v_end, 0.0)
    _, v_mid = ref.state(2.0 + 0.5)
    assert v_mid[0] == pytest.approx(3.0 - A_MAX * 0.5)


def test_the_rows_asked_for_again_are_the_ones_kept_until_the_plan_changes():
    ref = MissionReference(mission(((12.0, 0.0, -2.0), 3.0, 0.0)), START, AF)
    rows = ref.reference(2.0, 5, 0.1)
    assert ref.reference(2.0, 5, 0.1) is rows and not rows.flags.writeable      # made once, shared read-only
    assert ref.reference(2.0, 4, 0.1).shape == (5, rom.NX)                        # other arguments: made anew
    before = ref.reference(2.0, 5, 0.1)
    ref.fault_detected(2.0, np.array([4.0, 0.3, -1.8]))                           # a new plan: the hold's rows
    held = ref.reference(2.0, 5, 0.1)
    assert held is not before and np.allclose(held[0, rom.P], [4.0, 0.3, -1.8])
    assert not np.allclose(held[:, rom.P], before[:, rom.P])


def test_continue_on_fault_keeps_the_mission():
    ref = MissionReference(mission(((12.0, 0.0, -2.0), 3.0, 0.0), on_fault="continue"), START, AF)
    before = ref.reference(2.0, 40, 0.1)
    ref.fault_detected(2.0, (4.0, 0.3, -1.8))
    assert np.array_equal(ref.reference(2.0, 40, 0.1), before)


def test_landing_descends_at_the_descent_speed_to_the_standing_height():
    ref = MissionReference(mission(((2.0, 0.0, -2.0), 2.0, 0.0), land=Landing(at_s=5.0, descent_speed_m_s=0.5)),
                           START, AF)
    _t, p, v = sample(ref, 15.0)
    assert not ref.landing_started(4.99) and ref.landing_started(5.0)
    assert v[:, 2].max() == pytest.approx(0.5)
    cruise = np.isclose(v[:, 2], 0.5)
    assert cruise.sum() * 0.01 == pytest.approx((2.0 - ground_com_height_m(AF)) / 0.5 - 0.5 / A_MAX, abs=0.03)
    ground_z = -ground_com_height_m(AF)
    down_s = 5.0 + (2.0 - ground_com_height_m(AF)) / 0.5 + 0.5 / A_MAX
    assert ref.state(8.0)[0][2] < ground_z - 0.05
    assert ref.state(down_s)[0][2] == pytest.approx(ground_z) and np.allclose(ref.state(down_s)[1], 0.0)


def test_landing_sinks_on_below_the_standing_height_until_the_touchdown():
    """A robot tracking the plan a few centimetres high still meets the ground."""
    ref = MissionReference(mission(((2.0, 0.0, -2.0), 2.0, 0.0), land=Landing(at_s=5.0, descent_speed_m_s=0.5)),
                           START, AF)
    down_s = 5.0 + (2.0 - ground_com_height_m(AF)) / 0.5 + 0.5 / A_MAX
    _t, p, v = sample(ref, down_s + 3.0)
    assert np.linalg.norm(np.diff(v, axis=0), axis=1).max() <= A_MAX * 0.01 + 1e-9
    p_end, v_end = ref.state(down_s + 3.0)
    assert np.allclose(v_end, [0.0, 0.0, LANDING_SINK_M_S]) and np.allclose(p_end[:2], [2.0, 0.0])
    assert p_end[2] == pytest.approx(-ground_com_height_m(AF) + sunk_m(3.0))


def test_landing_while_moving_brakes_first():
    ref = MissionReference(mission(((20.0, 0.0, -2.0), 3.0, 0.0), land=Landing(at_s=3.0, descent_speed_m_s=0.5)),
                           START, AF)
    t, p, v = sample(ref, 12.0)
    assert np.linalg.norm(np.diff(v, axis=0), axis=1).max() <= A_MAX * 0.01 + 1e-9
    assert np.all(v[t >= 3.0, 0] <= 3.0 + 1e-9) and p[-1, 0] < 20.0


def test_fault_after_landing_started_keeps_the_landing():
    ref = MissionReference(mission(((2.0, 0.0, -2.0), 2.0, 0.0), land=Landing(at_s=5.0, descent_speed_m_s=0.5)),
                           START, AF)
    before = ref.reference(6.0, 30, 0.1)
    ref.fault_detected(6.0, (2.5, 0.0, -1.5))
    assert np.array_equal(ref.reference(6.0, 30, 0.1), before)


def test_landing_after_a_fault_hold_descends_from_the_hold_position():
    ref = MissionReference(mission(((12.0, 0.0, -2.0), 3.0, 0.0), land=Landing(at_s=8.0, descent_speed_m_s=0.5)),
                           START, AF)
    ref.fault_detected(2.0, (4.0, 0.0, -2.0))
    p, _ = ref.state(20.0)
    assert np.allclose(p[:2], [4.0 + 9.0 / (2 * A_MAX), 0.0]) and p[2] > -ground_com_height_m(AF)


def test_ground_height_is_the_hull_bottom_for_the_reference_airframe():
    assert ground_com_height_m(AF) == pytest.approx(AF.body_box_size_m[2] / 2)


def test_touchdown_needs_ground_height_and_stillness_for_the_dwell_time():
    ground = -0.075
    det = TouchdownDetector(ground)
    dwell = TouchdownConfig().dwell_s
    assert not det.update(0.0, ground - 0.2, 0.3)           # descending above the ground
    assert not det.update(0.1, ground - 0.01, 0.0)
    assert not det.update(0.1 + dwell / 2, ground, 0.02)
    assert not det.update(0.1 + dwell / 2 + 0.05, ground, 0.5)  # a bounce restarts the dwell
    t0 = 0.2 + dwell
    assert not det.update(t0, ground, 0.0)
    assert not det.update(t0 + dwell - 0.05, ground, 0.0)
    assert det.update(t0 + dwell, ground + 0.01, 0.0)
    assert det.touchdown_s == pytest.approx(t0 + dwell)
    assert det.update(t0 + dwell + 1.0, -5.0, 1.0)            # latched


def test_hovering_above_the_tolerance_is_not_a_touchdown():
    det = TouchdownDetector(-0.075)
    assert not any(det.update(0.1 * k, -0.075 - 0.1, 0.0) for k in range(20))


def test_joining_the_fcs_landing_descends_from_where_the_robot_is_at_the_fcs_speed():
    ref = MissionReference(mission(((12.0, 0.0, -2.0), 3.0, 0.0)), START, AF)
    ref.land_from(2.0, (4.0, 0.5, -1.4))
    assert not ref.landing_started(1.99) and ref.landing_started(2.0)
    p, v = ref.state(2.0)
    assert np.allclose(p, [4.0, 0.5, -1.4]) and np.allclose(v, 0.0)
    speeds = [ref.state(t)[1][2] for t in np.arange(2.0, 5.0, 0.01)]
    assert max(speeds) == pytest.approx(FC_LAND_SPEED_M_S)
    down_s = 2.0 + (1.4 - ground_com_height_m(AF)) / FC_LAND_SPEED_M_S + FC_LAND_SPEED_M_S / A_MAX
    assert np.allclose(ref.state(down_s)[0], [4.0, 0.5, -ground_com_height_m(AF)])
    assert ref.state(10.0)[0][2] == pytest.approx(-ground_com_height_m(AF) + sunk_m(10.0 - down_s))
    ref.fault_detected(3.0, (4.0, 0.5, -1.0))                       # during the landing: nothing changes
    assert ref.progress == PlanProgress(PlanState.LANDING, 0.0, START, 2.0, (4.0, 0.5, -1.4))
    ref.land_from(4.0, (4.0, 0.5, -0.6))                              # the FC landed it further meanwhile
    assert np.allclose(ref.state(4.0)[0], [4.0, 0.5, -0.6]) and ref.progress.change_time_s == 4.0


@pytest.mark.parametrize("change", [
    lambda ref: ref.fault_detected(2.0, (4.0, 0.3, -1.8)),
    lambda ref: ref.land_from(2.5, (4.5, 0.0, -1.6)),
])
def test_a_plan_restored_from_its_progress_is_the_same_plan(change):
    """What a restarted companion makes of the progress the FC kept."""
    ways = mission(((12.0, 0.0, -2.0), 3.0, 0.0), land=Landing(at_s=8.0, descent_speed_m_s=0.5))
    ref = MissionReference(ways, START, AF, t0_s=0.5)
    change(ref)
    again = MissionReference(ways, ref.progress.start_ned_m, AF, t0_s=ref.progress.start_time_s)
    again.restore(ref.progress)
    assert again.progress == ref.progress
    assert np.array_equal(again.reference(2.5, 100, 0.1), ref.reference(2.5, 100, 0.1))
