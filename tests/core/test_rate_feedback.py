"""The rate feedback the companion hands the FC: the torque it asks for, from the live rotors,
without changing their sum; the planned rates from the plan."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from companion.core import rom
from companion.core.rate_feedback import RateFeedbackDesign
from m4.airframe import load_airframe
from m4.setpoint import (EFFECTIVENESS_MAX_RAD_S2_PER_N, RATE_GAIN_MAX_N_PER_RAD_S, SHORTFALL_GAIN_MAX, RateFeedback,
                         ShortfallCover)

AF = load_airframe()
BW = 20.0
ALL_LIVE = np.full(4, AF.thrust_max_n)
DESIGN = RateFeedbackDesign(AF, BW)


def torque_and_sum(hip, thrust_change):
    com, _ = rom.mass_properties(AF, ca.DM(hip))
    arms = np.asarray(rom.thruster_positions(AF, ca.DM(hip)) - ca.repmat(com, 1, 4))
    return np.array([-(arms[1] * thrust_change).sum(), (arms[0] * thrust_change).sum()]), thrust_change.sum()


@pytest.mark.parametrize("hip_deg", [[45, 45, 45, 45], [87, 2, 53, 23]])
@pytest.mark.parametrize("lost", [None, 3])
def test_a_rate_error_asks_for_bandwidth_times_inertia_from_the_live_rotors_at_constant_sum(hip_deg, lost):
    hip = np.radians(hip_deg)
    bound = ALL_LIVE.copy()
    if lost is not None:
        bound[lost] = AF.thrust_min_n
    gain = DESIGN.gain(hip, bound)
    _, inertia = rom.mass_properties(AF, ca.DM(hip))
    for error in ([1.0, 0.0, 0.0], [0.0, -0.5, 0.0], [0.3, 0.2, 5.0]):
        change = gain @ np.array(error)
        torque, total = torque_and_sum(hip, change)
        assert torque == pytest.approx(BW * np.asarray(inertia)[:2, :2] @ np.array(error[:2]), abs=1e-9)
        assert total == pytest.approx(0.0, abs=1e-9)
    assert np.all(gain[:, 2] == 0.0)                       # yaw is left to the plan
    if lost is not None:
        assert np.all(gain[lost] == 0.0)


def test_no_feedback_with_fewer_than_three_live_rotors_or_no_bandwidth():
    two_lost = ALL_LIVE.copy()
    two_lost[[1, 3]] = 0.0
    assert DESIGN.gain(np.full(4, AF.nominal_hip_rad), two_lost) is None
    assert RateFeedbackDesign(AF, 0.0).gain(np.full(4, AF.nominal_hip_rad), ALL_LIVE) is None


def test_planned_rates_are_the_plans_start_and_their_change_its_next_node():
    x0, x1 = rom.hover_state(AF), rom.hover_state(AF)
    x0[rom.RATES] = [0.5, -0.25, 3.0]
    x1[rom.RATES] = [0.0, 0.25, 3.5]
    fb = DESIGN.feedback(x0, x1, 0.1, ALL_LIVE)
    assert fb.rates_ref_frd_rad_s == pytest.approx([0.5, -0.25, 3.0])
    assert fb.rates_ref_change_frd_rad_s2 == pytest.approx([-5.0, 5.0, 5.0])
    assert np.all(fb.gain_n_per_rad_s.astype(np.float32) == fb.gain_n_per_rad_s)   # as MAVLink carries it


@pytest.mark.filterwarnings("error")
@pytest.mark.parametrize("rate_rad_s", [np.inf, np.nan, 1e39])        # 1e39 rad/s: beyond what float32 carries
def test_no_feedback_for_a_planned_rate_mavlink_cannot_carry(rate_rad_s):
    x0, x1 = rom.hover_state(AF), rom.hover_state(AF)
    x1[rom.RATES] = [rate_rad_s, 0.0, 0.0]
    assert DESIGN.feedback(x0, x1, 0.1, ALL_LIVE) is None


def test_the_fc_side_reads_no_feedback_from_zero_or_unusable_fields_and_holds_the_plan_after_the_period():
    zeros, three = np.zeros(12), np.zeros(3)
    assert RateFeedback.from_fields(three, three, zeros) is None
    assert RateFeedback.from_fields([np.nan, 0, 0], three, np.ones(12)) is None
    assert RateFeedback.from_fields(three, three, np.full(12, 2 * RATE_GAIN_MAX_N_PER_RAD_S)) is None
    fb = RateFeedback.from_fields([1.0, 0, 0], [10.0, 0, 0], np.r_[1.0, np.zeros(11)])
    assert fb.thrust_change_n(np.zeros(3), 0.01, 0.02)[0] == pytest.approx(1.1)
    assert fb.thrust_change_n(np.zeros(3), 0.5, 0.02)[0] == pytest.approx(1.2)
    assert np.all(fb.thrust_change_n([np.nan, 0, 0], 0.0, 0.02) == 0.0)


COVERING = RateFeedbackDesign(AF, BW, shortfall_cover=True)


@pytest.mark.parametrize("hip_deg", [[45, 45, 45, 45], [87, 2, 53, 23]])
def test_the_other_three_rotors_cover_a_shortfall_keeping_sum_and_roll_and_pitch_torque(hip_deg):
    hip = np.radians(hip_deg)
    cover = COVERING.cover(hip, fault_confirmed=False)
    for short in range(4):
        shortfall = np.zeros(4)
        shortfall[short] = 5.0
        delivered_change = cover.thrust_change_n(shortfall) - shortfall
        torque, total = torque_and_sum(hip, delivered_change)
        assert torque == pytest.approx([0.0, 0.0], abs=1e-5)
        assert total == pytest.approx(0.0, abs=1e-5)
        assert cover.gain[short, short] == 0.0             # a rotor never covers itself
    assert np.all(cover.gain.astype(np.float32) == cover.gain)   # as MAVLink carries it


@pytest.mark.parametrize("hip_deg", [[45, 45, 45, 45], [87, 2, 53, 23]])
def test_with_the_cover_goes_the_roll_and_pitch_acceleration_each_rotor_gives_per_newton(hip_deg):
    """As the ROM has it: its angular acceleration per newton of one rotor, from rest."""
    hip = np.radians(hip_deg)
    f = rom.dynamics(AF)
    x, u = rom.hover_state(AF, hip_rad=hip), rom.hover_input(AF)
    accel = lambda u: np.asarray(f(x, u, np.zeros(rom.ND))).ravel()[rom.RATES][:2]
    effectiveness = COVERING.cover(hip, fault_confirmed=False).effectiveness_frd_rad_s2_per_n
    for rotor in range(4):
        more = u.copy()
        more[rom.THRUST.start + rotor] += 1.0
        assert effectiveness[:, rotor] == pytest.approx(accel(more) - accel(u), rel=1e-6, abs=1e-6)
    assert np.all(effectiveness.astype(np.float32) == effectiveness)   # as MAVLink carries it


def test_no_cover_when_switched_off_or_once_a_fault_is_confirmed():
    """A confirmed fault is in the plan (a damaged propeller keeps a bound above hover, its
    effectiveness modelled): covering it too would count its shortfall twice."""
    hip = np.full(4, AF.nominal_hip_rad)
    assert COVERING.cover(hip, fault_confirmed=False) is not None
    assert COVERING.cover(hip, fault_confirmed=True) is None
    assert DESIGN.cover(hip, fault_confirmed=False) is None


def test_the_fc_side_reads_no_cover_from_zero_or_unusable_fields():
    assert ShortfallCover.from_fields(np.zeros(16)) is None
    assert ShortfallCover.from_fields(np.r_[np.nan, np.ones(15)]) is None
    assert ShortfallCover.from_fields(np.full(16, 2 * SHORTFALL_GAIN_MAX)) is None
    cover = ShortfallCover.from_fields(np.r_[0.0, 0.0, 0.0, 1.0, np.zeros(12)])
    assert cover.thrust_change_n([0.0, 0.0, 0.0, 3.0]) == pytest.approx([3.0, 0.0, 0.0, 0.0])
    assert cover.effectiveness_frd_rad_s2_per_n is None


def test_the_fc_side_reads_the_effectiveness_by_rotor_and_leaves_an_unusable_one_out_alone():
    gain = np.r_[0.0, 0.0, 0.0, 1.0, np.zeros(12)]
    by_rotor = [1.0, -2.0, 3.0, -4.0, 5.0, -6.0, 7.0, -8.0]           # rotor 1 x, y, rotor 2 x, y, ...
    cover = ShortfallCover.from_fields(gain, by_rotor)
    assert np.array_equal(cover.effectiveness_frd_rad_s2_per_n, [[1.0, 3.0, 5.0, 7.0], [-2.0, -4.0, -6.0, -8.0]])
    for unusable in (np.zeros(8), np.r_[np.nan, np.ones(7)], np.full(8, 2 * EFFECTIVENESS_MAX_RAD_S2_PER_N)):
        cover = ShortfallCover.from_fields(gain, unusable)
        assert cover is not None and cover.effectiveness_frd_rad_s2_per_n is None


def test_a_prepared_design_is_the_one_its_posture_gets_and_another_posture_gets_its_own():
    design = RateFeedbackDesign(AF, BW, shortfall_cover=True)
    hip, lost = np.radians([87.0, 2.0, 53.0, 23.0]), ALL_LIVE.copy()
    lost[3] = AF.thrust_min_n
    design.prepare(hip, ALL_LIVE, False)
    gain, cover = design.gain(hip.copy(), ALL_LIVE), design.cover(hip.copy(), False)
    assert design.gain(hip, ALL_LIVE) is gain and design.cover(hip, False) is cover
    fresh = RateFeedbackDesign(AF, BW, shortfall_cover=True)
    for posture, bound in ((hip, lost), (hip + 0.01, ALL_LIVE)):
        assert np.array_equal(design.gain(posture, bound), fresh.gain(posture, bound))
    assert design.cover(hip, True) is None
    assert np.array_equal(design.cover(hip + 0.01, False).gain, fresh.cover(hip + 0.01, False).gain)
