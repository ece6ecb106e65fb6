"""The campaign's sample, scenario files and summaries, and the comparison table (no flights)."""

from __future__ import annotations

import tomllib

import numpy as np
import pytest

from companion.config import parse_config
from m4.airframe import ROTOR_COUNT, load_airframe
from m4.scenario import parse_scenario
from sitl.campaigns import campaign, detection_campaign, tradeoff
from sitl.flights.flight_run import FlightOptions, companion_config_text
from sitl.flights import metrics
from sitl.flights.records import FaultStatusLog
from sitl.campaigns.compare import markdown_table

AF = load_airframe()


def test_the_grid_covers_every_rotor_loss_level_speed_and_fault_time_once():
    cases = campaign.grid_cases()
    keys = {(c.rotor, c.loss, c.speed_m_s, c.at_s) for c in cases}
    assert len(keys) == len(cases) == 4 * len(campaign.LOSS_LEVELS) * len(campaign.GRID_SPEEDS_M_S) \
        * len(campaign.GRID_FAULT_TIMES_S)
    assert {c.rotor for c in cases} == {1, 2, 3, 4}


def test_random_cases_are_reproducible_and_within_the_campaign_ranges():
    cases = campaign.random_cases(40, seed=3)
    assert cases == campaign.random_cases(40, seed=3) != campaign.random_cases(40, seed=4)
    assert all(0.0 <= c.speed_m_s <= campaign.MAX_SPEED_M_S for c in cases)
    assert any(c.speed_m_s == 0.0 for c in cases) and any(c.speed_m_s > 0.0 for c in cases)
    assert any(c.sensor_noise for c in cases) and not all(c.sensor_noise for c in cases)


def test_each_case_is_a_valid_scenario_flying_at_its_speed_when_the_fault_comes():
    case = campaign.Case("c", rotor=2, loss=1.0, at_s=2.0, speed_m_s=3.0, heading_deg=90.0, mass_scale=1.02,
                         sensor_noise=True)
    s = parse_scenario(tomllib.loads(case.scenario_toml()), "c.toml")
    assert s.duration_s == case.duration_s and s.faults[0].rotor == 2 and s.faults[0].at_s == 2.0
    assert s.plant.mass_scale == 1.02 and s.plant.sensor_noise
    wp = s.mission.waypoints[0]
    assert wp.speed_m_s == 3.0 and abs(wp.ned_m[0]) < 1e-3 and wp.ned_m[1] > 3.0 * case.duration_s   # due east
    hover = parse_scenario(tomllib.loads(campaign.Case("h", 1, 0.33, 1.5, 0.0).scenario_toml()), "h.toml")
    assert hover.mission.waypoints == ()


def _row(loss, speed, survived, latency, isolated=True, error=""):
    case = campaign.Case("x", rotor=4, loss=loss, at_s=1.0, speed_m_s=speed)
    if error:
        return campaign.result_row(case, {"error": error})
    metrics = {"survived": survived, "crashed": not survived, "altitude_loss_m": 0.2, "max_tilt_deg_after_fault": 30.0,
               "faults": [{"at_s": 1.0, "detected_at_s": 1.0 + latency, "detected_rotor": 4 if isolated else 1}]}
    return campaign.result_row(case, metrics)


def test_summary_counts_survival_detection_and_isolation_per_group_and_the_target():
    rows = [_row(1.0, 0.0, True, 0.1), _row(1.0, 2.0, False, 0.2, isolated=False), _row(0.33, 0.0, True, 0.3),
            _row(1.0, 3.0, False, 0.0, error="the companion did not start")]
    assert rows[1]["detection_latency_s"] == 0.2 and not rows[1]["rotor_isolated"]
    text = campaign.summary_markdown(rows)
    assert "| loss 1, hover | 1 | 1/1 (100 %)" in text
    assert "| loss 1, forward flight | 2 | 0/2 (0 %)" in text
    assert "| **all** | 4 | 2/4 (50 %)" in text
    assert "up to 3 m/s: 1/3 survived" in text


def test_comparison_table_has_one_row_per_flight_and_shows_errors():
    flown = {"scenario": "s", "controller": "nmpc", "survived": False, "altitude_loss_m": 1.234,
             "max_tilt_deg_after_fault": 80.2, "time_to_yaw_saturation_s": None, "yaw_rate_final_rad_s": 12.34,
             "max_thrust_n": 24.0, "position_rmse_m": 0.5}
    table = markdown_table([flown, {"scenario": "s", "controller": "fixed-posture", "error": "port in use"}])
    lines = table.strip().splitlines()
    assert len(lines) == 4
    assert lines[2].startswith("| s | nmpc | **no** | 1.23 | 80 | - | 12.3 | 24.0 | 0.50 |")
    assert "not flown: port in use" in lines[3]


