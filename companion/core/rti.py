"""The real-time iteration's QP: prepared before the state arrives, moved to it once it does.

A real-time iteration takes ONE Gauss-Newton QP step per control period, split in two phases.
The preparation (after the previous setpoint left, off the critical path) rolls the model out
from the state the last plan predicts for the next step along the previous plan shifted (one
compiled CasADi call: the trajectory and every stage's A_k, B_k and D_k = dx+/dd) and
condenses it into the dense QP on the inputs, with the predicted states' sensitivity P to the
initial state and the disturbance: dX = Gamma dU + P (dx0, dd). The feedback (once the state
arrives) moves the predicted states, the gradient and the constraint rows by P, and the
gradient by the change of the targets: the QP the preparation would have built at the
arrived state, to first order (initial-value embedding). It solves it with DAQP and takes
the full step.

The feedback (`RtiFeedback`) is two CasADi functions and a DAQP workspace: `moved`, from the
arrived state, reference, disturbance and input bounds to the QP's gradient and bounds (the
targets inside it); DAQP's solve on the workspace the preparation loaded; `plan`, from the
step to the plan (inputs, predicted states) and its cost. Compiled (`[nmpc] codegen`, the
default), the three are ONE call into C (companion.core.rti_compiled); else three calls from
Python (DAQP's Python binding, companion.core.feedback_qp). What the preparation fixed is
written into the two functions' parameter buffers at the preparation, not at the feedback.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from math import pi

import casadi as ca
import numpy as np

from companion.core.casadi_call import BufferedFunction
from companion.core.codegen_cache import compiled
from companion.core.condensing import Linearisation, QpRows, TrackingCost, sensitivities_and_parameters
from companion.core.feedback_qp import NO_BOUND, FeedbackQp
from companion.core.rom import EULER, ND, NU, NX
from companion.core.rti_compiled import INVALID_INPUT, CompiledFeedback, feedback_library

_YAW = EULER.stop - 1


@dataclass(frozen=True)
class PreparedQp:
    """The condensed QP linearised at the initial state x0 and disturbance d along the inputs us."""

    x0: np.ndarray
    d: np.ndarray
    ref: np.ndarray            # (N+1, 20) state targets at the preparation
    u_ref: np.ndarray          # (N, 8)
    us: np.ndarray             # (N, 8) the linearisation's inputs: the previous plan shifted
    xs: np.ndarray             # (N+1, 20) their rollout from x0
    gamma: np.ndarray          # (N*20, N*8) d x_{1..N} / dU
    sens: np.ndarray           # (N*20, 26) d x_{1..N} / d(x0, d)
    hess: np.ndarray           # (N*8, N*8) Gauss-Newton Hessian (with its damping)
    grad: np.ndarray           # (N*8,)
    rows: np.ndarray           # (m, N*8) the constraint rows' derivatives in dU
    row_values: np.ndarray     # (m,) the constraint rows at (x0, xs, us)
    cost: TrackingCost         # the cost the QP was built for


def prepare_qp(rollout: Linearisation, cost: TrackingCost, rows: QpRows, x0: np.ndarray, us: np.ndarray,
               d: np.ndarray, ref: np.ndarray, u_ref: np.ndarray, damping_rel: float) -> PreparedQp | None:
    """The QP at (x0, d) along us; damping_rel times the Hessian's largest diagonal entry is added
    to its diagonal. None when the rollout or its derivatives are not finite."""
    xs, a, b, c = rollout(x0, us, d)
    gamma, sens = sensitivities_and_parameters(a, b, c)      # every entry of a, b and c reaches them
    if not (np.isfinite(xs).all() and np.isfinite(gamma).all() and np.isfinite(sens).all()):
        return None
    hess, grad = cost.gauss_newton(gamma, xs, us, ref, u_ref)
    diagonal = np.einsum("ii->i", hess)          # a writeable view (np.diag_indices' fancy indexing: 7x slower)
    diagonal += damping_rel * diagonal.max()
    return PreparedQp(x0=x0.copy(), d=d.copy(), ref=ref, u_ref=u_ref, us=us, xs=xs, gamma=gamma, sens=sens,
                      hess=hess, grad=grad, rows=rows.jacobian(gamma), row_values=rows.values(x0, xs, us), cost=cost)


class RtiFeedback:
    """The feedback phase of the real-time iteration over `horizon` stages with the QP's rows
    `rows`: `load` a prepared QP (off the critical path), then `solve` at the arrived state and
    read the `planned` inputs and states. codegen: the two CasADi functions and DAQP compiled
    to C, one call (when the library can be built; else the functions compiled, DAQP from
    Python), or all three from Python."""

    def __init__(self, targets: ca.Function, horizon: int, rows: QpRows, sense: np.ndarray, iter_limit: int,
                 codegen: bool):
        self.horizon = horizon
        moved, plan = feedback_functions(targets, horizon, rows)
        library = feedback_library(moved, plan, codegen)
        if library is not None:
            def build(fn: ca.Function) -> ca.Function:
                return ca.external(fn.name(), str(library))       # the library's own, for `qp` and `plan`
        else:
            build = compiled if codegen else (lambda fn: fn)
        self._moved = BufferedFunction(build(moved), parameters=moved.n_in() - _MOVED_INPUTS)
        self._plan = BufferedFunction(build(plan), parameters=plan.n_in() - 1,       # all but the step
                                      shared={"gamma": self._moved.buffer("gamma"),   # one Gamma: 32 kB at N = 5
                                              "carry": self._moved.result("carry")})
        self._moved.set_parameters(rows_lo=rows.lo, rows_hi=rows.hi)
        self._bounds: tuple[np.ndarray, np.ndarray] | None = None    # the input bounds in the parameters
        self._cost: TrackingCost | None = None                        # the cost whose weights are in them
        self.solver = FeedbackQp(horizon * NU, sense, iter_limit) if library is None else \
            CompiledFeedback(library, self._moved, self._plan, horizon * NU, sense, iter_limit)
        self.duals = np.zeros(sense.size)          # the last solve's
        self.solve = self._python_solve if library is None else self._compiled_solve

    def load(self, prep: PreparedQp, warm: bool) -> None:
        """The next feedback's QP: prep's Hessian and rows into DAQP (warm: from the last solve's
        active set), the rest into the functions' parameters."""
        self.solver.load(prep.hess, prep.rows, warm=warm)
        us = prep.us.ravel()
        self._moved.set_parameters(x0_p=prep.x0, d_p=prep.d, xs_p=prep.xs[1:].ravel(), sens_t=prep.sens.T,
                                   gamma=prep.gamma, grad_p=prep.grad, ref_p=prep.ref[1:].ravel(),
                                   u_ref_p=prep.u_ref.ravel(), us=us, rows_p=prep.row_values)
        self._plan.set_parameters(us=us)
        cost = prep.cost
        if cost is not self._cost:               # it changes when altitude_first does
            self._moved.set_parameters(state_w2=cost.state_gradient_scale, input_w2=cost.input_gradient_scale)
            self._plan.set_parameters(state_w=cost.state_w.ravel(), input_w=np.tile(cost.input_w, self.horizon))
            self._cost = cost

    def _compiled_solve(self, x0: np.ndarray, x_ref: np.ndarray, d: np.ndarray, lo: np.ndarray,
                        hi: np.ndarray) -> int:
        """`solve` (the route chosen once, at construction): the loaded QP moved to the initial
        state x0 (20,), reference x_ref (N+1, 20) and disturbance d (6,), under the input bounds
        lo, hi (8,; read-only: kept while they are the same arrays), solved, and its plan
        (`planned`) when DAQP's exitflag is > 0: INVALID_INPUT when an entry of x0 or x_ref is not
        finite (or finite entries' sum overflows), else DAQP's exitflag (negative: the load, the
        solve or, compiled, the plan's evaluation failed). One call into C."""
        self._set_bounds(lo, hi)
        self._moved.set_inputs(x0, x_ref.ravel(), d)
        flag = self.solver.feedback()
        self.duals = self.solver.duals
        return flag

    def _python_solve(self, x0: np.ndarray, x_ref: np.ndarray, d: np.ndarray, lo: np.ndarray,
                      hi: np.ndarray) -> int:
        """`solve` as `_compiled_solve` says, in three calls from Python."""
        grad, upper, lower, _, inputs_sum = self.qp(x0, x_ref, d, lo, hi)
        if not math.isfinite(inputs_sum[0]):
            return INVALID_INPUT
        step, flag, self.duals = self.solver.solve(grad, upper, lower)
        if flag > 0:
            self._plan.evaluate(step)
        return flag

    def qp(self, x0: np.ndarray, x_ref: np.ndarray, d: np.ndarray, lo: np.ndarray,
           hi: np.ndarray) -> list[np.ndarray]:
        """The loaded QP moved as `solve` moves it: [gradient (N*8,), upper and lower bounds (N*8 + m,)
        on the step, what `plan` takes on from here (read where it lies), the sum of x0's and
        x_ref's entries (1,)]. The arrays are buffers that the next call overwrites."""
        self._set_bounds(lo, hi)
        return self._moved.evaluate(x0, x_ref.ravel(), d)

    def planned(self) -> tuple[np.ndarray, np.ndarray, float]:
        """(inputs (N, 8), predicted states (N+1, 20), the cost of both) of the last plan: the
        inputs within the QP's input bounds, the states moved by Gamma step (fresh arrays). The
        cost is not finite when a state is not."""
        us, xs, cost = self._plan.buffers()[1]
        return us.reshape(self.horizon, NU).copy(), xs.reshape(self.horizon + 1, NX).copy(), float(cost[0])

    def _set_bounds(self, lo: np.ndarray, hi: np.ndarray) -> None:
        if self._bounds is None or self._bounds[0] is not lo or self._bounds[1] is not hi:
            self._moved.set_parameters(lo=lo, hi=hi)
            self._bounds = (lo, hi)


