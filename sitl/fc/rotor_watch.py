"""The flight controller's own check for a lost rotor, from its ESC telemetry.

An ESC reports its motor's speed (a FC without ESC telemetry has no such check); the FC
knows what it commanded and the rotors' thrust coefficient, so it knows the speed a healthy
rotor settles at (w = sqrt(T / k)). A rotor commanded at least `MIN_COMMAND_N` that turns
at less than `SLOW_FRACTION` of that speed for `CONFIRM_MS` (a few motor time constants, so
a healthy rotor spinning up is never taken for a lost one) is lost, and stays lost: the
FC's failsafe then flies on the other three.
The companion's M4_FAULT_STATUS says the same sooner when it is alive; this is for when it
is not (killed before it confirmed, or restarted and not yet told).
Its thresholds, and whether it runs at all, are parameters (sitl/fc/params.py).
"""

from __future__ import annotations

import math

from m4.airframe import ROTOR_COUNT, Airframe

MIN_COMMAND_N = 3.0
SLOW_FRACTION = 0.5
CONFIRM_MS = 100


class RotorWatch:
    def __init__(self, airframe: Airframe):
        self.k_n_s2 = airframe.thrust_coefficient_n_s2
        self.enabled = True
        self.min_command_n = MIN_COMMAND_N
        self.slow_fraction = SLOW_FRACTION
        self.confirm_ms = CONFIRM_MS
        self.lost: int | None = None                      # rotor 1..4
        self._slow_since_ms: list[int | None] = [None] * ROTOR_COUNT

    def update(self, command_n, speed_rad_s, now_ms: int) -> int | None:
        """Feed the thrusts commanded (4,) and the speeds the ESCs report (4,); the lost rotor, if any."""
        if self.lost is not None or not self.enabled:
            return self.lost
        command = list(map(float, command_n))         # Python floats: four numbers
        speed = list(map(float, speed_rad_s))
        for i in range(ROTOR_COUNT):
            expected = math.sqrt((0.0 if 0.0 > command[i] else command[i]) / self.k_n_s2)     # max(., 0), no call: every tick
            if not (command[i] >= self.min_command_n and speed[i] < self.slow_fraction * expected):
                self._slow_since_ms[i] = None
            elif self._slow_since_ms[i] is None:
                self._slow_since_ms[i] = now_ms
            elif now_ms - self._slow_since_ms[i] >= self.confirm_ms:
                self.lost = i + 1
        return self.lost
