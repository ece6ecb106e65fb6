"""The hip servos' reference: commanded angles and rates shaped by the rate and acceleration limits.

A command gives a target angle and rate per hip; the target moves at that rate from the
time of the command (a setpoint trajectory, as a servo controller takes one) and stays in
the joint range. Every REFERENCE_PERIOD_S the reference rate is updated so that the
reference heads for the target as fast as the limits allow and brakes in time to stop
exactly on it (|rate| <= rate_max, |acceleration| <= accel_max, discrete braking); between
updates the rate is constant and the reference angle grows linearly. The MJCF's `hip{i}`
actuators integrate that rate natively, so the Python side runs at the servo controller's
rate, not at the physics rate.
"""

from __future__ import annotations

import math

REFERENCE_PERIOD_S = 0.005     # the servo controller's reference update (200 Hz)
_SETTLED_RAD = 1e-12
_SETTLED_RAD_S = 1e-9


class HipReference:
    def __init__(self, hip_rad, *, rate_max_rad_s: float, accel_max_rad_s2: float,
                 hip_min_rad: float, hip_max_rad: float, dt_s: float):
        self._rate_max = rate_max_rad_s
        self._dv = accel_max_rad_s2 * dt_s          # largest change of rate in one step
        self._brake_gain = 8.0 / (self._dv * dt_s)
        self._lo, self._hi = hip_min_rad, hip_max_rad
        self._dt = dt_s
        self.pos_rad = [self._clamp(float(q)) for q in hip_rad]
        self.rate_rad_s = [0.0] * len(self.pos_rad)
        self._goal = list(self.pos_rad)
        self._goal_rate = [0.0] * len(self.pos_rad)
        self.settled = True

    def _clamp(self, q: float) -> float:
        return min(self._hi, max(self._lo, q))

    def set_target(self, hip_rad, hip_rate_rad_s) -> None:
        """New targets (finite floats): angles clamped to the joint range, rates to the rate limit."""
        self._goal = [self._clamp(q) for q in hip_rad]
        self._goal_rate = [min(self._rate_max, max(-self._rate_max, r)) for r in hip_rate_rad_s]
        self.settled = False

    def advance(self) -> None:
        """One period of the reference: new rate, and the angle at the end of the period."""
        dt, dv, vmax, brake_gain = self._dt, self._dv, self._rate_max, self._brake_gain
        lo, hi = self._lo, self._hi
        pos, rate, goals, goal_rates = self.pos_rad, self.rate_rad_s, self._goal, self._goal_rate     # (in place)
        moving = False
        for i, q in enumerate(pos):
            goal, goal_rate, v = goals[i], goal_rates[i], rate[i]
            err = goal - q
            if abs(err) < _SETTLED_RAD and abs(v - goal_rate) < _SETTLED_RAD_S and goal_rate == 0.0:
                pos[i], rate[i] = goal, 0.0
                continue
            moving = True
            # Fastest rate relative to the goal from which k steps of -dv (and one remainder)
            # stop exactly on it.
            dist = abs(err)
            k = math.floor(0.5 * (math.sqrt(1.0 + brake_gain * dist) - 1.0))
            brake = dv * k + (dist - dv * dt * k * (k + 1) / 2) / ((k + 1) * dt)
            # min(c, max(-c, x)) as the comparisons it makes (the builtins' calls cost several times more)
            v_des = goal_rate + math.copysign(brake, err)
            v_des = v_des if v_des > -vmax else -vmax
            v_des = v_des if v_des < vmax else vmax
            dv_step = v_des - v
            dv_step = dv_step if dv_step > -dv else -dv
            v += dv_step if dv_step < dv else dv
            q_free = q + v * dt
            q = q_free if q_free > lo else lo       # _clamp
            q = q if q < hi else hi
            if abs(q - q_free) > _SETTLED_RAD:      # ran into the joint range: stop there
                v = 0.0
            pos[i], rate[i] = q, v
            goal += goal_rate * dt
            if not lo <= goal <= hi:
                goals[i], goal_rates[i] = self._clamp(goal), 0.0
            else:
                goals[i] = goal
        self.settled = not moving
