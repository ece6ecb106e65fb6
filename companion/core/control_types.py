"""The control step's plain types and checks, free of CasADi and Zenoh: what the link, the
feed and the tests share with the controller without loading a solver.

- FaultState, FaultStatus: the fault detector's answer (M4_FAULT_STATUS's content; its kind is
  m4.fault_kind.FaultKind).
- plausible_state: whether a measured ROM state can be planned from.
- one_period_apart: whether two frame instants are consecutive control steps (the controller's
  disturbance update and the FC's applied thrust both ask it).
- thrust_bounds, safe_setpoint: the last word on a setpoint before it leaves the process
  (every value finite, thrusts within [thrust_min, bound], hips within the joint range and
  the same-side sum, rates within the servo's limit; what is not finite becomes a safe value).
"""

from __future__ import annotations

import functools
import math
import struct
from array import array
from dataclasses import dataclass
from enum import IntEnum

import numpy as np

from companion.core import rom_layout
from m4.airframe import ROTOR_COUNT, Airframe
from m4.fault_kind import FaultKind
from m4.setpoint import RateFeedback, Setpoint, ShortfallCover

_HIP_MARGIN_RAD = 0.5            # measured hips beyond the joint range by more than this are broken
_CONSECUTIVE_TOLERANCE = 0.5     # of a period: the FC's frames are on a grid of the period, and half
                                 # of one tells one period (jittered) from none or two (a lost frame)
_PLAUSIBLE = ((rom_layout.P, 1e5), (rom_layout.EULER, 2 * np.pi), (rom_layout.V, 100.0),
              (rom_layout.RATES, 100.0), (rom_layout.HIP_RATE, 100.0))


@functools.cache
def _plausible_range(hip_min_rad: float, hip_max_rad: float) -> tuple[np.ndarray, np.ndarray]:
    """(NX,) the least and the most each state entry may be: +-its limit, the hips within the
    joint range widened by _HIP_MARGIN_RAD (every entry finite: NaN and inf fall outside).
    Read-only: the cache hands the same arrays to every caller."""
    most = np.full(rom_layout.NX, np.inf)
    for part, limit in _PLAUSIBLE:
        most[part] = limit
    least = -most
    least[rom_layout.HIP], most[rom_layout.HIP] = hip_min_rad - _HIP_MARGIN_RAD, hip_max_rad + _HIP_MARGIN_RAD
    least.flags.writeable = most.flags.writeable = False
    return least, most


_FLOAT32, _INT32 = struct.Struct("<f"), struct.Struct("<i")
_FLOAT32_LEAST = _FLOAT32.unpack(_INT32.pack(1))[0]      # the least positive float32 (a subnormal)


class FaultState(IntEnum):
    """Values as in M4_FAULT_STATUS.state."""

    HEALTHY = 0
    SUSPECT = 1
    CONFIRMED = 2


@dataclass(frozen=True)
class FaultStatus:
    state: FaultState
    rotor: int | None                  # 1..4 (suspect or confirmed), None when healthy
    kind: FaultKind
    thrust_max_estimate_n: np.ndarray  # (4,) what each rotor can still give: the limits, the estimate on the faulty one
    thrust_bound_n: np.ndarray         # (4,) the NMPC's bounds: the estimate plus the probe on the faulty rotor
    detected_at_s: float | None        # time of the latest confirmation
    message: str                       # "thrust loss rotor 4 (propeller)" once confirmed
    deficit_n: np.ndarray              # (4,) latest deficit estimate per rotor hypothesis (diagnostics)


def plausible_state(af: Airframe, x) -> bool:
    """Finite and physically possible (a state outside this is a broken measurement: the
    controller falls back instead of planning from it)."""
    least, most = _plausible_range(af.hip_min_rad, af.hip_max_rad)
    x = np.asarray(x, dtype=float)
    return bool(((least <= x) & (x <= most)).all())      # every comparison is false for NaN


def one_period_apart(earlier_s: float, later_s: float, period_s: float) -> bool:
    """Whether frames at these FC instants are consecutive control steps: one period apart,
    within _CONSECUTIVE_TOLERANCE of a period."""
    return abs(later_s - earlier_s - period_s) <= _CONSECUTIVE_TOLERANCE * period_s


def thrust_bounds(af: Airframe, thrust_bound_n) -> np.ndarray:
    """Per-rotor upper bounds: finite entries clipped into [thrust_min, thrust_max], the rest the maximum."""
    return np.array(thrust_bound_list(af, thrust_bound_n))


def thrust_bound_list(af: Airframe, thrust_bound_n) -> list[float]:
    """thrust_bounds as Python floats (four comparisons each cost less than a numpy call)."""
    bound = np.asarray(thrust_bound_n, dtype=float).reshape(-1)
    if bound.size != ROTOR_COUNT:
        raise ValueError(f"thrust_bound_n must have {ROTOR_COUNT} entries, got {bound.size}")
    # The bounds are ordered (m4.airframe): one comparison a clamp, which gives the bound itself
    # when a value equals it, as numpy's minimum and maximum do (+0.0 for a -0.0 at a bound of 0).
    least_n, most_n = af.thrust_min_n, af.thrust_max_n
    return [(least_n if b <= least_n else most_n if b >= most_n else b) if math.isfinite(b) else most_n
            for b in bound.tolist()]