def test_every_flight_has_its_own_noise_seed_from_the_campaign_seed():
    seeds = [c.noise_seed for c in campaign.random_cases(20, seed=3)]
    assert len(set(seeds)) == 20
    assert seeds == [c.noise_seed for c in campaign.random_cases(20, seed=3)]
    assert seeds != [c.noise_seed for c in campaign.random_cases(20, seed=4)]
    assert [c.noise_seed for c in campaign.grid_cases(seed=3)][:20] == seeds


def test_the_detection_campaign_takes_each_flights_detection_from_its_metrics():
    """Half of rotor 3's propeller lost at 2 s: confirmed at 2.02 s while its estimate still
    says healthy, sized at 2.06 s (the detection), rotor 1 confirmed later (a false alarm)."""
    case = detection_campaign.DetectionCase("damage-r3", "damage", 3, 0.0, True, 1.0, 1.0, 6.0)
    scenario = parse_scenario(tomllib.loads(case.scenario_toml()), "damage-r3.toml")
    rows = [(2.02, 3, AF.thrust_max_n), (2.06, 3, 0.5 * AF.thrust_max_n), (4.0, 1, 0.5 * AF.thrust_max_n)]
    estimate = np.full((len(rows), ROTOR_COUNT), AF.thrust_max_n)
    for k, (_, rotor, e) in enumerate(rows):
        estimate[k, rotor - 1] = e
    t = np.array([r[0] for r in rows])
    status = FaultStatusLog(t, np.array([r[1] for r in rows]), np.full(len(rows), 2), estimate, t,
                            np.zeros(len(rows), int))
    flight = {"survived": True, "faults": metrics.detections(scenario, status, AF)}
    row = detection_campaign.result_row(case, flight, status, None, AF.hover_thrust_per_rotor_n)
    assert (row["detected"], row["latency_s"], row["rotor_isolated"]) == (True, 0.06, True)
    assert row["false_alarm"]
    alone = FaultStatusLog(t[:2], status.rotor[:2], status.state[:2], estimate[:2], t[:2], status.kind[:2])
    assert not detection_campaign.result_row(case, flight, alone, None, AF.hover_thrust_per_rotor_n)["false_alarm"]


def test_weather_cases_are_valid_scenarios_in_the_wind_level_and_profile_asked():
    """5 m/s from a bearing drawn per flight, moderate Dryden, the gps profile; a gust every
    10 s on the fault-free flights only; still air draws as before the weather existed."""
    grid = detection_campaign.WeatherGrid(5.0, ("light", "moderate"), ("gps", "mocap"))
    cases = detection_campaign.detection_cases(("motor",), (0.0,), (True,), 0, 1.0, grid)
    assert len(cases) == 2 * 2 * (ROTOR_COUNT + 1) and len({c.name for c in cases}) == len(cases)
    bearings = set()
    for case in cases:
        scenario = parse_scenario(tomllib.loads(case.scenario_toml()), f"{case.name}.toml")
        assert np.hypot(*scenario.wind.mean_ned_m_s[:2]) == pytest.approx(5.0, abs=1e-3)
        assert (scenario.wind.turbulence, scenario.sensors.profile) == (case.weather.turbulence, case.weather.profile)
        assert len(scenario.wind.gusts) == (0 if case.kind else 6)
        bearings.add(case.weather.wind_from_deg)
    assert len(bearings) == len(cases)
    still = detection_campaign.detection_cases(("motor",), (0.0,), (True,), 0, 1.0)
    assert [c.mass_scale for c in still] == [c.mass_scale for c in detection_campaign.detection_cases(
        ("motor",), (0.0,), (True,), 0, 1.0, detection_campaign.WeatherGrid())]
    assert all(parse_scenario(tomllib.loads(c.scenario_toml()), "s.toml").wind is None for c in still)


def test_a_sweep_flies_every_case_at_each_value_and_hands_the_setting_to_the_companion():
    sweep = (("deficit_min_n", 1.0), ("deficit_min_n", 4.0))
    cases = detection_campaign.detection_cases(("motor",), (0.0,), (False,), 0, 1.0, sweep=sweep)
    assert [c.detector_setting for c in cases] == [sweep[0]] * 5 + [sweep[1]] * 5
    text = companion_config_text(FlightOptions(fault_detector=(sweep[1],)), 14550, None)
    assert parse_config(tomllib.loads(text), "flight").fault_detector.deficit_min_n == 4.0


def _status(rows):
    t = np.array([r[0] for r in rows])
    return FaultStatusLog(t, np.array([r[1] for r in rows]), np.array([r[2] for r in rows]),
                          np.full((len(rows), ROTOR_COUNT), AF.thrust_max_n), t, np.zeros(len(rows), int))


