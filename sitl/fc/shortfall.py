"""How far each rotor falls short of its command, as the flight controller sees it in its
ESCs' speed (bidirectional DShot, every output frame).

The FC knows what it commanded and the rotors' thrust coefficient and time constant, so it
knows the speed w_e a healthy rotor has now (sitl/fc/motor_model.py). A rotor turning slower
(its drive capped or dead) gives k_t w^2 instead of k_t w_e^2. One turning faster carries less load than the nominal
propeller on the voltage the ESC gives it: the motor's torque balance (sitl/plant/thrusters.py,
k_e ((u - k_e w) / R - i0) = drag) with u the voltage that settles the nominal propeller at
w_e says its propeller gives k_t w_e^2 - (k_t k_e^2 / (k_q R)) (w - w_e), nothing once it
has lost its propeller and runs near no-load speed. The shortfall is what is missing beyond
DEADBAND_N (the speed's noise and quantisation, the motor constants' error). The speeds
arrive esc_telemetry_delay_s late, so they are held against what was expected when they were
measured. M4_SETPOINT's shortfall cover (m4/setpoint.py) turns it into the other rotors'
change.

FC logic, without sockets: sitl/fc/flight_controller.py feeds it at every tick.
"""

from __future__ import annotations

import collections
import math

from m4.airframe import Airframe
from m4.units import RAD_S_TO_RPM
from sitl.fc.motor_model import MotorModel

DEADBAND_N = 1.5


class ShortfallMeter:
    def __init__(self, af: Airframe, tick_s: float):
        self._k_n_s2 = af.thrust_coefficient_n_s2
        # thrust a faster turning rotor gives less, per rad/s (the motor's torque balance)
        self._unload_n_s = (af.thrust_coefficient_n_s2 * af.motor_back_emf_v_s_rad ** 2
                            / (af.drag_torque_coefficient_n_m_s2 * af.motor_resistance_ohm))
        self._motors = MotorModel(af, tick_s)
        # the expected speeds of the last ticks, the newest now, the oldest when the speeds now
        # reported were measured
        self._history: collections.deque[list[float]] = collections.deque(
            maxlen=math.ceil(af.esc_telemetry_delay_s / tick_s - 1e-9) + 1)

    def update(self, thrust_cmd_n, rpm) -> list[float]:
        """The rotors' shortfall (N, rotors 1..4) one tick after they were commanded
        thrust_cmd_n (4,), their ESCs reporting rpm (4,)."""
        self._history.append(self._motors.update(thrust_cmd_n))
        k_n_s2, unload_n_s = self._k_n_s2, self._unload_n_s
        shortfall = []
        for expected, measured_rpm in zip(self._history[0], rpm):
            measured = float(measured_rpm) / RAD_S_TO_RPM
            expected_n = k_n_s2 * expected * expected
            if measured <= expected:
                delivered_n = k_n_s2 * measured * measured
            else:
                delivered_n = expected_n - unload_n_s * (measured - expected)
                delivered_n = 0.0 if 0.0 > delivered_n else delivered_n          # max(., 0) without the call
            short_n = expected_n - delivered_n - DEADBAND_N
            shortfall.append(0.0 if 0.0 > short_n else short_n)
        return shortfall