def safe_setpoint(af: Airframe, thrust_n, hip_rad, hip_rate_rad_s, thrust_bound_n, measured_hip_rad=None,
                  thrust_cut: bool = False, rate_feedback: RateFeedback | None = None,
                  shortfall_cover: ShortfallCover | None = None) -> Setpoint:
    """A setpoint that is finite and within every bound, whatever goes in (NaN, inf, out of range),
    with the FC's rate feedback and cover as they are (each checked where it is made).

    Its twelve values are checked as Python floats (the step answers with them: a dozen float
    comparisons cost less than numpy's calls on arrays of four), each clamp a comparison that
    keeps a value equal to its bound (a -0.0 stays -0.0, as Python's min and max kept it): the
    airframe's bounds are ordered (m4.airframe) and thrust_bound_list's lie within them."""
    r = ROTOR_COUNT
    thrust, hip, rate = (np.asarray(v, dtype=float).reshape(r).tolist() for v in (thrust_n, hip_rad, hip_rate_rad_s))
    if not all(map(math.isfinite, thrust + hip + rate)):
        thrust, hip, rate = _finite(af, thrust, hip, rate, measured_hip_rad)
    least_n = 0.0 if thrust_cut else af.thrust_min_n
    hip_min_rad, hip_max_rad, rate_max_rad_s = af.hip_min_rad, af.hip_max_rad, af.hip_rate_max_rad_s
    bound = thrust_bound_list(af, thrust_bound_n)
    thrust = [0.0] * r if thrust_cut else [least_n if t < least_n else b if t > b else t
                                           for t, b in zip(thrust, bound, strict=True)]
    hip = [hip_min_rad if h < hip_min_rad else hip_max_rad if h > hip_max_rad else h for h in hip]
    rate = [-rate_max_rad_s if v < -rate_max_rad_s else rate_max_rad_s if v > rate_max_rad_s else v for v in rate]
    for i, j in af.same_side_pairs:
        excess = hip[i] + hip[j] - af.same_side_sum_max_rad
        if excess > 0:
            hip[i], hip[j] = max(hip[i] - excess / 2, hip_min_rad), max(hip[j] - excess / 2, hip_min_rad)
    # As float32: thrusts within [thrust_min (0 when cut), bound], the hips at most themselves,
    # the rates within +-hip_rate_max.
    sent = np.array(_float32_within(thrust + hip + rate, [least_n] * r + [hip_min_rad] * r + [-rate_max_rad_s] * r,
                                    bound + hip + [rate_max_rad_s] * r))
    return Setpoint(thrust_n=sent[:r], hip_rad=sent[r:2 * r], hip_rate_rad_s=sent[2 * r:], thrust_cut=thrust_cut,
                    rate_feedback=rate_feedback, shortfall_cover=shortfall_cover)


def _finite(af: Airframe, thrust: list[float], hip: list[float], rate: list[float],
            measured_hip_rad) -> tuple[list[float], list[float], list[float]]:
    """What stands in for a value that is not finite: hover thrust, the measured hip (else the
    nominal one), no rate."""
    nominal = [af.nominal_hip_rad] * ROTOR_COUNT
    if measured_hip_rad is not None:
        measured = np.asarray(measured_hip_rad, dtype=float).reshape(ROTOR_COUNT).tolist()
        nominal = [m if math.isfinite(m) else n for m, n in zip(measured, nominal, strict=True)]
    return ([t if math.isfinite(t) else af.hover_thrust_per_rotor_n for t in thrust],
            [h if math.isfinite(h) else n for h, n in zip(hip, nominal, strict=True)],
            [v if math.isfinite(v) else 0.0 for v in rate])


def _float32_within(values: list[float], lo: list[float], hi: list[float]) -> list[float]:
    """Values that stay within [lo, hi] as the float32 MAVLink carries (rounding to the nearest
    float32 may step past a bound such as pi/2); the hips pass hi = themselves, so they never
    round up and a pair's sum stays within its bound."""
    sent = array("f", values).tolist()               # each the nearest float32, as numpy's astype rounds
    for i, (v, low, high) in enumerate(zip(sent, lo, hi, strict=True)):
        if v > high:
            sent[i] = v = _float32_next(v, down=True)
        if v < low:
            sent[i] = _float32_next(v, down=False)
    return sent


def _float32_next(v: float, down: bool) -> float:
    """The float32 next to the float32 value v (finite) downwards or upwards, as np.nextafter on
    float32 gives it, from v's bits (numpy's scalars cost a microsecond a call, and the hips round
    up about every other step): a float's bits read as a signed integer move one unit away from
    zero for a larger magnitude, toward it for a smaller one; past zero, the least subnormal of
    the other sign."""
    if v == 0.0:
        return -_FLOAT32_LEAST if down else _FLOAT32_LEAST
    bits = _INT32.unpack(_FLOAT32.pack(v))[0]
    return _FLOAT32.unpack(_INT32.pack(bits + (-1 if (v > 0.0) == down else 1)))[0]
