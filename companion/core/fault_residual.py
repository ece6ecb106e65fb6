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

from m4.airframe import ROTOR_COUNT, Airframe
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


# IntervalFit.sums: a (4), b (4), a_size (4), b_size (4), a_size x expected thrust (4), chi2 (1).
_A, _B, _A_SIZE, _B_SIZE, _WEIGHTED_EXPECTED = (slice(4 * k, 4 * k + 4) for k in range(5))
_CHI2 = 20


@dataclass(frozen=True)
class IntervalFit:
    """The residual of one interval (or several: `combine`) fitted by each single-rotor deficit
    hypothesis.

    Sufficient statistics, so several intervals add up: with a = B_i^T W B_i and
    b = -B_i^T W r, the deficit is b / a and it explains b^2 / a of chi2 = r^T W r. The
    test weights W count every model error; the sizing weights (a_size, b_size) count only
    sensor noise and the fixed model errors, so a manoeuvre's torque does not blur the size.
    All of them sit in one row, `sums`, so the fit of several intervals is one sum of rows.
    """

    sums: np.ndarray             # (21,) a, b, a_size, b_size, a_size x expected thrust (4 each), chi2

    @property
    def a(self) -> np.ndarray:
        return self.sums[_A]

    @property
    def b(self) -> np.ndarray:
        return self.sums[_B]

    @property
    def chi2(self) -> float:
        return float(self.sums[_CHI2])

    @property
    def a_size(self) -> np.ndarray:
        return self.sums[_A_SIZE]

    @property
    def b_size(self) -> np.ndarray:
        return self.sums[_B_SIZE]

    @property
    def expected_thrust_n(self) -> np.ndarray:
        """(4,) the interval-average thrust the model assumed (over several: weighted by a_size)."""
        return self.sums[_WEIGHTED_EXPECTED] / self.a_size

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
        x, x_now, dt = ca.SX.sym("x", rom.NX), ca.SX.sym("x_now", rom.NX), ca.SX.sym("dt")
        thrust = ca.SX.sym("thrust", ROTOR_COUNT)
        bias_per_s = ca.SX.sym("bias_per_s", len(CHANNELS))
        u = ca.vertcat(thrust, (x_now[rom.HIP_RATE] - x[rom.HIP_RATE]) / dt)     # the hips' mean acceleration
        measured = x_now[CHANNELS.tolist()]
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
        sums = ca.vertcat(a, b, a_size, b_size, a_size * u[rom.THRUST], ca.dot(r, w * r))    # IntervalFit.sums
        fit = ca.Function("m4_fault_fit", [x, x_now, thrust, dt, bias_per_s], [sums, raw])
        self._fit = BufferedFunction(compiled(fit) if codegen else fit)

    def motor_decay(self, dt_s: float) -> float:
        """Share of a thrust step the first-order motor lag has still to go after dt_s (0: no lag)."""
        tau = self._af.motor_time_constant_s
        return math.exp(-dt_s / tau) if tau > 0 else 0.0

    def motor_response(self, start_n: list[float], target_n: list[float],
                       dt_s: float) -> tuple[list[float], list[float]]:
        """(interval-average thrust, thrust at the end) of the first-order motor lag, entry by entry
        on Python floats (one rotor's, or several lags' entries one after the other)."""
        decay = self.motor_decay(dt_s)
        if decay == 0:
            return list(target_n), list(target_n)
        tau_s = self._af.motor_time_constant_s
        return ([t + (s - t) * tau_s / dt_s * (1 - decay) for s, t in zip(start_n, target_n)],
                [t + (s - t) * decay for s, t in zip(start_n, target_n)])

    def spin_response_n(self, start_n: list[float], target_n: list[float], dt_s: float) -> list[float]:
        """The thrust at the end when the rotor's speed, not its thrust, follows the first-order
        lag (as a motor does): k_t w^2, w heading from sqrt(start / k_t) to sqrt(target / k_t).
        A rotor slowing to a stop loses its thrust at twice the lag's rate. Rotor by rotor, on
        Python floats."""
        k_n_s2, decay = self._af.thrust_coefficient_n_s2, self.motor_decay(dt_s)
        ends = []
        for start_i, target_i in zip(start_n, target_n):
            start, target = math.sqrt(max(start_i, 0.0) / k_n_s2), math.sqrt(max(target_i, 0.0) / k_n_s2)
            speed = target + (start - target) * decay
            ends.append(k_n_s2 * speed * speed)
        return ends

    def fit(self, x_prev: np.ndarray, x_now: np.ndarray, expected_thrust_n: list[float],
            dt_s: float, bias_per_s: np.ndarray) -> tuple[IntervalFit, np.ndarray]:
        """Fit the interval x_prev -> x_now flown with the given interval-average thrusts.

        bias_per_s (6,): a slowly learnt residual rate the model always shows, removed first.
        Returns the fit and the raw residual (6,) (bias not removed), for learning the bias.
        """
        sums, raw = self._fit.evaluate(x_prev, x_now, expected_thrust_n, dt_s, bias_per_s)
        return IntervalFit(sums.copy()), raw.copy()


def _residual_variance(af: Airframe, n: ResidualNoise, dt_s, inertia_diag_kg_m2, torque_n_m):
    """(6,) the residual's variance per channel (velocity, then body rates), as CasADi expressions."""
    v = 2 * n.velocity_m_s**2 + (n.force_n * dt_s / af.total_mass_kg) ** 2
    torque_error = ca.hypot(n.torque_n_m, n.torque_share * torque_n_m)
    w = 2 * n.rates_rad_s**2 + (torque_error * dt_s / inertia_diag_kg_m2) ** 2
    return ca.vertcat(v, v, v, w)


def combine(fits: list[IntervalFit]) -> IntervalFit:
    """The fit of several intervals under one constant deficit per hypothesis: their rows
    summed in order (numpy sums along the first axis row after row, as Python's sum would)."""
    return IntervalFit(np.add.reduce(np.stack([f.sums for f in fits])))


def best_hypothesis(fit: IntervalFit) -> tuple[int, float, float]:
    """(rotor index, chi2 it explains, chi2 left) of the best deficit (> 0) hypothesis."""
    explained = np.where(fit.b > 0, fit.b**2 / fit.a, 0.0)
    i = int(np.argmax(explained))
    return i, float(explained[i]), fit.chi2 - float(explained[i])

