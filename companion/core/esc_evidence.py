"""What the ESCs' own telemetry says about each rotor: the thrust its speed and load imply.

An ESC reports rotor speed (RPM), current and voltage (ArduPilot's ESC_TELEMETRY_1_TO_4),
never thrust. A propeller's thrust is k_t * omega^2 at the speed it turns, so long as it is
on the shaft and whole; its aerodynamic load shows in the motor's power, current * voltage,
which grows as omega^3 (torque k_q omega^2 times speed). Per rotor:

- stopped (motor or ESC dead): the speed collapses, and with it the thrust k_t omega^2;
- unloaded (propeller lost): the motor overspeeds, its thrust is 0 whatever it turns at,
  and its load index current * voltage / rpm^3 falls far below the other rotors'. The
  serial current comes at a tenth of the RPM's rate and each ESC's at its own instant, so
  each current is judged against the speed of the frame it first came in
  (`current_speed_rpm`: a rotor speeding up would otherwise read a current from 0.1 s before
  as a collapsed load), a collapsed load index counts only on a rotor already turning faster
  than asked, and the overspeed alone also tells;
- a rotor that turns slower than the voltage and command ask (a weak motor) delivers the
  thrust of the speed it reaches;
- a chipped propeller turns normally: the ESC cannot see it (the model residual must).

The load index is compared with the median of the other rotors', not with a constant, so an
unknown motor constant, a sagging battery or a temperature drift cancel. The thrust a full
command can give at the ESC's voltage (the speed scales with voltage) is the battery's
common ceiling: a rotor held there is not a faulty rotor. Pure functions, no I/O.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum

import numpy as np

from m4.airframe import ROTOR_COUNT, Airframe
from m4.units import RPM_TO_RAD_S

# What ESC_TELEMETRY_1_TO_4 can carry (uint16 rpm, centiamps, centivolts): beyond it a number
# is no reading, and its powers would overflow.
_RPM_MAX = 65535.0
_CURRENT_MAX_A = _VOLTAGE_MAX_V = 655.35


class RotorCondition(IntEnum):
    NORMAL = 0          # turns as asked, loaded: the ESC sees nothing wrong
    STOPPED = 1         # speed collapsed
    UNLOADED = 2        # turning with no aerodynamic load: the propeller is gone
    SLOW = 3            # turning, loaded, but slower than the command asks


@dataclass(frozen=True)
class EscSample:
    """One ESC_TELEMETRY frame of the four rotors (NaN: not reported)."""

    time_s: float                  # the flight controller's clock
    rpm: np.ndarray                # (4,)
    current_a: np.ndarray          # (4,)
    voltage_v: np.ndarray          # (4,)


@dataclass(frozen=True)
class PropellerModel:
    """The airframe's propeller and motor figures the ESC evidence needs."""

    thrust_coefficient_n_s2: float     # k_t: thrust = k_t omega^2, omega in rad/s
    speed_max_rad_s: float             # at the nominal voltage, full command
    voltage_nominal_v: float

    @classmethod
    def from_airframe(cls, af: Airframe) -> "PropellerModel":
        return cls(thrust_coefficient_n_s2=af.thrust_coefficient_n_s2, speed_max_rad_s=af.rotor_speed_max_rad_s,
                   voltage_nominal_v=af.battery_nominal_voltage_v)

    def thrust_n(self, rpm: np.ndarray) -> np.ndarray:
        return self.thrust_coefficient_n_s2 * (np.asarray(rpm, dtype=float) * RPM_TO_RAD_S) ** 2

    def rpm(self, thrust_n: np.ndarray) -> np.ndarray:
        return np.sqrt(np.maximum(thrust_n, 0.0) / self.thrust_coefficient_n_s2) / RPM_TO_RAD_S

    def ceiling_n(self, voltage_v: float) -> float:
        """The thrust a full command gives at this supply voltage (speed proportional to it)."""
        omega = self.speed_max_rad_s * min(voltage_v / self.voltage_nominal_v, 1.0)
        return self.thrust_coefficient_n_s2 * omega**2


@dataclass(frozen=True)
class EscThresholds:
    stopped_share: float = 0.3        # turning below this share of the expected speed: stopped
    slow_share: float = 0.9           # below this share (and loaded): slow
    unloaded_load_share: float = 0.25  # load index below this share of the other rotors' median: unloaded
                                       # (a propeller with half its blade area left keeps about half)
    overspeed_share: float = 1.15     # this far above the expected speed: unloaded
    loaded_share: float = 1.05        # a collapsed load index counts only above this speed share (currents are stale)
    speed_min_rpm: float = 500.0      # below this the load index means nothing


