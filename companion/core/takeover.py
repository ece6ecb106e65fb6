"""Taking control from the flight controller's own controller without a thrust step.

Before the companion's first setpoint, and whenever its setpoints went stale at the FC (a
restart, a link loss, a stale telemetry stream), the FC's failsafe flies. At the takeover the
FC's thrusts (what it reports commanding, M4_THRUSTER_STATUS.thrust_cmd_n) can be far from
the NMPC's: 5.5-20.9 N apart was measured after a restart. So from the takeover on, each
setpoint's thrusts move at most SLEW_N_S x period from the previous one (the FC's report at
the takeover, then what we sent), and once the NMPC's thrusts are within that reach of the
last ones the ramp ends. A rotor the FC does not report (NaN) is not limited. Pure logic.
"""

from __future__ import annotations

import numpy as np

# 3 N per step at 50 Hz: a 20 N gap closes in 7 periods (0.13 s), about the time a motor with
# a 30 ms lag takes over its whole range, and the first setpoint of a start in hover (less
# than 3 N from the FC's hold) is not touched.
SLEW_N_S = 150.0


class TakeoverRamp:
    def __init__(self, period_s: float, slew_n_s: float = SLEW_N_S):
        self.step_n = slew_n_s * period_s
        self._last_n: np.ndarray | None = None            # None: no ramp under way

    @property
    def active(self) -> bool:
        return self._last_n is not None

    def begin(self, fc_thrust_cmd_n) -> None:
        """Take over from what the FC reports it commands (None: it does not say: no ramp)."""
        self._last_n = None if fc_thrust_cmd_n is None else np.asarray(fc_thrust_cmd_n, dtype=float).copy()

    def end(self) -> None:
        self._last_n = None

    def limit(self, thrust_n: np.ndarray, thrust_max_n: np.ndarray) -> np.ndarray:
        """thrust_n, each rotor at most one step from the last (and within thrust_max_n)."""
        if self._last_n is None:
            return thrust_n
        last, step = self._last_n, self.step_n
        known = np.isfinite(last)
        if np.all(np.abs(thrust_n - last)[known] <= step):
            self._last_n = None                      # within reach: the NMPC flies alone from here
            return thrust_n
        out = np.where(known, np.clip(thrust_n, last - step, last + step), thrust_n)
        out = np.minimum(out, thrust_max_n)
        self._last_n = out
        return out
