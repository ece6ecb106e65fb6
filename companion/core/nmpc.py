"""The fault-agnostic NMPC: thrust and leg posture planned together over a short horizon.

Route (chosen by measurement, `m4-companion bench`): a Gauss-Newton SQP in single
shooting. Each iteration makes ONE call of a compiled CasADi function (rollout + every
stage's Jacobians), condenses the problem into a dense QP over the N * 8 inputs in numpy
and solves it with DAQP (a dual active-set solver), warm-started from the previous active
set. State constraints (roll, pitch, hips, same-side hip sums) are linear rows in the
inputs after condensing; they are soft in the QP (a huge penalty, exact whenever feasible)
so that a measured state just outside a bound never makes the QP infeasible.

Fault-agnostic: each rotor's thrust upper bound is an argument of `solve`; a fault lowers a
bound and nothing else changes. While its plans saturate the rotors for want of thrust, the
cost's horizontal weights drop (companion.core.altitude_first: altitude before place). A solve
never returns NaN or an input out of its bounds: on bad input or solver failure it returns a
bounded fallback and says so (`fallback=True`).

Two schemes ([nmpc] scheme): "sqp" iterates to the optimum at every solve (with a line search
on a merit function); "rti", the real-time iteration, takes one full QP step per solve from a
QP that `prepare` built before the state arrived (companion.core.rti), so the time between
the state and the command is one QP. When nothing was prepared (the first solve, after a
reset or a fallback) the feedback prepares at the arrived state itself ("rti_unprepared").
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import daqp
import numpy as np

from m4.airframe import ROTOR_COUNT, Airframe
from companion.core import rom
from companion.core.altitude_first import AltitudeFirst, horizontal_scaled
from companion.core.casadi_call import BufferedFunction
from companion.core.codegen_cache import compiled
from companion.core.condensing import (
    FirstPeriodHipRows,
    Linearisation,
    QpRows,
    TrackingCost,
    linearisation,
    sensitivities_and_parameters,
    state_rows,
)
from companion.core.control_types import thrust_bounds
from companion.core.feedback_qp import NO_BOUND
from companion.core.nmpc_config import NmpcConfig
from companion.core.nmpc_targets import hover_targets
from companion.core.rti import PreparedQp, RtiFeedback, prepare_qp
from companion.core.rti_compiled import INVALID_INPUT
from companion.core.rom import ND, NU, NX

_MERIT_PENALTY = 1e4         # per unit of state-constraint violation, in the line search
_ARMIJO = 1e-4
_MAX_HALVINGS = 6
_DAQP_OK = (1, 2)            # optimal; optimal with soft constraints violated
_DAQP_ITER_LIMIT = 2000      # bounds the worst-case QP time (a few ms)
_LEVENBERG = 1e-8            # relative damping: keeps the QP solvable when a rollout nears the Euler singularity


@dataclass(frozen=True)
class NmpcResult:
    u: np.ndarray            # (8,) the first input: thrust_n (4), hip_accel_rad_s2 (4)
    x_pred: np.ndarray       # (N+1, 20) predicted states (x0 first)
    u_pred: np.ndarray       # (N, 8)
    solve_ms: float
    iterations: int
    status: str              # converged | max_iterations | time_budget | no_progress | rti | rti_unprepared |
                             # qp_failed | invalid_input
    ok: bool
    cost: float
    fallback: bool
    altitude_first: bool = False   # solved with the horizontal weights scaled down (companion.core.altitude_first)


class Nmpc:
    """NMPC over the ROM of `airframe`; `solve` once per control period."""

    def __init__(self, airframe: Airframe, config: NmpcConfig | None = None):
        self.af = airframe
        self.config = config = config or NmpcConfig()
        config.validate()
        n = config.horizon
        self.rom = rom.build_rom(airframe, config.dt_s, config.rk4_substeps)
        build = compiled if config.codegen else (lambda fn: fn)
        self._rollout = Linearisation(build(linearisation(self.rom.step, n)), n)
        self._prepared: PreparedQp | None = None
        self._saturation: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None   # (u, hi, d) of the last solve
        self._bounds: tuple[bytes, tuple[np.ndarray, np.ndarray]] | None = None   # the last input_bounds, by its argument
        self._fixed: tuple[np.ndarray, ...] | None = None     # _fixed_bounds: (lo, hi, upper, lower)
        self._planned: tuple[np.ndarray, np.ndarray] | None = None   # (x0, u0) of the last plan
        self.prepare_ms = 0.0            # how long the last `prepare` took

        fixed = config.fixed_hip_rad
        if fixed is not None and not airframe.hip_min_rad <= fixed <= airframe.hip_max_rad:
            raise ValueError(f"NmpcConfig.fixed_hip_rad {fixed} is outside the airframe's hip range")
        self.hip_ref_rad = airframe.nominal_hip_rad if fixed is None else fixed
        accel = 0.0 if fixed is not None else airframe.hip_accel_max_rad_s2
        self._accel_lo, self._accel_hi = np.full(ROTOR_COUNT, -accel), np.full(ROTOR_COUNT, accel)
        hip_bounds = (airframe.hip_min_rad, airframe.hip_max_rad)
        self.rows = state_rows(n, config.roll_pitch_max_rad, None if fixed is not None else hip_bounds,
                               airframe.same_side_pairs, airframe.same_side_sum_max_rad)
        tau = config.dt_s * config.warm_start_shift
        self.first_rows = None
        if fixed is None and tau < config.dt_s:
            self.first_rows = FirstPeriodHipRows.build(n, tau, hip_bounds, airframe.same_side_pairs,
                                                       airframe.same_side_sum_max_rad)
        self._qp_rows = QpRows(n, self.rows, self.first_rows)
        w = config.weights
        state_w = np.tile(w.state_diag(), (n + 1, 1))
        state_w[-1] *= w.terminal_scale
        self._costs = (TrackingCost(state_w=state_w, input_w=w.input_diag()),
                       TrackingCost(state_w=horizontal_scaled(state_w, rom.P, rom.V, w.horizontal_saturated_scale),
                                    input_w=w.input_diag()))
        self.altitude_first = AltitudeFirst(config.dt_s * config.warm_start_shift,
                                            airframe.total_mass_kg * airframe.gravity_m_s2)
        self._hover_u = np.tile(rom.hover_input(airframe), (n, 1))
        self._diagonal = np.diag_indices(n * NU)         # of the condensed QP's Hessian
        self._sense = np.concatenate([np.zeros(n * NU, dtype=np.int32),
                                      np.full(self._qp_rows.count, 8, dtype=np.int32)])
        targets = hover_targets(airframe, n, config.dt_s, self.hip_ref_rad)
        self._targets = BufferedFunction(build(targets))
        self._rti_rollout = self._advance = self._feedback = None
        if config.scheme == "rti":
            self._rti_rollout = Linearisation(build(linearisation(self.rom.step, n, disturbance_jacobian=True)), n)
            self._advance = BufferedFunction(build(rom.rk4_step(self.rom.f, tau, config.rk4_substeps)))
            self._feedback = RtiFeedback(targets, n, self._qp_rows, self._sense, _DAQP_ITER_LIMIT, config.codegen)
        self._guess: np.ndarray | None = None
        self._duals: np.ndarray | None = None
        # The warm start: the previous plan shifted by warm_start_shift stages, interpolated
        # between its nodes i0 and i1 (the last one held); the same every solve.
        pos = np.minimum(np.arange(n) + config.warm_start_shift, n - 1)
        self._shift_i0 = np.floor(pos).astype(int)
        self._shift_i1 = np.minimum(self._shift_i0 + 1, n - 1)
        self._shift_frac = (pos - self._shift_i0)[:, None]
        self._shift_keep = 1 - self._shift_frac

    # ----------------------------------------------------------------- public API
    def reset(self) -> None:
        """Drop the warm start (e.g. after a jump of the reference)."""
        self._saturation = None
        self.altitude_first.reset()
        self._guess = None
        self._duals = None
        self._prepared = None
        self._planned = None

    def input_bounds(self, thrust_bound_n) -> tuple[np.ndarray, np.ndarray]:
        """(lo, hi) of one stage's input (read-only); a non-finite thrust bound means the airframe's
        maximum. Kept from the last call with the same thrust bounds: they change at a fault."""
        key = np.asarray(thrust_bound_n, dtype=float).tobytes()
        if self._bounds is None or self._bounds[0] != key:
            lo = np.concatenate([np.full(ROTOR_COUNT, self.af.thrust_min_n), self._accel_lo])
            hi = np.concatenate([thrust_bounds(self.af, thrust_bound_n), self._accel_hi])
            lo.flags.writeable = hi.flags.writeable = False
            self._bounds = (key, (lo, hi))
        return self._bounds[1]

    def targets(self, x0, x_ref, disturbance) -> tuple[np.ndarray, np.ndarray]:
        """(state reference (N+1, 20), input reference (N, 8)) the cost tracks: x_ref with the
        hips at the posture the NMPC pulls towards and the roll, pitch and thrust of a hover
        under the disturbance (see nmpc_targets)."""
        n = self.config.horizon
        ref, u_ref = self._targets(x0, np.ravel(x_ref), disturbance)
        return ref.reshape(n + 1, NX), u_ref.reshape(n, NU)

    @property
    def cost(self) -> TrackingCost:
        """The cost the next solve tracks: the horizontal weights scaled down while the plans
        saturate the rotors (altitude before place)."""
        self._note_saturation()
        return self._costs[self.altitude_first.active]

    def solve(self, x0, x_ref, thrust_bound_n, disturbance=None) -> NmpcResult:
        """One receding-horizon step from state x0 (20,) along x_ref (N+1, 20)."""
        t0 = time.perf_counter()
        self._note_saturation()
        lo, hi = self.input_bounds(thrust_bound_n)
        d = _finite_disturbance(disturbance)
        res = self._solve(x0, x_ref, lo, hi, d, t0)
        self._saturation = (res.u, hi, d)
        return res

    def prepare(self, x_ref, thrust_bound_n, disturbance=None) -> None:
        """The real-time iteration's preparation of the next solve, to call between two solves
        (off the critical path): the QP linearised at the state the last plan predicts one
        control period on, for the next solve's reference x_ref (N+1, 20), bounds and
        disturbance. Nothing in the sqp scheme, or without a plan to go on (the next solve then
        prepares at its own state)."""
        t0 = time.perf_counter()
        self._note_saturation()
        planned, self._planned, self._prepared = self._planned, None, None
        if self.config.scheme != "rti" or planned is None:
            return
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):   # every result is checked
            x_ref = np.asarray(x_ref, dtype=float)
            d = _finite_disturbance(disturbance)
            x0 = self._advance.evaluate(*planned, d)[0].copy()
            if x_ref.shape == (self.config.horizon + 1, NX) and np.isfinite(x_ref).all() and np.isfinite(x0).all():
                lo, hi = self.input_bounds(thrust_bound_n)
                self._prepared = self._prepare_at(x0, x_ref, d, lo, hi)
        self.prepare_ms = _ms_since(t0)

    def plan_cost(self, x0, x_ref, us, disturbance=None) -> float:
        """The cost of the inputs us (N, 8) from x0 (20,) along x_ref (N+1, 20), by the model's
        rollout (a real-time iteration's own `cost` is its linearisation's)."""
        d = _finite_disturbance(disturbance)
        x0 = np.asarray(x0, dtype=float).reshape(NX)
        ref, u_ref = self.targets(x0, np.asarray(x_ref, dtype=float), d)
        return self.cost.value(self._rollout(x0, np.asarray(us, dtype=float), d)[0], us, ref, u_ref)

    def unprepare(self) -> None:
        """Drop what `prepare` built: the next solve is not the one it was prepared for."""
        self._prepared = self._planned = None

    # ----------------------------------------------------------------- internals
    def _solve(self, x0, x_ref, lo, hi, d, t0) -> NmpcResult:
        n = self.config.horizon
        x0 = np.asarray(x0, dtype=float).reshape(-1)
        x_ref = np.asarray(x_ref, dtype=float)
        if x0.size != NX or x_ref.shape != (n + 1, NX):
            raise ValueError(f"x0 must have {NX} entries and x_ref shape ({n + 1}, {NX}); "
                             f"got {x0.size} and {x_ref.shape}")
        if self._prepared is not None:          # the feedback checks x0 and x_ref in its compiled call
            return self._rti(x0, x_ref, d, lo, hi, t0)
        if not (np.isfinite(x0).all() and np.isfinite(x_ref).all()):
            return self._fallback(x0, lo, hi, "invalid_input", 0, t0)
        if self.config.scheme == "rti":
            return self._rti(x0, x_ref, d, lo, hi, t0)
        ref, u_ref = self.targets(x0, x_ref, d)
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):   # every result is checked
            return self._sqp(x0, ref, u_ref, d, lo, hi, t0)

    def _note_saturation(self) -> None:
        """The last plan's first thrusts against their bounds into altitude_first, which picks
        the cost of the plans after it: read after the send (at the preparation, or at the next
        solve), not between the state and the setpoint."""
        if self._saturation is not None:
            u, hi, d = self._saturation
            self._saturation = None
            self.altitude_first.update(u[rom.THRUST], hi[rom.THRUST], d[2])

    def _prepare_at(self, x0, x_ref, d, lo, hi) -> PreparedQp | None:
        """The QP at (x0, x_ref, d), loaded into the feedback's DAQP model (None: not finite)."""
        ref, u_ref = self.targets(x0, x_ref, d)
        prep = prepare_qp(self._rti_rollout, self.cost, self._qp_rows, x0, self._initial_guess(u_ref, lo, hi), d,
                          ref, u_ref, _LEVENBERG)
        if prep is not None:
            self._feedback.load(prep, warm=self._duals is not None)
        return prep

    def _rti(self, x0, x_ref, d, lo, hi, t0) -> NmpcResult:
        """The feedback: the prepared QP moved to (x0, x_ref, d), one QP, the full step."""
        status = "rti"
        if self._prepared is None:                 # what is fed back is loaded by the preparation
            status = "rti_unprepared"
            with np.errstate(over="ignore", invalid="ignore", divide="ignore"):   # every result is checked
                if self._prepare_at(x0, x_ref, d, lo, hi) is None:
                    return self._fallback(x0, lo, hi, "qp_failed", 1, t0)
        self._prepared = None
        feedback = self._feedback
        flag = feedback.solve(x0, x_ref, d, lo, hi)
        # Invalid: an entry of x0 or x_ref is not finite, or finite entries' sum overflows (then labelled
        # "invalid_input" where the solve would have said "qp_failed": only the label; the same fallback).
        if flag == INVALID_INPUT:
            return self._fallback(x0, lo, hi, "invalid_input", 0, t0)
        self._duals = feedback.duals
        if flag not in _DAQP_OK:
            return self._fallback(x0, lo, hi, "qp_failed", 1, t0)
        us, xs, cost = feedback.planned()
        if not math.isfinite(cost):               # a step, state or input that is not finite makes it so
            return self._fallback(x0, lo, hi, "qp_failed", 1, t0)
        self._guess = us.copy()
        self._planned = (x0.copy(), us[0].copy())
        return NmpcResult(u=us[0].copy(), x_pred=xs, u_pred=us, solve_ms=_ms_since(t0), iterations=1, status=status,
                          ok=True, cost=cost, fallback=False, altitude_first=self.altitude_first.active)

    def _qp_step(self, hess, grad, rows, x0, xs, us, lo, hi) -> np.ndarray | None:
        """The QP's step dU (N, 8) within the input bounds (lo, hi: one stage's, (8,)) and the
        state rows, their derivatives `rows` (QpRows.jacobian) taken from xs; None when DAQP
        fails. Its duals warm-start the next QP."""
        upper, lower = self._qp_bounds(x0, xs, us, lo, hi)
        step, _, flag, info = daqp.solve(hess, grad, rows, upper, lower, self._sense,
                                         dual_start=self._duals, iter_limit=_DAQP_ITER_LIMIT)
        return self._step(step, flag, info["lam"])

    def _qp_bounds(self, x0, xs, us, lo, hi) -> tuple[np.ndarray, np.ndarray]:
        """(upper, lower) of the QP on the step dU from us: the input bounds (lo, hi: one stage's, at
        every stage) first, then the state rows at xs (the first period's rows from x0 and us)."""
        upper, lower = self._fixed_bounds(lo, hi)
        moved = np.concatenate([us.ravel(), self._qp_rows.values(x0, xs, us)])   # what each bound is taken from
        return np.minimum(upper - moved, NO_BOUND), np.maximum(lower - moved, -NO_BOUND)   # no-ops on the inputs'

    def _fixed_bounds(self, lo, hi) -> tuple[np.ndarray, np.ndarray]:
        """(upper, lower) of the QP's inputs at every stage, then of its rows, before the inputs and
        rows are taken off them; kept while input_bounds hands out the same lo and hi."""
        kept = self._fixed
        if kept is None or kept[0] is not lo or kept[1] is not hi:
            n = self.config.horizon
            upper = np.concatenate([np.tile(hi, n), self._qp_rows.hi])
            lower = np.concatenate([np.tile(lo, n), self._qp_rows.lo])
            self._fixed = kept = (lo, hi, upper, lower)
        return kept[2], kept[3]

    def _step(self, step, flag, duals) -> np.ndarray | None:
        """DAQP's solution as the step dU (N, 8), its duals kept to warm-start the next QP; None
        when it failed."""
        if flag not in _DAQP_OK or not np.isfinite(step).all():
            return None
        self._duals = np.asarray(duals)
        return np.asarray(step).reshape(self.config.horizon, NU)

    def _merit(self, x0, xs, us, ref, u_ref):
        violation = self.rows.violation(xs)
        if self.first_rows is not None:
            violation += self.first_rows.violation(x0, us)
        return self.cost.value(xs, us, ref, u_ref) + _MERIT_PENALTY * violation

    def _initial_guess(self, u_ref, lo, hi) -> np.ndarray:
        if self._guess is None:
            us = u_ref.copy()
        else:
            us = self._shift_keep * self._guess[self._shift_i0] + self._shift_frac * self._guess[self._shift_i1]
        return np.clip(us, lo, hi)

    def _sqp(self, x0, ref, u_ref, d, lo, hi, t0) -> NmpcResult:
        us = self._initial_guess(u_ref, lo, hi)
        xs, a, b = self._rollout(x0, us, d)
        merit = self._merit(x0, xs, us, ref, u_ref)
        status, it = "max_iterations", 0
        budget_s = self.config.time_budget_s
        for it in range(1, self.config.max_iterations + 1):
            if not (np.isfinite(merit) and np.isfinite(a).all() and np.isfinite(b).all()):
                return self._fallback(x0, lo, hi, "qp_failed", it, t0)
            gamma, _ = sensitivities_and_parameters(a, b)
            hess, grad = self.cost.gauss_newton(gamma, xs, us, ref, u_ref)
            hess[self._diagonal] += _LEVENBERG * hess[self._diagonal].max()
            step = self._qp_step(hess, grad, self._qp_rows.jacobian(gamma), x0, xs, us, lo, hi)
            if step is None:
                return self._fallback(x0, lo, hi, "qp_failed", it, t0)
            decrease = float(grad @ step.ravel())
            if -decrease <= self.config.cost_tol_rel * merit:
                status = "converged"
                break
            alpha = 1.0
            for _ in range(_MAX_HALVINGS):
                trial_us = np.clip(us + alpha * step, lo, hi)
                trial = self._rollout(x0, trial_us, d)
                trial_merit = self._merit(x0, trial[0], trial_us, ref, u_ref)
                if trial_merit <= merit + _ARMIJO * alpha * min(decrease, 0.0):
                    break
                alpha *= 0.5
            else:
                status = "no_progress"
                break
            us, (xs, a, b), merit = trial_us, trial, trial_merit
            if budget_s is not None and it < self.config.max_iterations and \
                    (time.perf_counter() - t0) * (it + 1) / it > budget_s:     # the next one would end too late
                status = "time_budget"
                break
        if not (np.isfinite(xs).all() and np.isfinite(merit)):
            return self._fallback(x0, lo, hi, "qp_failed", it, t0)
        self._guess = us.copy()
        cost = self.cost.value(xs, us, ref, u_ref)
        return NmpcResult(u=us[0].copy(), x_pred=xs, u_pred=us, solve_ms=_ms_since(t0), iterations=it,
                          status=status, ok=True, cost=cost, fallback=False, altitude_first=self.altitude_first.active)

    def _fallback(self, x0, lo, hi, status, iterations, t0) -> NmpcResult:
        """A bounded command when no plan can be trusted: the previous plan (shifted) or hover
        thrust, clipped to the bounds, and hip accelerations that stop the legs."""
        n = self.config.horizon
        us = self._initial_guess(self._hover_u, lo, hi)
        finite_x0 = np.all(np.isfinite(x0))
        if finite_x0:
            brake = -x0[rom.HIP_RATE] / self.config.dt_s
            us[:, rom.HIP_ACCEL] = np.clip(brake, lo[rom.HIP_ACCEL], hi[rom.HIP_ACCEL])
        us = np.clip(us, lo, hi)
        xs = np.tile(np.nan_to_num(x0), (n + 1, 1))
        if finite_x0:
            rolled = self._rollout(x0, us, np.zeros(ND))[0]
            if np.all(np.isfinite(rolled)):
                xs = rolled
        self._guess = None
        self._duals = None
        self._prepared = self._planned = None
        return NmpcResult(u=us[0].copy(), x_pred=xs, u_pred=us, solve_ms=_ms_since(t0), iterations=iterations,
                          status=status, ok=False, cost=float("inf"), fallback=True,
                          altitude_first=self.altitude_first.active)


def _finite_disturbance(disturbance) -> np.ndarray:
    """(6,) the disturbance estimate, zero where it is not finite (None: none)."""
    d = np.zeros(ND) if disturbance is None else np.asarray(disturbance, dtype=float).reshape(ND)
    return np.where(np.isfinite(d), d, 0.0)


def _ms_since(t0: float) -> float:
    return (time.perf_counter() - t0) * 1e3
