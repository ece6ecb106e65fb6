"""How far each rotor falls short of its command, as the flight controller sees it on its gyro:
the incremental (INDI-style) measure, for a FC without ESC telemetry and for what the ESCs
misread.

Incremental nonlinear dynamic inversion (Smeur, Chu and de Croon; Sun et al. flew a
quadrotor on it after losing rotors) does not model what acts on the robot: it measures the
angular acceleration and changes the thrusts by what the robot lacks. Here the FC compares,
at every tick, the roll and pitch acceleration its gyro shows with the one it expects: the
plan's (M4_SETPOINT's planned rate change) plus what its own changes to the plan's thrusts
give (the setpoint's effectiveness times the difference between the thrust its commands give
and the thrust the plan's give, both through the motor model, sitl/fc/motor_model.py). The
gyro is differentiated through a second-order low-pass filter (CUTOFF_RAD_S, DAMPING) and the
expectation goes through the same filter, so the two meet at the same delay. What the robot
lacks is then explained by the rotors that fall short: a rotor short by s takes
effectiveness[:, i] x s from the angular acceleration, so the shortfall is the s >= 0 with
effectiveness @ s = lacking of least total (a lost rotor's torque lies along its own arm and
names it alone; one between two arms is shared by those two), beyond DEADBAND_N (the
effectiveness' and the plan's model errors, the gyro's noise).

The FC needs nothing a real one lacks: its gyro, its own commands, the motor constants it is
tuned with, and the setpoint's design data. It does not need to know what failed: a lost
propeller, a stopped motor or a capped drive all take the same angular acceleration away.
The shortfall cover (m4/setpoint.py) turns the measure into the other rotors' change; they
keep the sum and the roll and pitch torque, so the measure itself does not change while they
cover (the robot moves as expected, less what the short rotor lacks).

FC logic, without sockets: sitl/fc/flight_controller.py feeds it at every tick.
"""

from __future__ import annotations

import itertools
import math

import numpy as np

from m4.airframe import ROTOR_COUNT, Airframe
from sitl.fc.motor_model import MotorModel

CUTOFF_RAD_S = 188.0          # the low-pass filter's natural frequency (30 Hz; docs/fast-loops.md) ...
DAMPING = 0.7                 # ... and damping (Butterworth)
DEADBAND_N = 1.5
_PAIRS = tuple(itertools.combinations(range(ROTOR_COUNT), 2))
_SINGULAR = 1e-6              # |det| / (largest entry)^2 below this: two rotors on one line


class DifferentiatingFilter:
    """Second-order low-pass filter y'' = w^2 (u - y) - 2 zeta w y' on several channels,
    discretised exactly for input held over each tick (underdamped: 0 < zeta < 1); gives y and y'."""

    def __init__(self, tick_s: float, cutoff_rad_s: float = CUTOFF_RAD_S, damping: float = DAMPING):
        if not (tick_s > 0.0 and cutoff_rad_s > 0.0 and 0.0 < damping < 1.0):
            raise ValueError(f"the filter needs tick_s > 0, cutoff_rad_s > 0 and 0 < damping < 1, got "
                             f"{tick_s}, {cutoff_rad_s}, {damping}")
        # The state's transition over a tick and the held input's gain, in closed form: the
        # underdamped oscillator's impulse and step responses at t = tick_s.
        w, sigma = cutoff_rad_s, damping * cutoff_rad_s
        w_d = w * math.sqrt(1.0 - damping * damping)
        decay, cos, sin = math.exp(-sigma * tick_s), math.cos(w_d * tick_s), math.sin(w_d * tick_s)
        self._phi = ((decay * (cos + sigma / w_d * sin), decay * sin / w_d),
                     (-decay * w * w / w_d * sin, decay * (cos - sigma / w_d * sin)))
        self._gamma = (1.0 - decay * (cos + sigma / w_d * sin), decay * w * w / w_d * sin)
        self._value: list[float] | None = None
        self._derivative: list[float] = []

    def update(self, u) -> tuple[list[float], list[float]]:
        """Filter the input held over the last tick; (value, derivative), one entry a channel.
        The first input starts the filter settled on it."""
        u = [float(v) for v in u]
        if self._value is None:
            self._value, self._derivative = u, [0.0] * len(u)
        else:
            (p00, p01), (p10, p11) = self._phi
            g0, g1 = self._gamma
            y, dy = self._value, self._derivative
            self._value = [p00 * a + p01 * b + g0 * c for a, b, c in zip(y, dy, u)]
            self._derivative = [p10 * a + p11 * b + g1 * c for a, b, c in zip(y, dy, u)]
        return self._value, self._derivative


