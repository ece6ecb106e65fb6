"""The centre of mass's offset from the hull centre and its rate, in closed form on Python floats.

`Airframe.com_offset_frd_m` and `com_offset_rate_frd_m_s` (m4/airframe.py, the one source of
truth) place every leg's lumps with array operations: about 20 us a call, on the critical path
of every control step (the ROM state, companion.telemetry). Here the same sums are taken leg by
leg on floats with the constants read from the airframe once, in the airframe's order of
operations, so the results are the same to the last bit (tests/core/test_com_offset.py checks
that over random postures). An angle that is not finite gives NaN, as the airframe's does.
"""

from __future__ import annotations

import math

from m4.airframe import Airframe


class ComOffset:
    def __init__(self, af: Airframe):
        signs = af.leg_direction_signs.tolist()
        length = af.leg_length_m
        # per leg: hip x, hip y, L sx, L sy, -L sx (the factors as the airframe multiplies them)
        self._legs = tuple((hx, hy, length * sx, length * sy, -length * sx)
                           for (hx, hy, _), (sx, sy) in zip(af.hip_positions_frd_m.tolist(), signs))
        # the legs' masses at their hips: the first moment the airframe's offset starts from
        self._at_hips = tuple((af.leg_mass_kg * af.hip_positions_frd_m.sum(axis=0)).tolist())
        self._swing_kg = af.leg_swing_mass_kg
        self._total_kg = af.total_mass_kg

    def offset_and_rate(self, hip_rad, hip_rate_rad_s) -> tuple[list[float], list[float]]:
        """(com_offset_frd_m (3), com_offset_rate_frd_m_s (3)) of posture hip_rad moving at
        hip_rate_rad_s (a float per leg each)."""
        reach_x, reach_y, rate_x, rate_y = [], [], [], []
        for (hx, hy, lsx, lsy, minus_lsx), q, qd in zip(self._legs, hip_rad, hip_rate_rad_s, strict=True):
            cos_q, sin_q = (math.cos(q), math.sin(q)) if math.isfinite(q) else (math.nan, math.nan)
            # hip -> hub as the airframe takes it: the hub's position less the hip's (rounded so)
            reach_x.append((hx + lsx * cos_q) - hx)
            reach_y.append((hy + lsy * sin_q) - hy)
            rate_x.append(minus_lsx * sin_q * qd)
            rate_y.append(lsy * cos_q * qd)
        swing, total, (mx, my, mz) = self._swing_kg, self._total_kg, self._at_hips
        offset = [(mx + swing * _sum(reach_x)) / total, (my + swing * _sum(reach_y)) / total,
                  (mz + swing * 0.0) / total]
        rate = [swing * _sum(rate_x) / total, swing * _sum(rate_y) / total, swing * 0.0 / total]
        return offset, rate


def _sum(values: list[float]) -> float:
    """The legs' values summed in order from 0.0, as numpy sums an array's rows (builtin sum
    may compensate its rounding: Python 3.12 does)."""
    total = 0.0
    for value in values:
        total += value
    return total
