"""Altitude before place: while its plans saturate the rotors for want of thrust (a shortfall
in the disturbance estimate), the NMPC gives the horizontal position up first."""

import numpy as np
import pytest

from m4.airframe import load_airframe
from companion.core import rom
from companion.core.altitude_first import ENTER_S, LEAVE_S, AltitudeFirst
from companion.core.nmpc import Nmpc
from companion.core.nmpc_config import NmpcConfig

AF = load_airframe()
N = 5
PERIOD_S = 0.02
WEIGHT_N = AF.total_mass_kg * AF.gravity_m_s2
WEAK = np.full(4, 20.0)                        # a sagging pack: 80 N for 59 N of weight
CEILING = np.full(4, 15.5)                     # so weak that the push alone saturates two rotors
PUSH_N, SHORTFALL_N = 15.0, 15.0               # the air's push north; thrust the rotors do not deliver


def planned_tilt_deg(res) -> float:
    roll, pitch = res.x_pred[:, rom.EULER.start], res.x_pred[:, rom.EULER.start + 1]
    return float(np.degrees(np.arccos(np.cos(roll) * np.cos(pitch))).max())


def tilts_over(nmpc, bound_n, disturbance, seconds) -> list[float]:
    """The planned tilt of every solve from a hover on its reference, the state held (the
    real-time iteration prepares each next solve in between, as the companion does)."""
    x0 = rom.hover_state(AF)
    ref = np.tile(x0, (N + 1, 1))
    nmpc.reset()
    tilts = []
    for _ in range(round(seconds / PERIOD_S)):
        tilts.append(planned_tilt_deg(nmpc.solve(x0, ref, bound_n, disturbance)))
        nmpc.prepare(ref, bound_n, disturbance)
    return tilts


@pytest.fixture(scope="module", params=["sqp", "rti"])
def nmpc(request):
    """Both schemes: the RTI's QP is prepared on a kept solver workspace, its Hessian loaded again
    at every preparation (companion.core.feedback_qp), so a switch of the weights must reach it."""
    return Nmpc(AF, NmpcConfig(scheme=request.param, control_period_s=PERIOD_S))


def test_saturated_by_a_shortfall_the_plan_leans_less_and_gives_the_place_up(nmpc):
    short = tilts_over(nmpc, WEAK, np.array([PUSH_N, 0.0, SHORTFALL_N, 0.0, 0.0, 0.0]), 2 * ENTER_S)
    assert short[-1] < short[0] - 3.0              # 14 deg against the push, then 9.5
    # Saturated without a shortfall (the rotors' own ceiling, rotors 1 and 3 at 15.5 N): the place is kept.
    ceiling = tilts_over(nmpc, CEILING, np.array([PUSH_N, 0.0, 0.0, 0.0, 0.0, 0.0]), 2 * ENTER_S)
    assert ceiling[-1] == pytest.approx(ceiling[0], abs=0.5)


def test_a_plan_says_whether_it_gave_the_place_up(nmpc):
    x0 = rom.hover_state(AF)
    ref = np.tile(x0, (N + 1, 1))
    shortfall = np.array([PUSH_N, 0.0, SHORTFALL_N, 0.0, 0.0, 0.0])
    nmpc.reset()
    said = []
    for _ in range(2 * round(ENTER_S / PERIOD_S)):
        said.append(nmpc.solve(x0, ref, WEAK, shortfall).altitude_first)
        nmpc.prepare(ref, WEAK, shortfall)
    assert not said[0] and said[-1]
    nmpc.reset()
    assert not nmpc.solve(x0, ref, WEAK, shortfall).altitude_first


def saturated(mode: AltitudeFirst, plans: int, down_n: float = SHORTFALL_N, thrust_n=(20.0, 20.0, 12.0, 0.0),
              bound_n=(20.0, 20.0, 20.0, 0.0)) -> bool:
    for _ in range(plans):
        mode.update(np.array(thrust_n), np.array(bound_n), down_n)
    return mode.active


def test_the_mode_starts_after_enter_s_of_saturated_plans_and_ends_leave_s_after_the_last():
    mode = AltitudeFirst(PERIOD_S, WEIGHT_N)
    enter, leave = round(ENTER_S / PERIOD_S), round(LEAVE_S / PERIOD_S)
    assert not saturated(mode, enter - 1)
    assert saturated(mode, 1)
    assert saturated(mode, leave - 1, thrust_n=(15.0, 15.0, 12.0, 0.0))
    assert not saturated(mode, 1, thrust_n=(15.0, 15.0, 12.0, 0.0))
    mode.update(np.array([20.0, 20.0, 12.0, 0.0]), np.array([20.0, 20.0, 20.0, 0.0]), SHORTFALL_N)
    mode.reset()
    assert not saturated(mode, enter - 1)


@pytest.mark.parametrize("case", [
    {"down_n": 0.1 * WEIGHT_N},                                            # no shortfall to speak of
    {"thrust_n": (20.0, 15.0, 12.0, 0.0)},                                 # one rotor at its bound
    {"thrust_n": (20.0, 15.0, 12.0, 0.0), "bound_n": (20.0, 20.0, 20.0, 0.2)},   # nor a lost one's 0
])
def test_without_two_rotors_at_their_bound_and_a_shortfall_it_never_starts(case):
    assert not saturated(AltitudeFirst(PERIOD_S, WEIGHT_N), 5 * round(ENTER_S / PERIOD_S), **case)


def test_a_bad_period_is_refused_by_name():
    with pytest.raises(ValueError, match="period_s"):
        AltitudeFirst(0.0, WEIGHT_N)
