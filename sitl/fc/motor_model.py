"""The speed and thrust each rotor has now, as the flight controller expects them from what it
commanded.

The FC knows the rotors' thrust coefficient k_t and their motors' time constant tau (it is
tuned with them): a healthy rotor commanded thrust T heads for the speed sqrt(T / k_t), and
one tick of dt later it has covered 1 - exp(-dt / tau) of the way there. The thrust it then
gives is k_t w^2. Both of the FC's shortfall meters start from this: the ESCs' speed
(sitl/fc/shortfall.py) and the gyro (sitl/fc/gyro_shortfall.py).

FC logic, without sockets.
"""

from __future__ import annotations

import math

import numpy as np

from m4.airframe import Airframe


class MotorModel:
    def __init__(self, af: Airframe, tick_s: float):
        self._k_n_s2 = af.thrust_coefficient_n_s2
        self._decay = math.exp(-tick_s / af.motor_time_constant_s)
        self.speed_rad_s: list[float] | None = None        # None: nothing commanded yet

    def update(self, thrust_cmd_n) -> list[float]:
        """The rotors' expected speeds (rad/s, rotors 1..4) one tick after they were commanded
        thrust_cmd_n (4,); the first call takes them as settled there."""
        k_n_s2, decay, speed = self._k_n_s2, self._decay, self.speed_rad_s
        thrust = thrust_cmd_n.tolist() if isinstance(thrust_cmd_n, np.ndarray) else map(float, thrust_cmd_n)
        target = [math.sqrt((0.0 if 0.0 > t else t) / k_n_s2) for t in thrust]     # max(t, 0) without the call
        if speed is not None:
            target = [w + (e - w) * decay for w, e in zip(target, speed)]
        self.speed_rad_s = target
        return target

    @property
    def thrust_n(self) -> list[float]:
        """The thrusts (N) the expected speeds give."""
        k_n_s2 = self._k_n_s2
        return [k_n_s2 * w * w for w in self.speed_rad_s]
