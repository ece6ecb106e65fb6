"""Windy built-in scenarios flown end to end by `m4-sitl fly` (lockstep, the companion in the
loop): a rotor loss in a 5 m/s crosswind with moderate turbulence, and an agile fault-free
flight through moderate turbulence and a gust. Each about 13 s of CPU."""

from __future__ import annotations

import numpy as np
import pytest

from analysis.detection import CONFIRMED
from sitl.flights.figures import flight_tlog
from sitl.flights.flight_run import FlightFiles
from sitl.flights.fly import fly
from sitl.flights.records import read_fault_status
from sitl.plant.truth import load_truth
from sitl.scenarios import resolve

pytestmark = pytest.mark.flight


def _flown(name, tmp_path):
    metrics = fly(name, tmp_path, progress=False)
    truth = load_truth(tmp_path / "truth.npz")
    wind = resolve(name).wind
    assert metrics["wind"]["mean_ned_m_s"] == list(wind.mean_ned_m_s)
    assert metrics["wind"]["turbulence"] == wind.turbulence and metrics["wind"]["gusts"] == len(wind.gusts)
    assert truth.wind_ned_m_s.shape == truth.pos_ned_m.shape
    assert (tmp_path / "wind.png").stat().st_size > 0
    return metrics, truth


def test_rotor_loss_in_a_gusty_crosswind_is_found_on_its_rotor_and_survived(tmp_path):
    m, truth = _flown("crosswind-rotor-loss", tmp_path)
    assert np.all(np.std(truth.wind_ned_m_s, axis=0) > 0.5)     # turbulent on every axis
    assert m["survived"], m["checks"]
    fault, = m["faults"]
    assert fault["detected_rotor"] == fault["rotor"] and 0.0 < fault["latency_s"] <= 0.1


def test_agile_flight_through_turbulence_and_a_gust_raises_no_alarm_in_the_air_nor_at_touchdown(tmp_path):
    """The crosswind touchdown (the ground holding the robot against the air) once confirmed a
    lost rotor 0.2 s after the wheels met the ground."""
    m, truth = _flown("gusty-fault-free", tmp_path)
    assert m["survived"], m["checks"]
    status = read_fault_status(flight_tlog(FlightFiles(tmp_path)))
    assert truth.on_ground[-1] and status.time_s[-1] > truth.time_s[np.flatnonzero(truth.on_ground)[0]]
    assert not np.any(status.state == CONFIRMED)