def test_false_alarms_are_counted_per_confirmation_and_per_hour_flown_before_the_fault():
    """A fault-free minute confirmed twice (healthy again between) is 2 alarms: 120 per hour."""
    case = detection_campaign.DetectionCase("free", "", 0, 3.0, True, 1.0, 1.0, 60.0)
    status = _status([(10.0, 2, 1), (10.1, 2, 2), (10.2, 2, 2), (11.0, 0, 0), (30.0, 3, 2)])
    checks = {"completed": True, "no_ground_contact_before_landing": True, "altitude_loss_within_0.5_m": True,
              "tilt_back_within_10_deg": False}
    row = detection_campaign.result_row(case, {"survived": False, "checks": checks}, status, None, 14.7)
    assert (row["alarms_before_fault"], row["flown_before_fault_s"], row["held"]) == (2, 60.0, True)
    assert detection_campaign.alarms_per_hour([row]) == pytest.approx(120.0)


def test_the_tradeoff_has_one_point_per_value_with_its_latency_and_alarm_rate(tmp_path):
    def row(value, kind, latency, alarms, flown_s):
        return {"setting": "chi2_min", "setting_value": value, "kind": kind, "latency_s": latency,
                "detected": latency is not None, "alarms_before_fault": alarms, "flown_before_fault_s": flown_s}
    rows = [row(10.0, "motor", 0.04, 1, 2.0), row(10.0, "motor", 0.06, 0, 2.0), row(10.0, "", None, 3, 3596.0),
            row(50.0, "motor", 0.1, 0, 2.0), row(50.0, "motor", None, 0, 2.0), row(50.0, "", None, 0, 3596.0)]
    low, high = tradeoff.draw_tradeoff(rows, tmp_path / "tradeoff.png")
    assert (low.value, low.latency_median_s, low.latency_worst_s, low.missed) == (10.0, 0.05, 0.06, 0)
    assert low.alarms_per_hour == pytest.approx(4.0) and high.alarms_per_hour == 0.0 and high.missed == 1
    assert (tmp_path / "tradeoff.png").stat().st_size > 0
    assert "| chi2_min = 50 | 0.10 / 0.10 | 1 | 0.0 | 1.00 |" in tradeoff.tradeoff_markdown([low, high])


def test_the_tradeoff_marks_the_value_the_companion_flies_with():
    """deploy/companion.toml flies chi2_min = 25: that point, and only it, is the default."""
    rows = [{"setting": "chi2_min", "setting_value": value, "kind": "", "latency_s": None, "detected": False,
             "alarms_before_fault": 0, "flown_before_fault_s": 60.0} for value in (5.0, 25.0)]
    points = tradeoff.tradeoff_points(rows)
    assert [p.default for p in points] == [False, True]
    text = tradeoff.tradeoff_markdown(points)
    assert "| chi2_min = 25 (default) |" in text and "| chi2_min = 5 |" in text
    assert tradeoff.deployed_value("no_such_setting") is None


def test_values_that_land_on_one_point_of_the_tradeoff_are_named_together():
    """confirm_s 0.1 and 0.2 both 0.11 s with no alarm: one label, not two written over each other."""
    def point(value, latency, missed=0):
        return tradeoff.TradeoffPoint("confirm_s", value, latency, latency, missed, 0.0, 0.02, value == 0.1)
    labels = tradeoff.point_labels([point(0.04, 0.06), point(0.1, 0.11), point(0.2, 0.11, missed=1)])
    assert labels == {(0.0, 0.06): "0.04", (0.0, 0.11): "0.1 (default), 0.2 (1 missed)"}


def test_a_stalled_flight_is_flagged_and_counts_in_no_figure():
    """Two fault-free minutes, the second stalled with an alarm in its failsafe: the table has
    one minute and no alarm, and says which flight it left out."""
    checks = {"completed": True, "no_ground_contact_before_landing": True, "altitude_loss_within_0.5_m": True}
    alarm = _status([(10.0, 2, 1), (10.1, 2, 2), (10.2, 2, 2)])
    rows = [detection_campaign.result_row(detection_campaign.DetectionCase(name, "", 0, 3.0, True, 1.0, 1.0, 60.0),
                                          {"survived": True, "checks": checks}, status, None, 14.7, was_stalled)
            for name, status, was_stalled in (("calm", _status([]), False), ("late", alarm, True))]
    assert [r["stalled"] for r in rows] == [False, True] and rows[1]["alarms_before_fault"] == 1
    text = detection_campaign.summary_markdown(rows)
    assert text.startswith("1 of 2 flights stalled") and text.splitlines()[0].endswith(": late")
    assert "| 3 m/s, ESC on/off | none | ideal | default | 1 | 1 | 1/1 | 0 | 0.0 |" in text
    swept = [{**r, "setting": "chi2_min", "setting_value": 25.0} for r in rows]
    assert tradeoff.tradeoff_points(swept)[0].alarms_per_hour == 0.0
