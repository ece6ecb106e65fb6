"""The same NMPC problem solved by IPOPT: the reference that keeps the fast route honest.

Multiple shooting over the same RK4 step, the same cost (TrackingCost of the Nmpc), the same
bounds and constraints (hard here). Used by the bench (speed ratio, cost gap) and the tests;
not fast enough for the control loop.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import casadi as ca
import numpy as np

from companion.core import rom
from companion.core.nmpc import Nmpc
from companion.core.rom import ND, NU, NX


@dataclass(frozen=True)
class IpoptResult:
    x_pred: np.ndarray      # (N+1, 20)
    u_pred: np.ndarray      # (N, 8)
    cost: float             # the Nmpc's cost of (x_pred, u_pred)
    solve_ms: float
    status: str
    ok: bool


class IpoptReference:
    """IPOPT on the problem of `nmpc`, warm-started from its own previous solution."""

    def __init__(self, nmpc: Nmpc, tol: float = 1e-9):
        self.nmpc = nmpc
        n, cfg, af = nmpc.config.horizon, nmpc.config, nmpc.af
        xs, us = ca.SX.sym("X", NX, n + 1), ca.SX.sym("U", NU, n)
        x0, ref, d = ca.SX.sym("x0", NX), ca.SX.sym("ref", NX, n + 1), ca.SX.sym("d", ND)
        u_ref = ca.SX.sym("u_ref", NU, n)
        cost = ca.sum1(ca.sum2(ca.DM(nmpc.cost.state_w.T) * (xs - ref) ** 2))
        cost += ca.sum1(ca.sum2(ca.repmat(ca.DM(nmpc.cost.input_w), 1, n) * (us - u_ref) ** 2))
        gaps = [xs[:, 0] - x0] + [nmpc.rom.step(xs[:, k], us[:, k], d) - xs[:, k + 1] for k in range(n)]
        g, self._g_lo, self._g_hi = gaps, [0.0] * NX * (n + 1), [0.0] * NX * (n + 1)
        if cfg.fixed_hip_rad is None:
            for k in range(1, n + 1):
                for a, b in af.same_side_pairs:
                    g.append(xs[rom.HIP.start + a, k] + xs[rom.HIP.start + b, k])
                    self._g_lo.append(-np.inf)
                    self._g_hi.append(af.same_side_sum_max_rad)
        first = nmpc.first_rows
        if first is not None:
            hips = x0[rom.HIP] + first.tau * x0[rom.HIP_RATE] + 0.5 * first.tau ** 2 * us[rom.HIP_ACCEL, 0]
            g.append(ca.DM(first.select) @ hips)
            self._g_lo += list(first.lo)
            self._g_hi += list(first.hi)
        nlp = {"x": ca.veccat(xs, us), "p": ca.veccat(x0, ref, u_ref, d), "f": cost, "g": ca.vertcat(*g)}
        opts = {"print_time": False, "ipopt": {"print_level": 0, "sb": "yes", "tol": tol, "max_iter": 500}}
        self._solver = ca.nlpsol("m4_nmpc_ipopt", "ipopt", nlp, opts)
        self._x_lo, self._x_hi = np.full((n + 1, NX), -np.inf), np.full((n + 1, NX), np.inf)
        lim = cfg.roll_pitch_max_rad
        self._x_lo[1:, rom.EULER.start:rom.EULER.start + 2] = -lim
        self._x_hi[1:, rom.EULER.start:rom.EULER.start + 2] = lim
        if cfg.fixed_hip_rad is None:
            self._x_lo[1:, rom.HIP], self._x_hi[1:, rom.HIP] = af.hip_min_rad, af.hip_max_rad
        self._guess: np.ndarray | None = None

    def reset(self) -> None:
        self._guess = None

    def solve(self, x0, x_ref, thrust_bound_n, disturbance=None) -> IpoptResult:
        n = self.nmpc.config.horizon
        x0 = np.asarray(x0, dtype=float)
        d = np.zeros(ND) if disturbance is None else np.asarray(disturbance, dtype=float)
        ref, u_ref = self.nmpc.targets(x0, np.asarray(x_ref, dtype=float), d)
        lo, hi = self.nmpc.input_bounds(thrust_bound_n)
        if self._guess is None:
            self._guess = np.concatenate([np.tile(x0, n + 1), u_ref.ravel()])
        lbx = np.concatenate([self._x_lo.ravel(), np.tile(lo, n)])
        ubx = np.concatenate([self._x_hi.ravel(), np.tile(hi, n)])
        t0 = time.perf_counter()
        sol = self._solver(x0=np.clip(self._guess, lbx, ubx), p=np.concatenate([x0, ref.ravel(), u_ref.ravel(), d]),
                           lbx=lbx, ubx=ubx, lbg=self._g_lo, ubg=self._g_hi)
        solve_ms = (time.perf_counter() - t0) * 1e3
        stats = self._solver.stats()
        z = np.asarray(sol["x"]).ravel()
        self._guess = z
        xs = z[:NX * (n + 1)].reshape(n + 1, NX)
        us = z[NX * (n + 1):].reshape(n, NU)
        return IpoptResult(x_pred=xs, u_pred=us, cost=self.nmpc.cost.value(xs, us, ref, u_ref),
                           solve_ms=solve_ms, status=stats["return_status"], ok=bool(stats["success"]))
