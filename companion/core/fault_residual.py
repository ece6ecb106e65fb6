"""What the measured motion says about each rotor's thrust: the fault detector's evidence.

Between two telemetry frames the robot moved under the thrusts we commanded. The reduced-order
model predicts the second frame from the first with those thrusts (first-order motor lag
included: a rotor whose command stepped delivers the average of its lagged response), and
the prediction error of velocity and body rates is the residual r (6,). A thrust deficit
delta_i on rotor i alone would leave the residual -B_i delta_i, where B_i is the column of
d(v, rates)/d(thrust_i) of the model step at the measured state: the thrust -> wrench map of
the rotor at the current posture and attitude, integrated over the interval. Each rotor
hypothesis is fitted by weighted least squares; the weights are the inverse variances of the
residual from sensor noise (both frames) and from the model's own force and torque errors.

Working on the one-step prediction instead of differentiated velocities needs no filter and
keeps the posture's effect on the centre of mass, the moment arms and the inertia exact.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import casadi as ca
import numpy as np

from m4.airframe import Airframe
from companion.core import rom
from companion.core.casadi_call import BufferedFunction
from companion.core.codegen_cache import compiled

CHANNELS = np.r_[np.arange(rom.V.start, rom.V.stop), np.arange(rom.RATES.start, rom.RATES.stop)]
_PREDICTION_SUBSTEPS = 4


@dataclass(frozen=True)
class ResidualNoise:
    """Standard deviations behind the residual's weights."""

    velocity_m_s: float          # sensor noise of one measured velocity component
    rates_rad_s: float           # sensor noise of one measured body rate
    force_n: float               # force the model gets wrong (drag, mass error), per axis
    torque_n_m: float            # torque the model gets wrong (leg motion, drag), per axis
    torque_share: float          # share of the commanded thrust torque the model gets wrong (inertia, arms)


@dataclass(frozen=True)
class IntervalFit:
    """The residual of one interval fitted by each single-rotor deficit hypothesis.

    Sufficient statistics, so several intervals add up: with a = B_i^T W B_i and
    b = -B_i^T W r, the deficit is b / a and it explains b^2 / a of chi2 = r^T W r. The
    test weights W count every model error; the sizing weights (a_size, b_size) count only
    sensor noise and the fixed model errors, so a manoeuvre's torque does not blur the size.
    """

    a: np.ndarray                # (4,)
    b: np.ndarray                # (4,)
    chi2: float
    a_size: np.ndarray           # (4,)
    b_size: np.ndarray           # (4,)
    expected_thrust_n: np.ndarray   # (4,) interval-average thrust the model assumed

    @property
    def deficit_n(self) -> np.ndarray:
        return self.b / self.a

    @property
    def deficit_size_n(self) -> np.ndarray:
        return self.b_size / self.a_size


