"""The centre of mass's offset in closed form: the airframe's figures, to the last bit."""

from __future__ import annotations

import math

import numpy as np

from m4.airframe import load_airframe
from companion.core.com_offset import ComOffset

AF = load_airframe()


def _bits(values) -> list[str]:
    return [float(v).hex() for v in values]          # tells -0.0 from 0.0 and compares NaN


def test_offset_and_rate_are_the_airframes_to_the_bit_over_random_postures():
    com, rng = ComOffset(AF), np.random.default_rng(21)
    for k in range(2000):
        hip = rng.uniform(-2 * math.pi, 2 * math.pi, 4)
        hip_rate = rng.normal(0.0, 3.0, 4) * (k % 3)          # every third at rest: signed zeros
        if k % 40 == 0:
            hip[k % 4] = (math.inf, -math.inf, math.nan)[k % 3]      # not finite: NaN, as the airframe gives
        offset, rate = com.offset_and_rate(hip.tolist(), hip_rate.tolist())
        assert _bits(offset) == _bits(AF.com_offset_frd_m(hip))
        assert _bits(rate) == _bits(AF.com_offset_rate_frd_m_s(hip, hip_rate))
