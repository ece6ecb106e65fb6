"""The real-time iteration's QP: prepared before the state arrives, moved to it once it does.

A real-time iteration takes ONE Gauss-Newton QP step per control period, split in two phases.
The preparation (after the previous setpoint left, off the critical path) rolls the model out
from the state the last plan predicts for the next step along the previous plan shifted (one
compiled CasADi call: the trajectory and every stage's A_k, B_k and D_k = dx+/dd) and
condenses it into the dense QP on the inputs, with the predicted states' sensitivity P to the
initial state and the disturbance: dX = Gamma dU + P (dx0, dd). The feedback (once the state
arrives) moves the predicted states, the gradient and the constraint rows by P, and the
gradient by the change of the targets: the QP the preparation would have built at the
arrived state, to first order (initial-value embedding). The caller then solves it with DAQP
and takes the full step.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from companion.core.condensing import Linearisation, TrackingCost, sensitivities_and_parameters
from companion.core.rom import EULER, NX

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
    grad_state: np.ndarray     # (N*8, N*20) the gradient's change per unit of x_{1..N}
    grad_input: np.ndarray     # (N*8,) the gradient's change per unit of U (negated: of u_ref)
    rows: np.ndarray           # (m, N*8) the constraint rows' derivatives in dU (row_jacobian of gamma)

    def states(self, x0: np.ndarray, d: np.ndarray) -> np.ndarray:
        """(N+1, 20) the prepared rollout moved to initial state x0 and disturbance d (first order).
        The yaw moves by its change within +-pi: the model is the same at yaw + 2 pi, and a yaw
        that wrapped from +pi to -pi between the preparation and the state (a heading through
        south, a robot spinning after a rotor loss) is a small turn, not a 2 pi one that the
        linearisation would carry into every predicted state."""
        xs = self.xs.copy()
        xs[0] = x0
        moved = np.empty(self.sens.shape[1])                # (dx0, dd)
        dx0 = np.subtract(x0, self.x0, out=moved[:NX])
        np.subtract(d, self.d, out=moved[NX:])
        yaw_change = float(dx0[_YAW])
        if abs(yaw_change) > np.pi:                           # within +-pi it rounds to no turn
            dx0[_YAW] = yaw_change - 2 * np.pi * round(yaw_change / (2 * np.pi))
        xs[1:] += (self.sens @ moved).reshape(-1, NX)
        return xs

    def gradient(self, xs: np.ndarray, ref: np.ndarray, u_ref: np.ndarray) -> np.ndarray:
        """The QP's gradient with the states moved to xs (from `states`) and the targets to ref, u_ref."""
        shift = (xs[1:] - self.xs[1:]) - (ref[1:] - self.ref[1:])
        return self.grad + self.grad_state @ shift.ravel() - self.grad_input * (u_ref - self.u_ref).ravel()


def prepare_qp(rollout: Linearisation, cost: TrackingCost, x0: np.ndarray, us: np.ndarray, d: np.ndarray,
               ref: np.ndarray, u_ref: np.ndarray, damping_rel: float,
               row_jacobian: Callable[[np.ndarray], np.ndarray]) -> PreparedQp | None:
    """The QP at (x0, d) along us; damping_rel times the Hessian's largest diagonal entry is added
    to its diagonal; row_jacobian gives the constraint rows' derivatives from gamma. None when the
    rollout or its derivatives are not finite."""
    xs, a, b, c = rollout(x0, us, d)
    gamma, sens = sensitivities_and_parameters(a, b, c)      # every entry of a, b and c reaches them
    if not (np.isfinite(xs).all() and np.isfinite(gamma).all() and np.isfinite(sens).all()):
        return None
    hess, grad, grad_state = cost.gauss_newton_parts(gamma, xs, us, ref, u_ref)
    diagonal = np.einsum("ii->i", hess)          # a writeable view (np.diag_indices' fancy indexing: 7x slower)
    diagonal += damping_rel * diagonal.max()
    return PreparedQp(x0=x0.copy(), d=d.copy(), ref=ref, u_ref=u_ref, us=us, xs=xs, gamma=gamma,
                      sens=sens, hess=hess, grad=grad, grad_state=grad_state,
                      grad_input=cost.input_gradient_scale, rows=row_jacobian(gamma))
