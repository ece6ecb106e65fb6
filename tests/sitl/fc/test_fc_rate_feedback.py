"""The simulated FC closes the companion's rate feedback (M4_SETPOINT's extension fields) on its
own gyro at its own loop rate; without the fields it flies the setpoint's thrusts alone."""

from __future__ import annotations

import numpy as np
import pytest

from m4.airframe import load_airframe
from m4.mavlink import mavlink, new_mav
from sitl.fc.flight_controller import TICK_MS
from m4.scenario import Scenario
from sitl.vehicle import Vehicle
from tests.support.packets import packed

AF = load_airframe()
THRUST_N = 14.7
GAIN = np.zeros((4, 3))
GAIN[0, 0], GAIN[1, 0] = 2.0, -2.0          # N per rad/s of roll-rate error: rotors 1 and 2



def _from_companion(msg):
    """msg as the paired companion (1/191) sends it, decoded as the FC receives it."""
    return new_mav(None, 1, 1).parse_buffer(packed([msg], 1, 191)[0])[0]


def _fly_one_setpoint(*feedback):
    vehicle = Vehicle(Scenario(name="hover", duration_s=1.0), AF)
    vehicle.start(lambda msgs: None)
    vehicle.advance_to(100, lambda msgs: None)
    sp = mavlink.MAVLink_m4_setpoint_message(1, 1, 100, 20, [THRUST_N] * 4, [AF.nominal_hip_rad] * 4, [0.0] * 4, 0,
                                             *feedback)
    vehicle.handle([_from_companion(sp)], lambda msgs: None)
    commanded = []
    for t_ms in range(100 + TICK_MS, 141, TICK_MS):
        vehicle.advance_to(t_ms, lambda msgs: None)
        state = vehicle.fc.measured_state(t_ms)
        commanded.append((t_ms, state.thrust_cmd_n.copy(), state.rates_frd_rad_s.copy()))
    return commanded


def test_without_the_fields_the_fc_flies_the_setpoint_thrusts_alone():
    for _, thrust, _ in _fly_one_setpoint():
        assert thrust == pytest.approx([THRUST_N] * 4, abs=1e-5)


def test_the_fc_adds_gain_times_the_rate_error_along_the_planned_rates():
    """Planned roll rate 1 rad/s growing 10 rad/s^2 (held after the 20 ms period), the robot at
    rest: rotor 1 gets +2 N per rad/s of error, rotor 2 -2 N, the others nothing."""
    for t_ms, thrust, rates in _fly_one_setpoint([1.0, 0.0, 0.0], [10.0, 0.0, 0.0], GAIN.ravel()):
        planned = 1.0 + 10.0 * min((t_ms - 100) / 1000.0, 0.02)
        error = planned - rates[0]
        assert thrust[0] == pytest.approx(THRUST_N + 2.0 * error, abs=0.05)
        assert thrust[1] == pytest.approx(THRUST_N - 2.0 * error, abs=0.05)
        assert thrust[2:] == pytest.approx([THRUST_N] * 2, abs=1e-5)


@pytest.mark.parametrize("gain", [np.full(12, np.nan), np.full(12, 1e3)])
def test_a_gain_that_is_not_finite_or_too_large_is_ignored(gain):
    for _, thrust, _ in _fly_one_setpoint([1.0, 0.0, 0.0], [0.0, 0.0, 0.0], gain):
        assert thrust == pytest.approx([THRUST_N] * 4, abs=1e-5)