class ThrustResidualModel:
    """One-step prediction of the ROM, the per-rotor sensitivity of (v, rates) to thrust and the
    weighted fit of each hypothesis, in one CasADi function; codegen: compiled to C (cached,
    companion.core.codegen_cache), else CasADi's VM."""

    def __init__(self, af: Airframe, noise: ResidualNoise, codegen: bool = False):
        self._af = af
        f = rom.dynamics(af)
        x, u, dt = ca.SX.sym("x", rom.NX), ca.SX.sym("u", rom.NU), ca.SX.sym("dt")
        measured, bias_per_s = ca.SX.sym("measured", len(CHANNELS)), ca.SX.sym("bias_per_s", len(CHANNELS))
        xk = rom.rk4(f, x, u, ca.DM.zeros(rom.ND), dt, _PREDICTION_SUBSTEPS)[CHANNELS.tolist()]
        com, inertia = rom.mass_properties(af, x[rom.HIP])
        torque = rom.thrust_torque_frd(af, x[rom.HIP], com, u[rom.THRUST])
        sens = ca.jacobian(xk, u[rom.THRUST])                       # (6, 4)
        raw = measured - xk
        r = raw - bias_per_s * dt
        w = 1.0 / _residual_variance(af, noise, dt, ca.diag(inertia), torque)
        w_size = 1.0 / _residual_variance(af, noise, dt, ca.diag(inertia), ca.DM.zeros(3))
        a, a_size = ((sens * sens).T @ weights for weights in (w, w_size))
        b, b_size = (-(sens.T @ (weights * r)) for weights in (w, w_size))
        fit = ca.Function("m4_fault_fit", [x, u, dt, measured, bias_per_s], [a, b, ca.dot(r, w * r), a_size, b_size, raw])
        self._fit = BufferedFunction(compiled(fit) if codegen else fit)

    def motor_decay(self, dt_s: float) -> float:
        """Share of a thrust step the first-order motor lag has still to go after dt_s (0: no lag)."""
        tau = self._af.motor_time_constant_s
        return math.exp(-dt_s / tau) if tau > 0 else 0.0

    def motor_response(self, start_n: np.ndarray, target_n: np.ndarray, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
        """(interval-average thrust, thrust at the end) of the first-order motor lag."""
        decay = self.motor_decay(dt_s)
        if decay == 0:
            return target_n.copy(), target_n.copy()
        return (target_n + (start_n - target_n) * self._af.motor_time_constant_s / dt_s * (1 - decay),
                target_n + (start_n - target_n) * decay)

    def spin_response_n(self, start_n: np.ndarray, target_n: np.ndarray, dt_s: float) -> np.ndarray:
        """The thrust at the end when the rotor's speed, not its thrust, follows the first-order
        lag (as a motor does): k_t w^2, w heading from sqrt(start / k_t) to sqrt(target / k_t).
        A rotor slowing to a stop loses its thrust at twice the lag's rate."""
        k_n_s2, decay = self._af.thrust_coefficient_n_s2, self.motor_decay(dt_s)
        start, target = (np.sqrt(np.maximum(v, 0.0) / k_n_s2) for v in (start_n, target_n))
        speed = target + (start - target) * decay
        return k_n_s2 * speed * speed

    def fit(self, x_prev: np.ndarray, x_now: np.ndarray, expected_thrust_n: np.ndarray,
            dt_s: float, bias_per_s: np.ndarray) -> tuple[IntervalFit, np.ndarray]:
        """Fit the interval x_prev -> x_now flown with the given interval-average thrusts.

        bias_per_s (6,): a slowly learnt residual rate the model always shows, removed first.
        Returns the fit and the raw residual (6,) (bias not removed), for learning the bias.
        """
        u = np.zeros(rom.NU)
        u[rom.THRUST] = expected_thrust_n
        u[rom.HIP_ACCEL] = (x_now[rom.HIP_RATE] - x_prev[rom.HIP_RATE]) / dt_s
        a, b, chi2, a_size, b_size, raw = (v.copy() for v in self._fit.evaluate(x_prev, u, dt_s, x_now[CHANNELS],
                                                                                 bias_per_s))
        return IntervalFit(a=a, b=b, chi2=float(chi2[0]), a_size=a_size, b_size=b_size,
                           expected_thrust_n=expected_thrust_n), raw


def _residual_variance(af: Airframe, n: ResidualNoise, dt_s, inertia_diag_kg_m2, torque_n_m):
    """(6,) the residual's variance per channel (velocity, then body rates), as CasADi expressions."""
    v = 2 * n.velocity_m_s**2 + (n.force_n * dt_s / af.total_mass_kg) ** 2
    torque_error = ca.hypot(n.torque_n_m, n.torque_share * torque_n_m)
    w = 2 * n.rates_rad_s**2 + (torque_error * dt_s / inertia_diag_kg_m2) ** 2
    return ca.vertcat(v, v, v, w)


def combine(fits: list[IntervalFit]) -> IntervalFit:
    """The fit of several intervals under one constant deficit per hypothesis."""
    a_size = sum(f.a_size for f in fits)
    expected = sum(f.a_size * f.expected_thrust_n for f in fits) / a_size
    return IntervalFit(a=sum(f.a for f in fits), b=sum(f.b for f in fits), chi2=sum(f.chi2 for f in fits),
                       a_size=a_size, b_size=sum(f.b_size for f in fits), expected_thrust_n=expected)


def best_hypothesis(fit: IntervalFit) -> tuple[int, float, float]:
    """(rotor index, chi2 it explains, chi2 left) of the best deficit (> 0) hypothesis."""
    explained = np.where(fit.b > 0, fit.b**2 / fit.a, 0.0)
    i = int(np.argmax(explained))
    return i, float(explained[i]), fit.chi2 - float(explained[i])

