"""The same noisy scenario and seed give the same flight, companion and plant as two processes."""

from __future__ import annotations

import numpy as np
import pytest

from sitl.flight_run import FlightOptions
from sitl.fly import fly
from sitl.truth import load_truth

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


def _flight(tmp_path, name, seed):
    scenario = tmp_path / "noisy.toml"
    scenario.write_text(NOISY)
    fly(str(scenario), tmp_path / name, FlightOptions(seed=seed), figures=False, progress=False)
    truth = load_truth(tmp_path / name / "truth.npz")
    return np.hstack([truth.pos_ned_m, truth.euler_rad, truth.thrust_cmd_n, truth.hip_rad])


def test_the_same_seed_gives_the_same_noisy_flight(tmp_path):
    """(Another seed giving other noise: tests/sitl/test_serve.py and test_plant.py.)"""
    first, second = _flight(tmp_path, "a", 5), _flight(tmp_path, "b", 5)
    assert first.shape == second.shape and np.array_equal(first, second)
