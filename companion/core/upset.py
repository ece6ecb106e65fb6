"""Crash and upset: the robot upside down, or on the ground when the mission does not land it.

Either, held for its time, means the flight is over: the companion cuts thrust and stays cut
(the flight controller then needs an explicit re-arm, which the companion never sends after a
crash it detected). Pure logic: feed it the measured ROM state at telemetry rate.

- Upside down: tilt (the angle between the body's down axis and the vertical) beyond
  tilt_max_rad for upside_down_s; a recovering roll passes through large tilts, it does not
  stay there.
- On the ground: after having flown (the centre of mass once more than airborne_margin_m above
  its standing height), back within ground_margin_m of it and slower than still_speed_m_s
  for ground_s, outside a landing.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np

from companion.core import rom_layout


@dataclass(frozen=True)
class UpsetConfig:
    tilt_max_rad: float = math.radians(120.0)
    upside_down_s: float = 0.5
    ground_margin_m: float = 0.1
    airborne_margin_m: float = 0.3
    still_speed_m_s: float = 0.5
    ground_s: float = 0.5

    def validate(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"UpsetConfig.{f.name} must be > 0, got {value}")
        if self.tilt_max_rad >= math.pi:
            raise ValueError("UpsetConfig.tilt_max_rad must be below 180 deg")


def tilt_rad(euler_rad) -> float:
    """Angle between the body's down axis and the vertical (0 level, pi upside down)."""
    roll, pitch = float(euler_rad[0]), float(euler_rad[1])
    return math.acos(max(-1.0, min(1.0, math.cos(roll) * math.cos(pitch))))


class UpsetDetector:
    """Latches the first crash it sees: `crash` is its reason ("upside down", "on the ground")."""

    def __init__(self, ground_com_z_ned_m: float, config: UpsetConfig = UpsetConfig()):
        config.validate()
        self._ground_z, self._c = ground_com_z_ned_m, config
        self._airborne = False
        self._since_s: dict[str, float] = {}
        self.crash: str | None = None
        self.crash_s: float | None = None

    def update(self, time_s: float, x, landing: bool) -> str | None:
        """The crash's reason from the first instant its condition has held long enough on."""
        if self.crash is not None:
            return self.crash
        x = np.asarray(x, dtype=float)
        c = self._c
        values = x.tolist()                    # a few entries: Python floats, cheaper than numpy's scalars
        height_m = self._ground_z - values[rom_layout.P.start + 2]   # above the standing height
        self._airborne |= height_m > c.airborne_margin_m
        if self._held("upside down", tilt_rad(values[rom_layout.EULER]) > c.tilt_max_rad, c.upside_down_s, time_s):
            return self.crash
        v = x[rom_layout.V]
        on_ground = (self._airborne and not landing and height_m < c.ground_margin_m
                     and math.sqrt(v.dot(v)) < c.still_speed_m_s)
        if self._held("on the ground", on_ground, c.ground_s, time_s):
            return self.crash
        return None

    def _held(self, reason: str, now_true: bool, needed_s: float, time_s: float) -> bool:
        """Whether the condition `reason`, true now or not, has held needed_s on (the crash then latches)."""
        if not now_true:
            self._since_s.pop(reason, None)
            return False
        since = self._since_s.setdefault(reason, time_s)
        if time_s - since >= needed_s - 1e-9:
            self.crash, self.crash_s = reason, time_s
            return True
        return False
