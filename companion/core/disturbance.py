"""Offset-free estimation of the disturbance the ROM does not explain.

The NMPC's model has a disturbance input d = [force_ned_n (3), torque_frd_n_m (3)], held
constant over the horizon. After each control period this estimator compares the state
the robot reached with the state the model predicts from the previous state, the applied
input and the current estimate; the velocity and body-rate parts of that innovation are
mapped back to a force and a torque through the model's sensitivity dx+/dd, and the
estimate moves a fraction `gain` of the way (an integrator: at steady state the model with
d reproduces the robot, so the NMPC holds the reference without an offset). Behind a link
delay the caller lowers the fraction (`gain_scale`): the estimate's correction reaches the
robot only a lead later, and an integrator that fast inside a delayed loop rings (measured
on the SITL with 100 ms of lead: gain 0.3 made a fault-free flight oscillate in pitch and
crash, 0.05 flew it). Mass, thrust
and inertia errors and wind all land in d. The estimate is bounded, and a non-finite
measurement leaves it unchanged.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from m4.airframe import Airframe
from companion.core import rom
from companion.core.casadi_call import BufferedFunction
from companion.core.codegen_cache import compiled
from companion.core.rom import ND, NU, NX

_MEASURED = np.r_[np.arange(NX)[rom.V], np.arange(NX)[rom.RATES]]   # rows of x the estimate uses


class DisturbanceEstimator:
    """Filtered, bounded disturbance estimate for control period `period_s`; codegen: its correction
    (the model's step and the solve) compiled to C (cached, companion.core.codegen_cache), else
    CasADi's VM."""

    def __init__(self, airframe: Airframe, period_s: float, gain: float = 0.3,
                 force_max_n: float | None = None, torque_max_n_m: float | None = None, codegen: bool = False):
        if not 0 < gain <= 1:
            raise ValueError(f"DisturbanceEstimator gain must lie in (0, 1], got {gain}")
        if not period_s > 0:
            raise ValueError(f"DisturbanceEstimator period_s must be > 0, got {period_s}")
        self.gain = gain
        # Defaults: as force, half the weight across and up, the weight down. Down it carries the
        # thrust the rotors lose to the air (tilted into 13-17 m/s of it up to half:
        # docs/fault-detection.md, "held aloft"), which the NMPC must ask for; across, a larger push
        # would only tilt the robot further into that air, where the inflow takes more thrust than
        # the tilt gains; up, the ground carrying a landed robot must not wind it past half. As
        # torque: one rotor's full thrust at the leg's reach, either way.
        weight_n = airframe.total_mass_kg * airframe.gravity_m_s2
        if force_max_n is None:
            f_low, f_high = np.full(3, -0.5 * weight_n), np.array([0.5, 0.5, 1.0]) * weight_n
        else:
            f_low, f_high = np.full(3, -force_max_n), np.full(3, force_max_n)
        t_max = airframe.thrust_max_n * airframe.leg_length_m if torque_max_n_m is None else torque_max_n_m
        self.lower = np.r_[f_low, np.full(3, -t_max)]
        self.upper = np.r_[f_high, np.full(3, t_max)]
        step = rom.build_rom(airframe, period_s, substeps=2).step
        frame = ca.SX.sym("frame", NX + NU + ND + NX)   # x_prev, u_applied, the estimate, x_new: one copy a call
        x, u, d, x_new = ca.vertsplit(frame, [0, NX, NX + NU, NX + NU + ND, 2 * NX + NU + ND])
        predicted = step(x, u, d)[_MEASURED]
        # One call from the measurement to the correction: the innovation mapped back through the
        # sensitivity dx+/dd (square, 6 x 6) by a solve generated with the model (CasADi's
        # symbolic QR), not by numpy operations after it. A sensitivity it cannot invert gives a
        # non-finite correction: no update.
        correction = ca.Function("m4_disturbance_correction", [frame],
                                 [ca.solve(ca.jacobian(predicted, d), x_new[_MEASURED] - predicted)])
        self._correction = BufferedFunction(compiled(correction) if codegen else correction)
        self.estimate = np.zeros(ND)

    def reset(self) -> None:
        self.estimate = np.zeros(ND)

    def update(self, x_prev, u_applied, x_new, gain_scale: float = 1.0) -> np.ndarray:
        """New estimate (6,) after the robot went from x_prev to x_new under u_applied; the
        step is gain x gain_scale (in (0, 1]) of the innovation."""
        x_prev, u_applied, x_new = (np.asarray(v, dtype=float).ravel() for v in (x_prev, u_applied, x_new))
        if (x_prev.size, u_applied.size, x_new.size) != (NX, NU, NX):
            raise ValueError(f"DisturbanceEstimator.update needs states of {NX} and an input of {NU} entries, got "
                             f"{x_prev.size}, {u_applied.size} and {x_new.size}")
        frame = np.concatenate([x_prev, u_applied, self.estimate, x_new])
        if not np.isfinite(frame).all():           # the estimate is: it moves only by finite corrections
            return self.estimate.copy()
        correction = self._correction.evaluate(frame)[0]
        if np.isfinite(correction).all():             # else a state too wild for the model to step
            step = self.gain * min(max(float(gain_scale), 0.0), 1.0)
            self.estimate = np.minimum(np.maximum(self.estimate + step * correction, self.lower), self.upper)
        return self.estimate.copy()
