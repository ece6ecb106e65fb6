"""The air: [wind] scenario keys, Dryden turbulence, 1-cosine gusts, and drag on the velocity
relative to the air (sitl/plant/wind.py, sitl/plant/drag.py, sitl/plant/rotor_aero.py)."""

import math
import tomllib

import numpy as np
import pytest

from m4.airframe import ROTOR_COUNT, load_airframe
from m4.toml_fields import ConfigError
from sitl.plant import frames
from sitl.plant.mujoco_plant import Plant
from sitl.plant.truth import TruthRecorder
from sitl.plant.wind import KNOT_M_S, W20_KT, WindField, dryden_low_altitude, gust_ned_m_s
from m4.scenario import Gust, Wind, parse_scenario

AF = load_airframe()
NOMINAL = np.full(ROTOR_COUNT, AF.nominal_hip_rad)


def scenario(wind_text: str):
    return parse_scenario(tomllib.loads(f'name = "w"\nduration_s = 10.0\n{wind_text}'), "w.toml")


# -- scenario keys --------------------------------------------------------------------------

def test_wind_table_reads_mean_turbulence_and_gusts_in_time_order():
    s = scenario('[wind]\nmean_ned_m_s = [1.0, -4.0, 0.5]\nturbulence = "severe"\n'
                 '[[wind.gust]]\nat_s = 6.0\npeak_ned_m_s = [0.0, 3.0, 0.0]\nduration_s = 1.0\n'
                 '[[wind.gust]]\nat_s = 2.0\npeak_ned_m_s = [2.0, 0.0, -1.0]\nduration_s = 0.5\n')
    assert s.wind == Wind(mean_ned_m_s=(1.0, -4.0, 0.5), turbulence="severe",
                          gusts=(Gust(2.0, (2.0, 0.0, -1.0), 0.5), Gust(6.0, (0.0, 3.0, 0.0), 1.0)))


def test_no_wind_table_is_still_air_and_an_empty_one_is_calm_air_without_turbulence():
    assert scenario("").wind is None
    assert scenario("[wind]\n").wind == Wind(mean_ned_m_s=(0.0, 0.0, 0.0), turbulence="none", gusts=())


@pytest.mark.parametrize("text, key", [
    ('[wind]\nspeed = 3.0\n', "speed"),
    ('[wind]\nturbulence = "windy"\n', "turbulence"),
    ('[wind]\nmean_ned_m_s = [0.0, 40.0, 0.0]\n', r"mean_ned_m_s\[1\]"),
    ('[wind]\nmean_ned_m_s = [0.0, 4.0]\n', "mean_ned_m_s"),
    ('[[wind.gust]]\nat_s = 1.0\npeak_ned_m_s = [0.0, 1.0, 0.0]\nduration_s = 0.0\n', "duration_s"),
    ('[[wind.gust]]\nat_s = 11.0\npeak_ned_m_s = [0.0, 1.0, 0.0]\nduration_s = 1.0\n', "at_s"),
    ('[[wind.gust]]\nat_s = 1.0\nduration_s = 1.0\n', "peak_ned_m_s"),
    ('[[wind.gust]]\nat_s = 1.0\npeak_ned_m_s = [0.0, 1.0, 0.0]\nduration_s = 1.0\nshape = "sine"\n', "shape"),
])
def test_bad_wind_keys_are_one_line_errors_naming_the_key(text, key):
    with pytest.raises(ConfigError, match=key) as e:
        scenario(text)
    assert "\n" not in str(e.value)


# -- turbulence and gusts -------------------------------------------------------------------

def test_dryden_low_altitude_intensities_follow_the_wind_at_20_ft():
    sigma, length = dryden_low_altitude("moderate", 2.0)          # floored at 10 ft
    assert sigma[2] == pytest.approx(0.1 * 30.0 * KNOT_M_S)
    assert sigma[0] == sigma[1] == pytest.approx(sigma[2] / (0.177 + 0.000823 * 10.0) ** 0.4)
    assert length[2] == pytest.approx(5.0 * 0.3048) and length[0] == pytest.approx(2.0 * length[1])
    assert dryden_low_altitude("severe", 2.0)[0] == pytest.approx(1.5 * sigma)
    assert dryden_low_altitude("light", 2.0)[0] == pytest.approx(0.5 * sigma)
    assert dryden_low_altitude("moderate", 30.0)[1][2] > length[2]   # higher: longer eddies


def _samples(field: WindField, seconds: float, step_s: float) -> np.ndarray:
    return np.array([field.velocity_ned_m_s(k * step_s) for k in range(1, int(seconds / step_s))])


@pytest.mark.parametrize("level", sorted(W20_KT))
def test_turbulence_has_its_levels_standard_deviation_about_the_mean_over_a_long_run(level):
    wind = Wind(mean_ned_m_s=(0.0, 10.0, 0.0), turbulence=level)      # 10 m/s east: u is east, v is south
    field = WindField(wind, height_m=2.0, seed=3, step_s=0.05)
    air = _samples(field, 4000.0, 0.05)
    sigma_u, sigma_v, sigma_w = field.sigma_m_s
    assert np.std(air, axis=0) == pytest.approx([sigma_v, sigma_u, sigma_w], rel=0.1)
    assert np.mean(air, axis=0) == pytest.approx([0.0, 10.0, 0.0], abs=0.2 * sigma_u)


