"""What an M4_SETPOINT commands, as both ends hold it: the companion builds one, the flight
controller applies one. The message adds the instant it answers and its period."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Setpoint:
    thrust_n: np.ndarray          # (4,) per rotor
    hip_rad: np.ndarray           # (4,) servo goal at the answered instant ...
    hip_rate_rad_s: np.ndarray    # (4,) ... moving at this rate (M4_SETPOINT hip_angle_rad, hip_rate_rad_s)
    thrust_cut: bool = False      # M4_SETPOINT_FLAG_THRUST_CUT: every motor stops
