"""The real-time iteration's QP in one DAQP workspace: factorised at the preparation, solved at the feedback.

The feedback's Python route, through DAQP's binding: it flies where the compiled one
(companion.core.rti_compiled, the same workspace in C) cannot be built.

`daqp.solve` sets a QP up from scratch at every call: it factorises the Hessian and scales
every constraint row by the factor (the Hessian's Cholesky factor R, the rows A R^-1) for the
NMPC's 40 inputs and 46 rows, before its few active-set iterations. In a real-time iteration
the Hessian and the rows are the preparation's (the arrived state moves only the gradient and
the bounds), so `load` hands them to a kept `daqp.Model` then, off the critical path (about
48 us), and `solve` gives it only the gradient and the bounds: along `m4-companion bench`'s
control steps 22 us median between the state and the step against 61 us for `daqp.solve`.
The solution is daqp.solve's on the same data, to rounding (the same solver, its sums in
another order).

Warm start: the model starts from the active set of its last solve, as `daqp.solve` does with
that solve's duals as `dual_start`; `load(..., warm=False)` starts it from none (after a
fallback or a reset, as `dual_start=None`).
"""

from __future__ import annotations

import daqp
import numpy as np

NO_BOUND = 1e30              # DAQP's "no bound"


class FeedbackQp:
    """A DAQP model for QPs of `variables` unknowns and the constraint kinds `sense` (simple
    bounds first, then the rows), at most `iter_limit` iterations a solve."""

    def __init__(self, variables: int, sense: np.ndarray, iter_limit: int):
        self._model = daqp.Model()
        self._model.settings = {"iter_limit": iter_limit}
        self._variables = variables
        self._sense = sense
        self._shapes = {"hess": (variables, variables), "rows": (sense.size - variables, variables),
                        "grad": (variables,), "upper": sense.shape, "lower": sense.shape}
        self._set_up = False
        self._flag = -1                          # the last load's DAQP exitflag (< 0: failed or none yet)
        self.iterations = 0                      # the last solve's active-set iterations

    def load(self, hess: np.ndarray, rows: np.ndarray, warm: bool) -> None:
        """The Hessian (n, n) and the constraint rows (m, n) of the next solves; warm: start from
        the last solve's active set (else from none)."""
        self._check(hess=hess, rows=rows)
        if not self._set_up:
            free = np.full(self._sense.size, NO_BOUND)
            self._flag, _ = self._model.setup(hess, np.zeros(self._variables), rows, free, -free, self._sense)
        elif warm:
            self._flag = self._model.update(H=hess, A=rows)
        else:
            self._flag = self._model.update(H=hess, A=rows, sense=self._sense)
        self._set_up = self._flag >= 0          # a Hessian DAQP could not factorise: set up anew next time

    def solve(self, grad: np.ndarray, upper: np.ndarray, lower: np.ndarray) -> tuple[np.ndarray, int, np.ndarray]:
        """(x, exitflag, duals) of the loaded QP with this gradient and these bounds (simple bounds
        first); DAQP's negative exitflag and NaN when the load failed."""
        if grad.shape != self._shapes["grad"] or upper.shape != self._shapes["upper"] \
                or lower.shape != self._shapes["lower"]:
            self._check(grad=grad, upper=upper, lower=lower)
        if self._flag < 0:
            return np.full(self._variables, np.nan), self._flag, np.zeros(self._sense.size)
        self._model.update(f=grad, bupper=upper, blower=lower)
        x, _, flag, info = self._model.solve()
        self.iterations = info["iterations"]
        return x, flag, info["lam"]

    def _check(self, **arrays: np.ndarray) -> None:
        """A ValueError naming the first array not of its shape: DAQP would take it silently
        (a Hessian or gradient too small, bounds too short) and solve another QP."""
        for name, value in arrays.items():
            if np.shape(value) != self._shapes[name]:
                raise ValueError(f"FeedbackQp: {name} must have shape {self._shapes[name]}, got {np.shape(value)}")
