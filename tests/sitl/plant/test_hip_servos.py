"""The hip reference keeps the servo's rate and acceleration limits exactly and stops on target."""

import math

import numpy as np
import pytest

from sitl.plant.hip_servos import HipReference

RATE, ACCEL, PERIOD = 6.0, 50.0, 0.005
LO, HI = 0.0, math.pi / 2


def run(ref, periods):
    out = []
    for _ in range(periods):
        ref.advance()
        out.append((list(ref.pos_rad), list(ref.rate_rad_s)))
    pos, rate = (np.array(x) for x in zip(*out))
    return pos, rate


def new(q0):
    return HipReference(q0, rate_max_rad_s=RATE, accel_max_rad_s2=ACCEL, hip_min_rad=LO, hip_max_rad=HI,
                        dt_s=PERIOD)


def test_moves_to_targets_within_the_limits_and_stops_exactly_on_them():
    ref = new([0.785] * 4)
    target = [HI, LO, 0.785, 1.0]
    ref.set_target(target, [0.0] * 4)
    pos, rate = run(ref, 200)
    assert ref.settled
    assert pos[-1] == pytest.approx(target, abs=1e-12)
    assert np.abs(rate).max() <= RATE + 1e-12
    assert np.abs(np.diff(np.vstack([np.zeros(4), rate]), axis=0)).max() / PERIOD <= ACCEL * (1 + 1e-9)
    assert pos.min() >= LO and pos.max() <= HI                     # never past the target at a stop
    assert np.abs(rate[:, 1]).max() == pytest.approx(RATE)         # the long move reaches full speed


def test_a_long_move_takes_the_time_optimal_duration():
    ref = new([0.0] * 4)
    ref.set_target([HI] * 4, [0.0] * 4)
    pos, _ = run(ref, 200)
    arrived = np.flatnonzero(np.abs(pos[:, 0] - HI) < 1e-12)[0] + 1
    # Accelerate to RATE, cruise, brake: HI / RATE + RATE / ACCEL seconds.
    assert arrived * PERIOD == pytest.approx(HI / RATE + RATE / ACCEL, abs=2 * PERIOD)


def test_a_moving_target_is_tracked_at_its_rate_and_stays_in_range():
    ref = new([0.3] * 4)
    ref.set_target([0.3, 0.3, 1.5, 0.3], [0.5, -0.5, 1.0, 0.0])
    pos, rate = run(ref, 200)                                      # 1 s
    assert pos[-1, 0] == pytest.approx(0.8, abs=1e-9)
    assert rate[-1, 0] == pytest.approx(0.5)
    assert pos[-1, 1] == pytest.approx(LO) and rate[-1, 1] == 0.0  # ran into the range: held there
    assert pos[-1, 2] == pytest.approx(HI) and rate[-1, 2] == 0.0


def test_targets_and_rates_are_clamped_to_the_range_and_the_rate_limit():
    ref = new([0.5] * 4)
    ref.set_target([-1.0, 3.0, 0.5, 0.5], [0.0, 0.0, 100.0, -100.0])
    pos, rate = run(ref, 100)
    assert np.abs(rate).max() <= RATE + 1e-12
    assert pos.min() >= LO and pos.max() <= HI
