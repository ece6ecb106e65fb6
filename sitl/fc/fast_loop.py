"""The FC's fast loop at every tick, on Python floats: the companion's thrusts plus its rate
feedback on our gyro (m4.setpoint.RateFeedback) and the other rotors' cover for the rotors'
shortfall (m4.setpoint.ShortfallCover), clamped to the rotors' range. The same sums as those
classes' numpy, taken apart once per setpoint: numpy on vectors of three and four costs more
than the sums at 250 Hz.

FC logic, without sockets: sitl/fc/flight_controller.py holds one per setpoint in force.
"""

from __future__ import annotations

import math

from m4.setpoint import Setpoint


class FastLoop:
    def __init__(self, sp: Setpoint, thrust_min_n: float, thrust_max_n: float):
        self._thrust_n = sp.thrust_n.tolist()
        self._lo_n, self._hi_n = thrust_min_n, thrust_max_n
        fb = sp.rate_feedback
        self._feedback = None if fb is None else (fb.rates_ref_frd_rad_s.tolist(),
                                                  fb.rates_ref_change_frd_rad_s2.tolist(),
                                                  fb.gain_n_per_rad_s.tolist())
        self._cover = None if sp.shortfall_cover is None else sp.shortfall_cover.gain.tolist()

    def thrust_n(self, rates_frd_rad_s, in_force_s: float, period_s: float,
                 shortfall_n: list[float] | None) -> list[float]:
        """The thrusts (N, rotors 1..4) for the gyro's body rates (3,) after the setpoint has
        been in force in_force_s (planned rates held after period_s) and the rotors' shortfall
        (None: nothing measures it). Rates that are not finite give no feedback."""
        change = [0.0, 0.0, 0.0, 0.0]
        rates = [float(r) for r in rates_frd_rad_s]
        if self._feedback is not None and all(map(math.isfinite, rates)):
            ref, ref_change, gain = self._feedback
            t_s = min(max(in_force_s, 0.0), period_s)
            error = [r + c * t_s - m for r, c, m in zip(ref, ref_change, rates)]
            change = [row[0] * error[0] + row[1] * error[1] + row[2] * error[2] for row in gain]
        if self._cover is not None and shortfall_n is not None:
            change = [c + sum(g * s for g, s in zip(row, shortfall_n)) for c, row in zip(change, self._cover)]
        lo, hi = self._lo_n, self._hi_n
        thrust = [t + c for t, c in zip(self._thrust_n, change)]
        thrust = [lo if lo > t else t for t in thrust]              # max(t, lo), min(t, hi): without the
        return [hi if hi < t else t for t in thrust]                # builtins' calls, several times the sums'
