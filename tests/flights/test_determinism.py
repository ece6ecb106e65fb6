"""The same noisy scenario and seed give the same flight, companion and plant as two processes,
also through a delayed and lossy link (emulated in lockstep by the SITL), and also forked from
their fork servers as campaigns fly them."""

from __future__ import annotations

import numpy as np
import pytest

from sitl.flights.flight_run import FlightOptions, start_process
from sitl.flights.fly import fly
from sitl.flights.forks import ForkedStart
from sitl.links.emulation import LinkEmulation
from sitl.plant.truth import load_truth

pytestmark = pytest.mark.flight

NOISY = """name = "noisy-rotor-loss"
duration_s = 1.5
[start]
ned_m = [0.0, 0.0, -2.0]
[mission]
on_fault = "hold"
[[fault]]
at_s = 0.5
rotor = 4
loss = 1.0
[plant]
sensor_noise = true
"""


HOVER = """name = "noisy-hover"
duration_s = 2.0
[start]
ned_m = [0.0, 0.0, -2.0]
[plant]
sensor_noise = true
"""


def _flight(tmp_path, name, seed, text=NOISY, link=None, start=start_process):
    scenario = tmp_path / "scenario.toml"
    scenario.write_text(text)
    metrics = fly(str(scenario), tmp_path / name, FlightOptions(seed=seed, link=link), figures=False, progress=False,
                  start=start)
    truth = load_truth(tmp_path / name / "truth.npz")
    return np.hstack([truth.pos_ned_m, truth.euler_rad, truth.thrust_cmd_n, truth.hip_rad]), metrics


def test_the_same_seed_gives_the_same_noisy_flight(tmp_path):
    """(Another seed giving other noise: tests/sitl/test_serve.py and tests/sitl/plant/test_mujoco_plant.py.)"""
    (first, _), (second, _) = _flight(tmp_path, "a", 5), _flight(tmp_path, "b", 5)
    assert first.shape == second.shape and np.array_equal(first, second)


def test_a_delayed_lossy_link_in_lockstep_flies_to_the_end_measured_and_the_same_for_a_seed(tmp_path):
    link = LinkEmulation(delay_ms=20.0, loss=0.2)
    (first, metrics), (second, _) = (_flight(tmp_path, name, 5, HOVER, link) for name in ("a", "b"))
    assert metrics["completed"] and not metrics["crashed"]
    assert metrics["link"] == {"delay_ms": 20.0, "loss": 0.2, "mode": "lockstep", "setpoint_lead_ms": 40.0}
    assert first.shape == second.shape and np.array_equal(first, second)
    sitl_log = (tmp_path / "a" / "sitl.log").read_text()
    assert "link emulated (20 ms each way, loss 0.2)" in sitl_log and "no setpoint for" not in sitl_log


def test_flights_forked_from_the_fork_servers_are_those_of_new_processes_bit_for_bit(tmp_path):
    """As a campaign flies them: one pair of fork servers for two flights in turn, the second
    flight forked from servers that forked the first (nothing of it stays in them)."""
    forked = ForkedStart()
    try:
        flights = [_flight(tmp_path, name, 5, start=forked) for name in ("forked-a", "forked-b")]
    finally:
        forked.close()
    new, new_metrics = _flight(tmp_path, "new", 5)
    for truth, metrics in flights:
        assert truth.shape == new.shape and np.array_equal(truth, new)
        assert metrics["faults"] == new_metrics["faults"] and metrics["position_rmse_m"] == new_metrics["position_rmse_m"]
    last_words = [(tmp_path / name / "companion.log").read_text().splitlines()[-1].partition(";")[0]
                  for name in ("forked-a", "forked-b", "new")]
    assert len(set(last_words)) == 1 and "stopped by SIGTERM after" in last_words[0]
