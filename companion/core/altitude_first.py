"""Altitude before place: while the rotors have no thrust to spare, the NMPC gives up the
horizontal position first.

The NMPC's cost trades height against place by its weights (40 on height, 20 across), on a
model that does not know that tilting into moving air costs thrust (the rotors' inflow:
plant.md, "Wind, turbulence, gusts"). In 10-17 m/s of air after a lost rotor the plan holds
its place, tilts 30-38 deg into the air, and the rotors, saturated, lose a third of their
thrust to the inflow: the robot sinks 0.5-0.9 m (docs/fault-detection.md, "Held aloft").
A robot that drifts a metre with the air and keeps its height is the better outcome, so
while the plan saturates the rotors the horizontal position and velocity weights are scaled
down (`NmpcWeights.horizontal_saturated_scale`): the plan leans less, and the thrust it has
goes to the height.

Saturated: at least two usable rotors planned within SATURATION_MARGIN_N of their bound while
the disturbance estimate carries at least SHORTFALL_MIN of the weight downwards (thrust the
rotors do not deliver: the inflow's loss; a payload heavier than the airframe file says looks
the same to it, and there too height before place is the better trade). The mode starts after ENTER_S of such plans in a
row and ends after LEAVE_S without one. ENTER_S is above the longest saturation of every
built-in still-air flight (0.06 s, the transient at a rotor loss); SHORTFALL_MIN is above
the estimate of hover-rotor-loss-tight (at most 6.1 N downwards, 0.10 of the weight), whose
24 N rotors saturate for want of thrust, not to the air, and hold their place: no built-in
still-air flight enters the mode. In moderate turbulence the flights that sank had their
rotors saturated for 1.9-2.2 s at a time with 10-20 N (median) downwards. LEAVE_S keeps a
plan that stops saturating because it leans less from switching back at once and leaning
again.
"""

from __future__ import annotations

import numpy as np

SATURATION_MARGIN_N = 0.5
SATURATED_ROTORS_MIN = 2
SHORTFALL_MIN = 0.15             # of the weight
ENTER_S = 0.2
LEAVE_S = 1.0


class AltitudeFirst:
    """Whether the plans have been saturating the rotors: `update` after every plan."""

    def __init__(self, period_s: float, weight_n: float):
        if not period_s > 0:
            raise ValueError(f"AltitudeFirst period_s must be > 0, got {period_s}")
        self._shortfall_min_n = SHORTFALL_MIN * weight_n
        self._enter = max(1, round(ENTER_S / period_s))      # plans in a row
        self._leave = max(1, round(LEAVE_S / period_s))
        self._saturated = self._unsaturated = 0
        self.active = False

    def reset(self) -> None:
        self._saturated = self._unsaturated = 0
        self.active = False

    def update(self, thrust_n: np.ndarray, thrust_max_n: np.ndarray, disturbance_down_n: float) -> None:
        """After a plan whose first thrusts are thrust_n (4,) under the bounds thrust_max_n, made
        with disturbance_down_n (the estimate's NED down force): `active` for the next plan."""
        usable = thrust_max_n > SATURATION_MARGIN_N
        at_bound = int(np.count_nonzero(usable & (thrust_n >= thrust_max_n - SATURATION_MARGIN_N)))
        if at_bound >= SATURATED_ROTORS_MIN and disturbance_down_n >= self._shortfall_min_n:
            self._saturated, self._unsaturated = self._saturated + 1, 0
        else:
            self._saturated, self._unsaturated = 0, self._unsaturated + 1
        if self._saturated >= self._enter:
            self.active = True
        elif self._unsaturated >= self._leave:
            self.active = False


def horizontal_scaled(state_w: np.ndarray, position_cols: slice, velocity_cols: slice, scale: float) -> np.ndarray:
    """A copy of the state weights (N+1, 20) with the north and east position and velocity
    weights times scale."""
    out = np.array(state_w, dtype=float)
    out[:, position_cols.start:position_cols.start + 2] *= scale
    out[:, velocity_cols.start:velocity_cols.start + 2] *= scale
    return out
