"""The FC's fast loop on floats (sitl/fc/fast_loop.py) against m4.setpoint's numpy: the same
thrusts to rounding, and what it does with rates that are not finite."""

from __future__ import annotations

import math

import numpy as np
import pytest

from m4.airframe import load_airframe
from m4.setpoint import RateFeedback, Setpoint, ShortfallCover
from sitl.fc.fast_loop import FastLoop

AF = load_airframe()


def _setpoint(rng) -> Setpoint:
    return Setpoint(thrust_n=rng.uniform(0.0, AF.thrust_max_n, 4), hip_rad=np.zeros(4), hip_rate_rad_s=np.zeros(4),
                    rate_feedback=RateFeedback(rng.normal(0.0, 1.0, 3), rng.normal(0.0, 5.0, 3),
                                               rng.normal(0.0, 3.0, (4, 3))),
                    shortfall_cover=ShortfallCover(rng.normal(0.0, 0.5, (4, 4))))


@pytest.mark.parametrize("seed", range(5))
def test_the_thrusts_are_the_setpoints_sums_clamped(seed):
    rng = np.random.default_rng(seed)
    sp = _setpoint(rng)
    rates, shortfall = rng.normal(0.0, 1.0, 3), [0.0, 0.0, rng.uniform(0.0, 5.0), 0.0]
    in_force_s, period_s = rng.uniform(-0.01, 0.05), 0.02
    expected = np.clip(sp.thrust_n + sp.rate_feedback.thrust_change_n(rates, in_force_s, period_s)
                       + sp.shortfall_cover.thrust_change_n(shortfall), AF.thrust_min_n, AF.thrust_max_n)
    got = FastLoop(sp, AF.thrust_min_n, AF.thrust_max_n).thrust_n(rates, in_force_s, period_s, shortfall)
    assert got == pytest.approx(expected.tolist(), abs=1e-12)


def test_rates_that_are_not_finite_give_the_cover_alone():
    sp = _setpoint(np.random.default_rng(0))
    shortfall = [2.0, 0.0, 0.0, 0.0]
    got = FastLoop(sp, -math.inf, math.inf).thrust_n([math.nan, 0.0, 0.0], 0.01, 0.02, shortfall)
    assert got == pytest.approx((sp.thrust_n + sp.shortfall_cover.gain @ shortfall).tolist(), abs=1e-12)