def test_the_same_seed_gives_the_same_air_and_another_seed_other_air():
    wind = Wind(mean_ned_m_s=(3.0, 0.0, 0.0), turbulence="moderate")
    a, b, c = (_samples(WindField(wind, 2.0, seed=s), 5.0, 0.005) for s in (7, 7, 8))
    assert np.array_equal(a, b)
    assert not np.allclose(a, c)


def test_turbulence_does_not_depend_on_how_often_it_is_read():
    wind = Wind(mean_ned_m_s=(0.0, 5.0, 0.0), turbulence="light")
    every, sparse = WindField(wind, 2.0, seed=1), WindField(wind, 2.0, seed=1)
    dense = [every.velocity_ned_m_s(k * 0.005) for k in range(1, 401)]
    assert np.array_equal(sparse.velocity_ned_m_s(2.0), dense[-1])


def test_a_gust_is_a_whole_1_cosine_rising_to_its_peak_at_mid_duration():
    gust = (Gust(at_s=2.0, peak_ned_m_s=(0.0, 4.0, -2.0), duration_s=1.0),)
    peak = np.array([0.0, 4.0, -2.0])
    assert np.array_equal(gust_ned_m_s(gust, 1.99), np.zeros(3))
    assert gust_ned_m_s(gust, 2.25) == pytest.approx(0.5 * peak)
    assert gust_ned_m_s(gust, 2.5) == pytest.approx(peak)
    assert gust_ned_m_s(gust, 2.75) == pytest.approx(0.5 * peak)
    assert np.allclose(gust_ned_m_s(gust, 3.0), 0.0) and np.array_equal(gust_ned_m_s(gust, 3.01), np.zeros(3))
    field = WindField(Wind(mean_ned_m_s=(1.0, 0.0, 0.0), gusts=gust), 2.0)
    assert field.velocity_ned_m_s(2.5) == pytest.approx(peak + [1.0, 0.0, 0.0])


# -- the plant in the air -------------------------------------------------------------------

def _hovering(wind: Wind | None, vel_ned_m_s=(0.0, 0.0, 0.0)) -> Plant:
    plant = Plant(AF, wind=wind)
    plant.data.qvel[plant._vel] = frames.flip_vector(vel_ned_m_s)     # the whole robot moves with the hull
    plant.command(np.full(ROTOR_COUNT, plant.hover_thrust_n), NOMINAL)
    return plant


def _horizontal_accel_ned_m_s2(plant: Plant, seconds: float = 0.02) -> np.ndarray:
    v0 = plant.state().vel_ned_m_s
    plant.step(seconds)
    return (plant.state().vel_ned_m_s - v0)[:2] / seconds


def test_a_robot_held_still_in_wind_is_pushed_downwind_by_hull_and_rotor_drag():
    wind_m_s = 5.0
    a = _horizontal_accel_ned_m_s2(_hovering(Wind(mean_ned_m_s=(0.0, wind_m_s, 0.0))))
    speed_rad_s = math.sqrt(AF.hover_thrust_per_rotor_n / AF.thrust_coefficient_n_s2)
    force_n = (AF.drag_linear_n_s_m * wind_m_s + AF.drag_quadratic_n_s2_m2 * wind_m_s ** 2
               + ROTOR_COUNT * AF.drag_rotor_n_s_m_per_rad_s * speed_rad_s * wind_m_s)
    assert a[1] == pytest.approx(force_n / AF.total_mass_kg, rel=0.05)
    assert abs(a[0]) < 0.02 * a[1]


def test_a_robot_moving_with_the_wind_feels_no_drag_and_one_moving_in_still_air_does():
    air = (2.0, -3.0, 0.0)
    with_wind = _horizontal_accel_ned_m_s2(_hovering(Wind(mean_ned_m_s=air), vel_ned_m_s=air))
    assert np.allclose(with_wind, 0.0, atol=1e-3)
    through_still_air = _horizontal_accel_ned_m_s2(_hovering(None, vel_ned_m_s=air))
    assert np.all(np.sign(through_still_air) == -np.sign(air[:2])) and np.linalg.norm(through_still_air) > 0.1


def test_air_coming_down_through_the_rotors_lowers_their_thrust_by_the_inflow_law():
    down_m_s = 2.0
    plant = _hovering(Wind(mean_ned_m_s=(0.0, 0.0, down_m_s)))
    plant.step(0.01)
    expected = 1.0 - down_m_s / AF.inflow_reference_speed_m_s
    assert plant.state().thrust_n == pytest.approx(plant.hover_thrust_n * expected, rel=1e-3)


def test_the_truth_log_holds_the_air_at_the_robot_in_wind_only():
    gust = Gust(at_s=0.0, peak_ned_m_s=(0.0, 2.0, 0.0), duration_s=0.2)
    for wind in (None, Wind(mean_ned_m_s=(1.0, 0.0, 0.0), gusts=(gust,))):
        plant, log = _hovering(wind), TruthRecorder(period_ms=10)
        for ms in range(0, 201, 10):
            log.observe(ms, plant)
            plant.step(0.01)
        truth = log.truth()
        if wind is None:
            assert truth.wind_ned_m_s is None
        else:
            assert truth.wind_ned_m_s.shape == (21, 3)
            assert truth.wind_ned_m_s[10] == pytest.approx([1.0, 2.0, 0.0])
