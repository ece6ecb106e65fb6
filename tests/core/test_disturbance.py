"""The disturbance estimator recovers forces and torques the model does not know."""

import dataclasses
import math

import numpy as np
import pytest

from m4.airframe import load_airframe
from companion.core import rom
from companion.core.disturbance import DisturbanceEstimator

AF = load_airframe()
PERIOD = 0.02
PLANT = rom.build_rom(AF, PERIOD, substeps=4).step


def run(estimator, d_true, steps=80, x=None, u=None):
    x = rom.hover_state(AF) if x is None else x
    u = rom.hover_input(AF) if u is None else u
    for _ in range(steps):
        x_next = np.asarray(PLANT(x, u, d_true)).ravel()
        est = estimator.update(x, u, x_next)
        x = x_next
    return est


def test_a_constant_wind_force_is_recovered():
    d_true = np.array([2.0, -1.5, 0.8, 0.0, 0.0, 0.0])
    est = run(DisturbanceEstimator(AF, PERIOD, gain=0.3), d_true)
    assert est == pytest.approx(d_true, abs=0.02)


def test_a_constant_torque_is_recovered_even_while_the_robot_spins():
    d_true = np.array([0.0, 0.0, 0.0, 0.05, -0.08, 0.1])
    x = rom.hover_state(AF)
    x[rom.RATES] = [0.0, 0.0, 8.0]
    est = run(DisturbanceEstimator(AF, PERIOD, gain=0.3), d_true, x=x)
    assert est == pytest.approx(d_true, abs=0.005)


def test_a_heavier_robot_shows_up_as_a_downward_force():
    heavy = rom.build_rom(dataclasses.replace(AF, body_mass_kg=AF.body_mass_kg * 1.1), PERIOD, 4).step
    est_filter = DisturbanceEstimator(AF, PERIOD, gain=0.3)
    x, u = rom.hover_state(AF), rom.hover_input(AF)
    for _ in range(60):
        x_next = np.asarray(heavy(x, u, np.zeros(6))).ravel()
        est = est_filter.update(x, u, x_next)
        x = x_next
    # Same thrust, 10 % more hull mass: the model needs an extra weight of about the missing
    # acceleration times its own mass, pointing down (NED +z).
    m, m_plant = AF.total_mass_kg, AF.total_mass_kg + 0.1 * AF.body_mass_kg
    expected = m * AF.gravity_m_s2 * (1 - m / m_plant)
    assert est[2] == pytest.approx(expected, rel=0.05)
    assert np.abs(est[:2]).max() < 0.01


def test_a_thrust_shortfall_beyond_half_the_weight_is_recovered():
    # Tilted into 13-17 m/s of air the rotors lose up to half their thrust to the inflow (the
    # plant's law): the NMPC must know all of it, not a share clipped at half the weight.
    weight_n = AF.total_mass_kg * AF.gravity_m_s2
    d_true = np.array([0.3 * weight_n, 0.0, 0.7 * weight_n, 0.0, 0.0, 0.0])
    est = run(DisturbanceEstimator(AF, PERIOD, gain=0.3), d_true, steps=60)
    assert est == pytest.approx(d_true, abs=0.05)


def test_the_estimate_is_bounded():
    est = DisturbanceEstimator(AF, PERIOD, gain=1.0, force_max_n=5.0, torque_max_n_m=0.2)
    out = run(est, np.array([50.0, 0.0, 0.0, 3.0, 0.0, 0.0]), steps=20)
    assert out[0] == pytest.approx(5.0) and out[3] == pytest.approx(0.2)


def test_gain_sets_how_fast_it_follows():
    d_true = np.array([3.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    slow = run(DisturbanceEstimator(AF, PERIOD, gain=0.05), d_true, steps=5)
    fast = run(DisturbanceEstimator(AF, PERIOD, gain=0.5), d_true, steps=5)
    assert 0 < slow[0] < fast[0] <= 3.0 + 1e-6
    assert slow[0] == pytest.approx(3.0 * (1 - 0.95 ** 5), rel=0.05)    # first-order filter


def test_gain_scale_slows_the_estimate_as_a_lower_gain_would():
    d_true = np.array([3.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    x, u = rom.hover_state(AF), rom.hover_input(AF)
    x_next = np.asarray(PLANT(x, u, d_true)).ravel()
    scaled = DisturbanceEstimator(AF, PERIOD, gain=0.3).update(x, u, x_next, gain_scale=1 / 6)
    low = DisturbanceEstimator(AF, PERIOD, gain=0.05).update(x, u, x_next)
    assert scaled == pytest.approx(low) and 0 < scaled[0] < 0.3 * 3.0


def test_non_finite_measurements_leave_the_estimate_unchanged():
    est = DisturbanceEstimator(AF, PERIOD)
    before = run(est, np.array([1.0, 0, 0, 0, 0, 0]), steps=10)
    x = rom.hover_state(AF)
    bad = x.copy()
    bad[0] = math.nan
    assert est.update(x, rom.hover_input(AF), bad) == pytest.approx(before)
    assert np.all(np.isfinite(est.update(x, np.full(8, math.inf), x)))
    wild = x.copy()
    wild[rom.RATES] = 1e300
    assert est.update(wild, rom.hover_input(AF), x) == pytest.approx(before)
    est.reset()
    assert np.all(est.estimate == 0)


@pytest.mark.parametrize("kwargs", [{"gain": 0.0}, {"gain": 1.5}, {"period_s": 0.0}])
def test_bad_settings_are_rejected(kwargs):
    args = {"period_s": PERIOD, **kwargs}
    with pytest.raises(ValueError, match=next(iter(kwargs))):
        DisturbanceEstimator(AF, **args)


def test_the_estimate_carries_the_weight_downwards_but_only_half_of_it_upwards():
    """Down the rotors may lose thrust to the air, the NMPC must ask for it; up, a landed robot's
    ground would wind the estimate to the whole weight and the NMPC to no thrust at all."""
    weight_n = AF.total_mass_kg * AF.gravity_m_s2
    down = run(DisturbanceEstimator(AF, PERIOD, gain=1.0), np.array([0, 0, 2.0 * weight_n, 0, 0, 0]), steps=20)
    up = run(DisturbanceEstimator(AF, PERIOD, gain=1.0), np.array([0, 0, -2.0 * weight_n, 0, 0, 0]), steps=20)
    assert down[2] == pytest.approx(weight_n) and up[2] == pytest.approx(-0.5 * weight_n)


def test_states_or_an_input_of_the_wrong_size_are_named_in_one_line():
    est = DisturbanceEstimator(AF, PERIOD)
    with pytest.raises(ValueError, match=r"needs states of 20 and an input of 8 entries, got 19, 9 and 20"):
        est.update(np.zeros(rom.NX - 1), np.zeros(rom.NU + 1), np.zeros(rom.NX))
