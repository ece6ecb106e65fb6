"""The mission's reference for the NMPC: where the centre of mass should be over the horizon.
`reference_rows` makes the same rows from any plan (the hold the FC's HOLD mode asks for).

The plan itself (legs, holds, the brake after a fault, the landing) is `m4.mission_plan`,
shared with the simulator's metrics; this adds the NMPC's rows. Only position and velocity
carry information; the attitude, rates and hip rates of the reference rows are zero and the
hips nominal (the NMPC weighs neither yaw nor the reference's hips).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from companion.core import rom
from m4.airframe import Airframe
from m4.mission import Mission
from m4.mission_plan import DEFAULT_ACCEL_MAX_M_S2, MissionPlan


@dataclass(frozen=True)
class ReferenceConfig:
    accel_max_m_s2: float = DEFAULT_ACCEL_MAX_M_S2     # acceleration limit of every speed change of the reference

    def validate(self) -> None:
        if not (math.isfinite(self.accel_max_m_s2) and self.accel_max_m_s2 > 0):
            raise ValueError(f"ReferenceConfig.accel_max_m_s2 must be > 0, got {self.accel_max_m_s2}")


class MissionReference(MissionPlan):
    """The NMPC's reference along a mission flown from start_ned_m (centre of mass) at t0_s."""

    def __init__(self, mission: Mission, start_ned_m, af: Airframe,
                 config: ReferenceConfig = ReferenceConfig(), t0_s: float = 0.0):
        config.validate()
        super().__init__(mission, start_ned_m, af, config.accel_max_m_s2, t0_s)
        self._af = af
        self._kept: tuple[tuple, np.ndarray] | None = None      # the last rows made, by their arguments and plan

    def reference(self, t_s: float, horizon: int, dt_s: float) -> np.ndarray:
        """(horizon + 1, rom.NX) ROM states at t_s, t_s + dt_s, ..., t_s + horizon dt_s (read-only).

        The last rows made are kept for the same arguments and plan (a fault's hold or a landing
        makes a new plan): the controller's preparation makes the next step's rows, and that step
        asks for them again whenever the FC's clock has moved one period on to the last bit."""
        key = (t_s, horizon, dt_s, self._plan)
        if self._kept is None or self._kept[0] != key:
            rows = reference_rows(self.state, self._af, t_s, horizon, dt_s)
            rows.flags.writeable = False
            self._kept = (key, rows)
        return self._kept[1]


def reference_rows(state: Callable[[float], tuple[np.ndarray, np.ndarray]], af: Airframe, t_s: float,
                   horizon: int, dt_s: float) -> np.ndarray:
    """(horizon + 1, rom.NX) ROM states at t_s, t_s + dt_s, ..., t_s + horizon dt_s of a plan
    (`state(t)`: position and velocity, NED)."""
    if horizon < 0 or not dt_s > 0:
        raise ValueError(f"reference needs horizon >= 0 and dt_s > 0, got {horizon}, {dt_s}")
    out = np.zeros((horizon + 1, rom.NX))
    out[:, rom.HIP] = af.nominal_hip_rad
    for k in range(horizon + 1):
        out[k, rom.P], out[k, rom.V] = state(t_s + k * dt_s)
    return out
