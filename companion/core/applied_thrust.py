"""The thrust the flight controller commanded over a control period, from its own reports.

The FC reports, with every telemetry frame, what it commands its ESCs (M4_THRUSTER_STATUS
thrust_cmd_n at its time_boot_ms). Over a delayed, lossy link that is the only certain
account of which of our setpoints flew when: a setpoint lost on the way up leaves the
previous one in force, and our estimate of the link's lead is a median that a jittery link
misses by a period. What the disturbance estimate and the fault detector compare the robot
with is therefore the FC's report, not our guess.

Our setpoints reach the FC lead_s after the instants they answer, at frame + (lead_s mod P)
for frames P apart: over the period (t - P, t] the command reported at t - P is in force
until that arrival and the one reported at t after it. The thrust over the period is their
mix by those shares (for a model linear in thrust over one period, the mean). Without the
report at t - P (the first frame, or one lost) the report at t stands for the period.

Pure logic: no clock, no I/O.
"""

from __future__ import annotations

import math

import numpy as np

from companion.core.control_types import one_period_apart
from m4.airframe import ROTOR_COUNT


class AppliedThrust:
    """The FC's last two thrust-command reports (four Python floats each: cheaper than numpy's
    calls on arrays of four)."""

    def __init__(self, period_s: float):
        self.period_s = period_s
        self._previous: tuple[float, list[float]] | None = None
        self._newest: tuple[float, list[float]] | None = None

    def report(self, time_s: float, thrust_cmd_n) -> None:
        """The FC's command at FC instant time_s (None or any non-finite entry: it cannot
        tell, which forgets what was reported)."""
        thrust = None if thrust_cmd_n is None else np.asarray(thrust_cmd_n, dtype=float).reshape(ROTOR_COUNT).tolist()
        if thrust is None or not all(map(math.isfinite, thrust)):
            self.clear()
            return
        if self._newest is not None and time_s <= self._newest[0]:
            return                                  # a repeated or older frame changes nothing
        self._previous, self._newest = self._newest, (time_s, thrust)

    def clear(self) -> None:
        self._previous = self._newest = None

    def over_period(self, time_s: float, lead_s: float) -> np.ndarray | None:
        """The thrust (4,) the FC commanded over the period ending at time_s, given our
        setpoints' lead; None without a report at time_s."""
        if self._newest is None or abs(self._newest[0] - time_s) > 1e-9:
            return None
        now = self._newest[1]
        previous = self._previous
        p = self.period_s
        if previous is None or not one_period_apart(previous[0], time_s, p):
            return np.array(now)
        share_previous = (max(float(lead_s), 0.0) % p) / p if math.isfinite(lead_s) else 0.0
        return np.array([share_previous * b + (1.0 - share_previous) * n
                         for b, n in zip(previous[1], now, strict=True)])
