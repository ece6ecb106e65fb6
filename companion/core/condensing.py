"""Single-shooting linearisation of the ROM and its condensing into a dense QP on the inputs.

`linearisation(step, horizon)` is ONE CasADi function: from (x0, U, d) it rolls the model
out over the horizon and returns the trajectory with every stage's Jacobians A_k = dx+/dx,
B_k = dx+/du. `sensitivities_and_parameters` and `TrackingCost.gauss_newton` then eliminate
the states: with dX = Gamma dU the Gauss-Newton QP of the tracking cost has only the N * 8
inputs as variables, and every state constraint is a linear row in the inputs. At N = 5 that
is 40 variables, small enough for a dense active-set solver.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from companion.core import rom
from companion.core.casadi_call import BufferedFunction
from companion.core.rom import ND, NU, NX


def linearisation(step: ca.Function, horizon: int, disturbance_jacobian: bool = False) -> ca.Function:
    """(x0 (20), U (8, N), d (6)) -> X (20, N+1), A (20, 20 N), B (20, 8 N), and with
    disturbance_jacobian D (20, 6 N), D_k = dx+/dd (the real-time iteration's feedback moves
    its QP with the disturbance estimate)."""
    x, u, d = ca.SX.sym("x", NX), ca.SX.sym("u", NU), ca.SX.sym("d", ND)
    x_next = step(x, u, d)
    jacobians = [ca.jacobian(x_next, x), ca.jacobian(x_next, u)]
    if disturbance_jacobian:
        jacobians.append(ca.jacobian(x_next, d))
    stage = ca.Function("m4_nmpc_stage", [x, u, d], [x_next, *jacobians])
    rollout = stage.mapaccum("m4_nmpc_rollout", horizon)
    x0, us, dm = ca.MX.sym("x0", NX), ca.MX.sym("U", NU, horizon), ca.MX.sym("d", ND)
    xs, *jac = rollout(x0, us, ca.repmat(dm, 1, horizon))
    names = ["X", "A", "B", "D"][:1 + len(jac)]
    suffix = "_d" if disturbance_jacobian else ""
    return ca.Function(f"m4_nmpc_lin_n{horizon}{suffix}", [x0, us, dm], [ca.horzcat(x0, xs), *map(ca.densify, jac)],
                       ["x0", "U", "d"], names)


class Linearisation:
    """Evaluates a `linearisation` function on preallocated numpy buffers (companion.core.casadi_call).

    Call with (x0 (20,), us (N, 8), d (6,)); returns fresh arrays xs (N+1, 20),
    a (N, 20, 20) and b (N, 20, 8) with a[k] = A_k, b[k] = B_k, and c (N, 20, 6) with
    c[k] = D_k when the function has D (NaN when the evaluation fails: reported like a
    diverged rollout, the caller falls back).
    """

    def __init__(self, fn: ca.Function, horizon: int):
        self.horizon = horizon
        self._fn = BufferedFunction(fn)

    def __call__(self, x0: np.ndarray, us: np.ndarray, d: np.ndarray):
        n = self.horizon
        xs, *jac = self._fn.evaluate(x0, us.ravel(), d)
        # Column-major outputs: X (20, N+1) is xs (N+1, 20); A (20, 20N) holds A_k^T blocks.
        return (xs.reshape(n + 1, NX).copy(),
                *(m.reshape(n, m.size // (n * NX), NX).transpose(0, 2, 1).copy() for m in jac))


def sensitivities_and_parameters(a: np.ndarray, b: np.ndarray,
                                 c: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """Gamma (N*20, N*8): row block k is d x_{k+1} / d U, from A_k = a[k], B_k = b[k]; with
    D_k = c[k] also P (N*20, 26): row block k is d x_{k+1} / d(x0, d) (without c, None: the
    converged SQP's linearisation has no D). One pass: row block k of [Gamma | P] is A_k times
    block k-1, with B_k and D_k added in their columns (block 0: [B_0 0 | A_0 D_0])."""
    horizon = a.shape[0]
    inputs = horizon * NU
    both = np.zeros((horizon * NX, inputs + (0 if c is None else NX + ND)))
    both[:NX, :NU] = b[0]
    if c is not None:
        both[:NX, inputs:inputs + NX], both[:NX, inputs + NX:] = a[0], c[0]
    for k in range(1, horizon):
        rows = slice(k * NX, (k + 1) * NX)
        np.matmul(a[k], both[rows.start - NX:rows.start], out=both[rows])
        both[rows, k * NU:(k + 1) * NU] = b[k]          # block k-1 has no part of input k: exact
        if c is not None:
            both[rows, inputs + NX:] += c[k]
    gamma = np.ascontiguousarray(both[:, :inputs])      # Gamma contiguous: its products are faster
    return gamma, (None if c is None else both[:, inputs:])


class TrackingCost:
    """Diagonal quadratic tracking cost; state_w (N+1, 20) per stage, input_w (8,)."""

    def __init__(self, state_w: np.ndarray, input_w: np.ndarray):
        self.state_w = np.asarray(state_w, dtype=float)
        self.input_w = np.asarray(input_w, dtype=float)
        horizon = self.state_w.shape[0] - 1
        self._qw2 = 2.0 * self.state_w[1:].reshape(-1, 1)               # stages 1..N, as a column
        self._rw2 = 2.0 * np.tile(self.input_w, horizon)
        self._r_hess = np.diag(self._rw2)

    def value(self, xs: np.ndarray, us: np.ndarray, x_ref: np.ndarray, u_ref: np.ndarray) -> float:
        """Cost of a trajectory xs (N+1, 20), inputs us (N, 8)."""
        ex, eu = xs - x_ref, us - u_ref
        return float(np.vdot(self.state_w * ex, ex) + np.vdot(self.input_w * eu, eu))

    def gauss_newton(self, gamma: np.ndarray, xs: np.ndarray, us: np.ndarray, x_ref: np.ndarray,
                     u_ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Hessian and gradient of the cost in dU, with dX = Gamma dU (x0 is fixed)."""
        wg = self._qw2 * gamma
        hess = gamma.T @ wg + self._r_hess
        grad = wg.T @ (xs[1:] - x_ref[1:]).ravel() + self._rw2 * (us - u_ref).ravel()
        return hess, grad

    @property
    def state_gradient_scale(self) -> np.ndarray:
        """(N*20,) the state weights of stages 1..N times 2: the gradient is Gamma^T times them
        times the states' distance to their targets, plus the inputs' part."""
        return self._qw2.ravel()

    @property
    def input_gradient_scale(self) -> np.ndarray:
        """(N*8,) the gradient's change per unit of change of the inputs (negated: of their reference)."""
        return self._rw2


@dataclass(frozen=True)
class StateRows:
    """Linear functions of the predicted states 1..N, each with bounds: c = S x, lo <= c <= hi.

    Every row is a sum of one or two state entries (one for roll, pitch, a hip; two for the
    sum of the hips on one side), so evaluation is indexing, never a big matrix product.
    """

    first: np.ndarray       # (m,) flat index into states 1..N of the first entry
    paired: np.ndarray      # (m,) bool: the row sums a second entry
    second: np.ndarray      # (number of paired rows,) flat index of that second entry
    lo: np.ndarray
    hi: np.ndarray

    @staticmethod
    def build(horizon: int, entries: list[tuple[tuple[int, ...], float, float]]) -> StateRows:
        """entries: (state indices summed, lo, hi), each repeated over the stages 1..N."""
        first, second, lo, hi = [], [], [], []
        for k in range(horizon):
            for idx, low, high in entries:
                first.append(k * NX + idx[0])
                second.append(k * NX + idx[1] if len(idx) > 1 else -1)
                lo.append(low)
                hi.append(high)
        second_all = np.array(second, dtype=int)
        return StateRows(np.array(first, dtype=int), second_all >= 0, second_all[second_all >= 0], np.array(lo),
                         np.array(hi))

    @property
    def count(self) -> int:
        return self.first.size

    def values(self, xs: np.ndarray) -> np.ndarray:
        flat = xs[1:].ravel()
        c = flat[self.first]
        c[self.paired] += flat[self.second]
        return c

    def jacobian(self, gamma: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """The rows' derivatives in dU, from Gamma (N*20, N*8); into `out` (m, N*8) if given."""
        rows = np.take(gamma, self.first, axis=0, out=out)
        rows[self.paired] += gamma[self.second]
        return rows

    def violation(self, xs: np.ndarray) -> float:
        return _violation(self.values(xs), self.lo, self.hi)


def state_rows(horizon: int, roll_pitch_max_rad: float, hip_bounds: tuple[float, float] | None,
               side_pairs: tuple[tuple[int, int], ...], side_sum_max_rad: float) -> StateRows:
    """Roll and pitch within +-roll_pitch_max_rad; with hip_bounds, each hip in its range and
    the hips of each side pair (rotor indices) summing to at most side_sum_max_rad."""
    roll, pitch = rom.EULER.start, rom.EULER.start + 1
    entries: list[tuple[tuple[int, ...], float, float]] = [
        ((roll,), -roll_pitch_max_rad, roll_pitch_max_rad),
        ((pitch,), -roll_pitch_max_rad, roll_pitch_max_rad)]
    if hip_bounds is not None:
        entries += [((rom.HIP.start + i,), *hip_bounds) for i in range(NU // 2)]
        entries += [((rom.HIP.start + a, rom.HIP.start + b), -np.inf, side_sum_max_rad) for a, b in side_pairs]
    return StateRows.build(horizon, entries)


@dataclass(frozen=True)
class FirstPeriodHipRows:
    """Hips and same-side sums `tau` seconds into stage 0 (tau: the control period, when the
    NMPC is re-solved before its first stage ends). The nodes of the horizon alone would let
    a hip swing past its bound between two nodes, and the robot only ever flies that first
    stretch; the rows are exact and linear in stage 0's hip accelerations."""

    tau: float
    select: np.ndarray      # (m, 4): which hips each row sums
    lo: np.ndarray
    hi: np.ndarray
    jac: np.ndarray         # (m, N*8)
    state_jac: np.ndarray   # (m, 20): the rows' derivatives in the initial state

    @staticmethod
    def build(horizon: int, tau: float, hip_bounds: tuple[float, float],
              side_pairs: tuple[tuple[int, int], ...], side_sum_max_rad: float) -> FirstPeriodHipRows:
        hips = NU // 2
        select = np.vstack([np.eye(hips)] + [np.eye(hips)[a] + np.eye(hips)[b] for a, b in side_pairs])
        lo = np.r_[np.full(hips, hip_bounds[0]), np.full(len(side_pairs), -np.inf)]
        hi = np.r_[np.full(hips, hip_bounds[1]), np.full(len(side_pairs), side_sum_max_rad)]
        jac = np.zeros((select.shape[0], horizon * NU))
        jac[:, rom.HIP_ACCEL] = 0.5 * tau ** 2 * select
        state_jac = np.zeros((select.shape[0], NX))
        state_jac[:, rom.HIP], state_jac[:, rom.HIP_RATE] = select, tau * select
        return FirstPeriodHipRows(tau, select, lo, hi, jac, state_jac)

    @property
    def count(self) -> int:
        return self.select.shape[0]

    def values(self, x0: np.ndarray, us: np.ndarray) -> np.ndarray:
        hips = x0[rom.HIP] + self.tau * x0[rom.HIP_RATE] + 0.5 * self.tau ** 2 * us[0, rom.HIP_ACCEL]
        return self.select @ hips

    def violation(self, x0: np.ndarray, us: np.ndarray) -> float:
        return _violation(self.values(x0, us), self.lo, self.hi)


class QpRows:
    """The QP's general constraints over `horizon` stages: the state rows at the nodes 1..N,
    then the first period's hip rows (when there are), with their bounds lo and hi (m,). For fixed inputs, the rows
    change by `selection` (m, N*20) times the change of x_{1..N} plus `initial` (m, 20) times
    that of x0."""

    def __init__(self, horizon: int, nodes: StateRows, first: FirstPeriodHipRows | None):
        self.nodes, self.first = nodes, first
        parts = (nodes,) if first is None else (nodes, first)
        self.count = sum(part.count for part in parts)
        self.lo = np.concatenate([part.lo for part in parts])
        self.hi = np.concatenate([part.hi for part in parts])
        self.selection = np.zeros((self.count, horizon * NX))      # (m, N*20)
        self.initial = np.zeros((self.count, NX))                  # (m, 20)
        node_rows = np.arange(nodes.count)
        np.add.at(self.selection, (node_rows, nodes.first), 1.0)
        np.add.at(self.selection, (node_rows[nodes.paired], nodes.second), 1.0)
        if first is not None:
            self.initial[nodes.count:] = first.state_jac

    def values(self, x0: np.ndarray, xs: np.ndarray, us: np.ndarray) -> np.ndarray:
        """(m,) the rows at the states xs (N+1, 20), the first period's from x0 and us (N, 8)."""
        nodes = self.nodes.values(xs)
        return nodes if self.first is None else np.concatenate([nodes, self.first.values(x0, us)])

    def jacobian(self, gamma: np.ndarray) -> np.ndarray:
        """(m, N*8) the rows' derivatives in the step dU, from Gamma (N*20, N*8)."""
        rows = np.empty((self.count, gamma.shape[1]))
        self.nodes.jacobian(gamma, out=rows[:self.nodes.count])
        if self.first is not None:
            rows[self.nodes.count:] = self.first.jac
        return rows


def _violation(c: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> float:
    """Total amount by which the row values c leave their bounds [lo, hi]."""
    return float(np.sum(np.maximum(c - hi, 0.0) + np.maximum(lo - c, 0.0)))
