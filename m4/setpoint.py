"""What an M4_SETPOINT commands, as both ends hold it: the companion builds one, the flight
controller applies one. The message adds the instant it answers and its period.

Rate feedback (M4_SETPOINT's extension fields): the companion's plan reaches the flight
controller a link delay after the telemetry it answers, and a rotor lost in between tips the
robot for that long before the plan can react. So the setpoint also carries the body rates
the plan expects while it is in force and a gain, and the FC closes that fast loop on its
own gyro at its own rate: thrust_n + gain x (planned rates - measured rates). When the robot
moves as planned the feedback adds nothing; the plan stays the companion's.

Shortfall cover (also extension fields): the FC sees a rotor fall short of its command
in its ESC's speed within a few milliseconds, long before the companion's answer can come
back over the link. The setpoint carries how the other rotors cover each rotor's shortfall
(thrust change per newton short: keep the sum and the roll and pitch torque), and the FC adds
gain x shortfall at its own rate. With every rotor delivering, it adds nothing. With the
rotors' effectiveness (roll and pitch acceleration per newton at the planned posture) the FC
also measures the shortfall on its gyro, as the angular acceleration the robot lacks: the
only measure a FC without ESC telemetry has (sitl/fc/gyro_shortfall.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

RATE_GAIN_MAX_N_PER_RAD_S = 50.0     # the FC refuses larger entries: no sane posture needs them
SHORTFALL_GAIN_MAX = 4.0             # likewise for the cover: N per N short
EFFECTIVENESS_MAX_RAD_S2_PER_N = 100.0   # and for the effectiveness (the M4's is about 3)


@dataclass(frozen=True)
class RateFeedback:
    rates_ref_frd_rad_s: np.ndarray          # (3,) planned body rates when the setpoint takes effect ...
    rates_ref_change_frd_rad_s2: np.ndarray  # (3,) ... and their planned change per second (held after the period)
    gain_n_per_rad_s: np.ndarray             # (4, 3) thrust change per rotor per unit rate error about x, y, z

    @classmethod
    def from_fields(cls, rates_ref, change, gain_flat) -> RateFeedback | None:
        """From M4_SETPOINT's fields; None when they ask for no feedback (all gains zero, the
        default of a sender that does not know them) or cannot be used (not finite, a gain
        beyond RATE_GAIN_MAX_N_PER_RAD_S)."""
        ref, chg = np.asarray(rates_ref, dtype=float), np.asarray(change, dtype=float)
        gain = np.asarray(gain_flat, dtype=float).reshape(4, 3)
        if not (np.isfinite(ref).all() and np.isfinite(chg).all() and np.isfinite(gain).all()):
            return None
        if not gain.any() or np.abs(gain).max() > RATE_GAIN_MAX_N_PER_RAD_S:
            return None
        return cls(ref, chg, gain)

    def thrust_change_n(self, rates_frd_rad_s, in_force_s: float, period_s: float) -> np.ndarray:
        """(4,) the feedback after the setpoint has been in force in_force_s (planned rates
        held after period_s), for the measured body rates; zeros when they are not finite.

        No product code calls it (the FC restates the sums on floats, sitl/fc/fast_loop.py; the
        prediction is one generated call, companion/core/prediction.py): it is the one executable
        statement of the FC's law they are checked against, so it stays. Checked against it:
        FastLoop (tests/sitl/fc/test_fast_loop.py) and the compiled prediction
        (tests/core/test_prediction.py, loop_prediction)."""
        rates = np.asarray(rates_frd_rad_s, dtype=float)
        if not all(map(math.isfinite, rates.tolist())):      # three floats: cheaper than numpy's all
            return np.zeros(4)
        ref = self.rates_ref_frd_rad_s + self.rates_ref_change_frd_rad_s2 * min(max(in_force_s, 0.0), period_s)
        return self.gain_n_per_rad_s @ (ref - rates)


@dataclass(frozen=True)
class ShortfallCover:
    gain: np.ndarray                         # (4, 4) thrust change of rotor i per newton rotor j falls short
    effectiveness_frd_rad_s2_per_n: np.ndarray | None = None   # (2, 4) roll, pitch acceleration per newton
                                                               # of each rotor; None: no measure on the gyro

    @classmethod
    def from_fields(cls, gain_flat, effectiveness_flat=(0.0,) * 8) -> ShortfallCover | None:
        """From M4_SETPOINT's shortfall_gain and effectiveness_frd_rad_s2_per_n; None when it
        asks for no cover (all zero, the default of a sender that does not know the field) or
        cannot be used (not finite, an entry beyond SHORTFALL_GAIN_MAX). An effectiveness that
        is all zero, not finite or beyond EFFECTIVENESS_MAX_RAD_S2_PER_N is left out alone."""
        gain = np.asarray(gain_flat, dtype=float).reshape(4, 4)
        if not np.isfinite(gain).all() or not gain.any() or np.abs(gain).max() > SHORTFALL_GAIN_MAX:
            return None
        effectiveness = np.asarray(effectiveness_flat, dtype=float).reshape(4, 2).T
        usable = (np.isfinite(effectiveness).all() and effectiveness.any()
                  and np.abs(effectiveness).max() <= EFFECTIVENESS_MAX_RAD_S2_PER_N)
        return cls(gain, effectiveness if usable else None)

    def thrust_change_n(self, shortfall_n) -> np.ndarray:
        """(4,) the other rotors' cover for the rotors' shortfalls (4,), N.

        No product code calls it (as RateFeedback.thrust_change_n): the one executable statement
        of the cover the FC adds, which stays. Checked against it: FastLoop
        (tests/sitl/fc/test_fast_loop.py), the compiled prediction (tests/core/test_prediction.py,
        loop_prediction) and the Lua applet (tests/sitl/ardupilot/test_m4_fc_applet.py)."""
        return self.gain @ np.asarray(shortfall_n, dtype=float)


@dataclass(frozen=True)
class Setpoint:
    thrust_n: np.ndarray          # (4,) per rotor
    hip_rad: np.ndarray           # (4,) servo goal at the answered instant ...
    hip_rate_rad_s: np.ndarray    # (4,) ... moving at this rate (M4_SETPOINT hip_angle_rad, hip_rate_rad_s)
    thrust_cut: bool = False      # M4_SETPOINT_FLAG_THRUST_CUT: every motor stops
    rate_feedback: RateFeedback | None = None   # None: thrust_n alone
    shortfall_cover: ShortfallCover | None = None   # None: no cover (applied with the rate feedback)