_MOVED_INPUTS = 3                 # x0, x_ref, d; then the parameters


def feedback_functions(targets: ca.Function, horizon: int, rows: QpRows) -> tuple[ca.Function, ca.Function]:
    """The feedback's two CasADi functions, vectors stage after stage (numpy's (N+1, 20) and
    (N, 8) raveled); m = rows.count.

    moved: (x0 (20), x_ref ((N+1) * 20), d (6); then the input bounds lo, hi (8), what the
    preparation fixed: its x0, d, x_{1..N}, P^T, Gamma, gradient, state weights of stages 1..N
    times 2 (N*20), targets of stages 1..N, input targets, input weights times 2 (N*8), inputs
    us, rows; and the rows' lo and hi) -> the QP's gradient (N*8), upper and lower bounds on the
    step (N*8 + m), carry (the arrived x0, x_{1..N} moved, targets ((N+1) * 20), input targets
    (N*8), lo, hi), the sum of x0's and x_ref's entries (1).

    plan: (step (N*8); then moved's carry, us, state weights ((N+1) * 20), input weights (N*8), Gamma)
    -> inputs us + step within lo, hi (N*8), predicted states x_{0..N} moved by Gamma step
    ((N+1) * 20), their cost (1: with the weights as parameters, a state or input that is not
    finite makes it so, a zero weight too).
    """
    n_x, n_u = horizon * NX, horizon * NU
    x0, x_ref, d = ca.MX.sym("x0", NX), ca.MX.sym("x_ref", NX + n_x), ca.MX.sym("d", ND)
    lo, hi = ca.MX.sym("lo", NU), ca.MX.sym("hi", NU)
    x0_p, d_p, xs_p = ca.MX.sym("x0_p", NX), ca.MX.sym("d_p", ND), ca.MX.sym("xs_p", n_x)
    sens_t, gamma, grad_p = ca.MX.sym("sens_t", NX + ND, n_x), ca.MX.sym("gamma", n_x, n_u), ca.MX.sym("grad_p", n_u)
    state_w2, ref_p = ca.MX.sym("state_w2", n_x), ca.MX.sym("ref_p", n_x)
    u_ref_p, input_w2, us = ca.MX.sym("u_ref_p", n_u), ca.MX.sym("input_w2", n_u), ca.MX.sym("us", n_u)
    rows_p, rows_lo, rows_hi = (ca.MX.sym(name, rows.count) for name in ("rows_p", "rows_lo", "rows_hi"))

    ref, u_ref = targets(x0, x_ref, d)
    # The yaw moves by its change within +-pi: the model is the same at yaw + 2 pi, and a yaw
    # that wrapped from +pi to -pi between the preparation and the state (a heading through
    # south, a robot spinning after a rotor loss) is a small turn, not a 2 pi one that the
    # linearisation would carry into every predicted state.
    dx = x0 - x0_p
    turn = dx[_YAW]
    turn = ca.if_else(ca.fabs(turn) > pi, turn - 2 * pi * ca.floor(turn / (2 * pi) + 0.5), turn)
    moved = ca.vertcat(dx[:_YAW], turn, dx[_YAW + 1:], d - d_p)
    # Products as row vector times matrix: column after column of the matrix as it lies in memory.
    shift = ca.mtimes(moved.T, sens_t).T
    # The gradient (2 Q Gamma)^T (x - ref) + 2 R (u - u_ref) moves with the states and the targets.
    grad = (grad_p + ca.mtimes((state_w2 * (shift - (ref[NX:] - ref_p))).T, gamma).T
            - input_w2 * (u_ref - u_ref_p))
    row_values = (rows_p + ca.mtimes(ca.sparsify(ca.DM(rows.selection)), shift)
                  + ca.mtimes(ca.sparsify(ca.DM(rows.initial)), dx))
    upper = ca.vertcat(ca.repmat(hi, horizon) - us, ca.fmin(rows_hi - row_values, NO_BOUND))
    lower = ca.vertcat(ca.repmat(lo, horizon) - us, ca.fmax(rows_lo - row_values, -NO_BOUND))
    carry = ca.vertcat(x0, xs_p + shift, ref, u_ref, lo, hi)
    moved_fn = ca.Function(f"m4_rti_moved_n{horizon}",
                           [x0, x_ref, d, lo, hi, x0_p, d_p, xs_p, sens_t, gamma, grad_p, state_w2, ref_p, u_ref_p,
                            input_w2, us, rows_p, rows_lo, rows_hi],
                           [ca.densify(grad), ca.densify(upper), ca.densify(lower), ca.densify(carry),
                            ca.sum1(x0) + ca.sum1(x_ref)],
                           ["x0", "x_ref", "d", "lo", "hi", "x0_p", "d_p", "xs_p", "sens_t", "gamma", "grad_p",
                            "state_w2", "ref_p", "u_ref_p", "input_w2", "us", "rows_p", "rows_lo", "rows_hi"],
                           ["grad", "upper", "lower", "carry", "inputs_sum"])

    step, carry_in = ca.MX.sym("step", n_u), ca.MX.sym("carry", carry.numel())
    state_w, input_w = ca.MX.sym("state_w", NX + n_x), ca.MX.sym("input_w", n_u)
    arrived, xs_moved, ref_in, u_ref_in, lo_in, hi_in = ca.vertsplit(
        carry_in, np.cumsum([0, NX, n_x, NX + n_x, n_u, NU, NU]).tolist())
    inputs = ca.fmin(ca.fmax(us + step, ca.repmat(lo_in, horizon)), ca.repmat(hi_in, horizon))
    states = ca.vertcat(arrived, xs_moved + ca.mtimes(gamma, step))
    state_error, input_error = states - ref_in, inputs - u_ref_in
    cost = ca.dot(state_w * state_error, state_error) + ca.dot(input_w * input_error, input_error)
    plan_fn = ca.Function(f"m4_rti_plan_n{horizon}", [step, carry_in, us, state_w, input_w, gamma],
                          [ca.densify(inputs), ca.densify(states), cost],
                          ["step", "carry", "us", "state_w", "input_w", "gamma"], ["inputs", "states", "cost"])
    return moved_fn, plan_fn
