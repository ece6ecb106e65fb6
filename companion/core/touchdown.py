"""Touchdown: the centre of mass has been at ground height and still for a while.

The companion cuts thrust when this reports a touchdown during a landing. Pure logic: feed
it the measured height and vertical speed of the centre of mass at telemetry rate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class TouchdownConfig:
    height_tolerance_m: float = 0.05        # centre of mass at most this far above its standing height
    vertical_speed_max_m_s: float = 0.1     # |v_z| at most this
    dwell_s: float = 0.3                    # both, without a break, for this long

    def validate(self) -> None:
        for name in ("height_tolerance_m", "vertical_speed_max_m_s", "dwell_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"TouchdownConfig.{name} must be > 0, got {value}")


class TouchdownDetector:
    """Latches once the robot rests on the ground: z_ned within height_tolerance_m of
    ground_com_z_ned_m (or below it) and |v_z| small, continuously for dwell_s."""

    def __init__(self, ground_com_z_ned_m: float, config: TouchdownConfig = TouchdownConfig()):
        config.validate()
        self._ground_z, self._config = ground_com_z_ned_m, config
        self._still_since_s: float | None = None
        self.touchdown_s: float | None = None

    def at_ground_height(self, z_ned_m: float) -> bool:
        """The centre of mass within height_tolerance_m of its standing height (or below it): the
        wheels may be on the ground, which then carries part of the weight and holds the robot
        against the air."""
        return z_ned_m >= self._ground_z - self._config.height_tolerance_m

    def update(self, time_s: float, z_ned_m: float, v_z_ned_m_s: float) -> bool:
        """True from the first instant the conditions have held for dwell_s on."""
        if self.touchdown_s is not None:
            return True
        c = self._config
        resting = self.at_ground_height(z_ned_m) and abs(v_z_ned_m_s) <= c.vertical_speed_max_m_s
        if not resting:
            self._still_since_s = None
            return False
        if self._still_since_s is None:
            self._still_since_s = time_s
        if time_s - self._still_since_s >= c.dwell_s - 1e-9:
            self.touchdown_s = time_s
        return self.touchdown_s is not None