@dataclass(frozen=True)
class EscReading:
    """Per rotor: what the ESC frame says it delivers and how it behaves."""

    rpm: np.ndarray                        # (4,) as reported (NaN: not reported)
    thrust_n: np.ndarray                   # (4,) k_t omega^2, 0 when unloaded; NaN when the ESC says nothing
    condition: tuple[RotorCondition, ...]  # (4,)
    battery_ceiling_n: float               # what a full command gives at the reported voltage (inf: unknown)
    voltage_v: float                       # the ESCs' median voltage (NaN: unknown)


def current_speed_rpm(sample: EscSample, before: EscSample | None,
                      before_speed_rpm: list[float] | None) -> list[float]:
    """Each rotor's speed when the current `sample` reports was measured: the speed of the frame
    that current first came in. A current the frame `before` reported already keeps the speed it
    came with (`before_speed_rpm`, this function's answer for `before`); a new one, this frame's."""
    rpm = _reported(sample.rpm, _RPM_MAX)
    if before is None or before_speed_rpm is None:
        return rpm
    return [held if now_a == then_a and math.isfinite(held) else r for r, held, now_a, then_a
            in zip(rpm, before_speed_rpm, _floats(sample.current_a), _floats(before.current_a))]


def read_escs(sample: EscSample, expected_n: list[float] | np.ndarray, model: PropellerModel,
              th: EscThresholds = EscThresholds(), current_rpm: list[float] | None = None) -> EscReading:
    """The thrusts and conditions of one ESC frame, against the thrust the rotors should give now
    (the command through the motor lag, within the battery's ceiling). current_rpm: each rotor's
    speed when its current was measured (`current_speed_rpm`; None: this frame's). Four rotors:
    Python floats, numpy only for the propeller model's and the load's powers."""
    rpm = _reported(sample.rpm, _RPM_MAX)
    current = [v if v > 0.0 else math.nan for v in _reported(sample.current_a, _CURRENT_MAX_A)]  # 0: not polled yet
    voltage = _reported(sample.voltage_v, _VOLTAGE_MAX_V)
    volts = [v for v in voltage if math.isfinite(v) and v > 0]
    volts_v = _median(volts) if volts else math.nan
    ceiling = model.ceiling_n(volts_v) if volts else math.inf
    expected_rpm = model.rpm(np.minimum(expected_n, ceiling)).tolist()
    load_rpm = rpm if current_rpm is None else [c if math.isfinite(c) else r for c, r in zip(current_rpm, rpm)]
    cubes = (np.maximum(load_rpm, th.speed_min_rpm) ** 3).tolist()
    loads = [c * (v if math.isfinite(v) else 1.0) / cube if math.isfinite(r) and r >= th.speed_min_rpm
             and math.isfinite(c) else math.nan for r, c, v, cube in zip(rpm, current, voltage, cubes)]
    shares = [r / e if e >= th.speed_min_rpm else math.nan for r, e in zip(rpm, expected_rpm)]
    measured = [(j, v) for j, v in enumerate(loads) if math.isfinite(v)]
    conditions = []
    for i, (load_i, share_i, rpm_i) in enumerate(zip(loads, shares, rpm)):
        unloaded = share_i > th.overspeed_share
        if math.isfinite(load_i) and share_i > th.loaded_share and (others := [v for j, v in measured if j != i]):
            unloaded |= load_i < th.unloaded_load_share * _median(others)
        conditions.append(_condition(share_i, unloaded, th) if math.isfinite(rpm_i) else RotorCondition.NORMAL)
    thrust = [0.0 if c is RotorCondition.UNLOADED else t for c, t in zip(conditions, model.thrust_n(rpm).tolist())]
    return EscReading(rpm=np.array(rpm), thrust_n=np.array(thrust), condition=tuple(conditions),
                      battery_ceiling_n=ceiling, voltage_v=volts_v)


def _reported(values, most: float) -> list[float]:
    """The four values as reported; NaN (not reported) where one is not a reading: not finite,
    negative or beyond `most`."""
    return [v if 0.0 <= v <= most else math.nan for v in _floats(values)]


def _floats(values) -> list[float]:
    """The four rotors' values as Python floats."""
    return np.asarray(values, dtype=float).reshape(ROTOR_COUNT).tolist()


def _median(values: list[float]) -> float:
    """np.median's value (the middle two averaged as np.mean does: their sum halved)."""
    ordered, middle = sorted(values), len(values) // 2
    return ordered[middle] if len(values) % 2 else (ordered[middle - 1] + ordered[middle]) / 2


def _condition(speed_share: float, unloaded: bool, th: EscThresholds) -> RotorCondition:
    if not math.isfinite(speed_share):                  # nothing expected (rotor commanded idle)
        return RotorCondition.UNLOADED if unloaded else RotorCondition.NORMAL
    if speed_share < th.stopped_share:
        return RotorCondition.STOPPED
    if unloaded:
        return RotorCondition.UNLOADED
    return RotorCondition.SLOW if speed_share < th.slow_share else RotorCondition.NORMAL