def rotor_shortfall_n(effectiveness: np.ndarray, lacking: np.ndarray) -> list[float]:
    """The s >= 0 (4,) of least total with effectiveness (2, 4) @ s = lacking (2,): one rotor,
    or the two whose effects bracket it; zeros where no rotors' effects bracket it (a posture
    whose rotors do not surround the centre of mass)."""
    return _Pairs(effectiveness.tolist()).shortfall_n(lacking)


class _Pairs:
    """The pairs of rotors whose effects are not on one line, for one effectiveness (2, 4, as
    nested lists): prepared once per setpoint, solved at every tick."""

    def __init__(self, e: list[list[float]]):
        self._pairs = []
        for i, j in _PAIRS:
            a, b, c, d = e[0][i], e[0][j], e[1][i], e[1][j]
            det = a * d - b * c
            if abs(det) > _SINGULAR * max(abs(a), abs(b), abs(c), abs(d)) ** 2:
                self._pairs.append((i, j, a, b, c, d, det))

    def shortfall_n(self, lacking) -> list[float]:
        """rotor_shortfall_n(effectiveness, lacking)."""
        t0, t1 = (float(v) for v in lacking)
        best, best_total = None, math.inf
        for i, j, a, b, c, d, det in self._pairs:
            s_i = (t0 * d - b * t1) / det
            s_j = (a * t1 - c * t0) / det
            if s_i >= 0.0 and s_j >= 0.0 and s_i + s_j < best_total:
                best, best_total = (i, s_i, j, s_j), s_i + s_j
        shortfall = [0.0] * ROTOR_COUNT
        if best is not None:
            shortfall[best[0]], shortfall[best[2]] = best[1], best[3]
        return shortfall


class GyroShortfallMeter:
    def __init__(self, af: Airframe, tick_s: float):
        self._commanded = MotorModel(af, tick_s)      # what the FC's commands give
        self._planned = MotorModel(af, tick_s)        # what the plan's thrusts would give
        self._filter = DifferentiatingFilter(tick_s)
        self.lacking_rad_s2 = [0.0, 0.0]              # the last roll and pitch acceleration lacking
        # the effectiveness last given, its rows and pairs: a setpoint's (numpy arrays are not
        # changed in place here), taken apart once, not at every tick
        self._prepared: tuple[np.ndarray, list[list[float]], _Pairs] | None = None

    def update(self, rates_frd_rad_s, thrust_cmd_n, planned_thrust_n, planned_accel_frd_rad_s2,
               effectiveness: np.ndarray | None) -> list[float] | None:
        """One tick: the gyro now (3,), the FC's commands (4,) and the plan's thrusts (4,) over
        the last tick, the plan's roll and pitch acceleration (2,); the rotors' shortfall (N,
        rotors 1..4), None without an effectiveness (the filter runs on regardless, so that it
        is settled when one comes)."""
        self._commanded.update(thrust_cmd_n)
        self._planned.update(planned_thrust_n)
        expected = [float(v) for v in planned_accel_frd_rad_s2]
        if effectiveness is not None:
            if self._prepared is None or self._prepared[0] is not effectiveness:
                rows = effectiveness.tolist()
                self._prepared = (effectiveness, rows, _Pairs(rows))
            gap = [c - p for c, p in zip(self._commanded.thrust_n, self._planned.thrust_n)]
            expected = [e + sum(k * g for k, g in zip(row, gap)) for e, row in zip(expected, self._prepared[1])]
        value, derivative = self._filter.update([float(rates_frd_rad_s[0]), float(rates_frd_rad_s[1]), *expected])
        self.lacking_rad_s2 = [value[2] - derivative[0], value[3] - derivative[1]]
        if effectiveness is None:
            return None
        shortfall = [s - DEADBAND_N for s in self._prepared[2].shortfall_n(self.lacking_rad_s2)]
        return [0.0 if 0.0 > s else s for s in shortfall]           # max(s, 0) without the call
