"""The baseline to beat: ArduCopter's thrust-loss check, ported to the M4's signals.

ArduCopter (ArduCopter/crash_check.cpp, Copter::thrust_loss_check) declares a "potential
thrust loss" when, continuously for 1 s: the attitude target is within 15 deg of level, the
throttle is at least 90 % or the mixer hit its upper limit (and at least 25 %), the vehicle
descends, and the attitude error is below 30 deg. It says nothing of which rotor, nor how
much thrust is left; its reaction (thrust boost) is a different controller mode.

Here: the reference is always level (the mission reference carries no attitude), so the
angle conditions become "measured tilt below 30 deg"; "throttle upper limit" is any rotor
commanded at or above saturation_share of its limit (the M4's thrust-to-weight of 2 keeps the
collective far below 90 % even with a rotor off, so the collective condition alone would
never fire); "descending" is v_z (NED) > 0.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from m4.airframe import ROTOR_COUNT, Airframe
from m4.fault_kind import FaultKind
from companion.core import rom
from companion.core.control_types import FaultState, FaultStatus


@dataclass(frozen=True)
class ThrustLossCheckConfig:
    trigger_s: float = 1.0              # THRUST_LOSS_CHECK_TRIGGER_SEC
    saturation_share: float = 0.9       # THRUST_LOSS_CHECK_MINIMUM_THROTTLE, applied per rotor
    collective_min_share: float = 0.25  # no check below 25 % collective
    tilt_max_rad: float = math.radians(30.0)   # CRASH_CHECK_ANGLE_DEVIATION_DEG


class ThrustLossCheck:
    """update() at telemetry rate; the status names no rotor and keeps the limits as bounds."""

    def __init__(self, af: Airframe, config: ThrustLossCheckConfig = ThrustLossCheckConfig()):
        self._af, self._c = af, config
        self._since_s: float | None = None
        self._detected_at_s: float | None = None

    def update(self, time_s: float, state_measured, thrust_cmd_n, thrust_limit_n=None, esc=None) -> FaultStatus:
        """Same signature as FaultDetector.update; the check has no use for ESC telemetry."""
        x = np.asarray(state_measured, dtype=float)
        cmd = np.asarray(thrust_cmd_n, dtype=float)
        limit = np.full(ROTOR_COUNT, self._af.thrust_max_n) if thrust_limit_n is None else np.asarray(thrust_limit_n)
        if self._detected_at_s is None:
            roll, pitch = x[rom.EULER][:2]
            tilt = math.acos(max(-1.0, min(1.0, math.cos(roll) * math.cos(pitch))))
            suspicious = (np.any(cmd >= self._c.saturation_share * limit)
                          and cmd.sum() >= self._c.collective_min_share * limit.sum()
                          and x[rom.V][2] > 0.0 and tilt < self._c.tilt_max_rad)
            if not suspicious:
                self._since_s = None
            elif self._since_s is None:
                self._since_s = time_s
            elif time_s - self._since_s >= self._c.trigger_s - 1e-9:
                self._detected_at_s = time_s
        confirmed = self._detected_at_s is not None
        return FaultStatus(state=FaultState.CONFIRMED if confirmed else
                           FaultState.SUSPECT if self._since_s is not None else FaultState.HEALTHY,
                           rotor=None, kind=FaultKind.UNKNOWN, thrust_max_estimate_n=limit.copy(),
                           thrust_bound_n=limit.copy(), detected_at_s=self._detected_at_s,
                           message="potential thrust loss" if confirmed else "",
                           deficit_n=np.full(ROTOR_COUNT, math.nan))
