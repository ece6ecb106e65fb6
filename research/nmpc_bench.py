"""`m4-companion bench`: how fast the NMPC solves on this machine, and whether it solves right.

A closed-loop-like sequence on the reduced-order model: hover with measurement noise, a
random kick (velocity and body-rate jump) every second, a 10 % heavier robot with weaker
thrusters in a light wind (so the disturbance estimate moves) and rotor 4 lost halfway,
one warm-started solve per control period. The same problems (state, reference, thrust
bounds, disturbance) are then solved by IPOPT, warm-started from its own previous
solution, so the speed ratio comes with the relative cost gap: speed never hides a wrong
answer.

Measured on the 2-core development machine while other jobs kept it busy (load 1-3),
300 solves, `m4-companion bench` (BLAS single-threaded), milliseconds median / p99 / max,
relative cost gap to IPOPT median / max:

    N = 5,  dt = 0.1 s                      1.1 / 2.1 / 2.4     IPOPT 37 ms   gap 1e-6 / 9e-6
    N = 5,  dt = 0.1 s, re-solved at 50 Hz  1.3 / 3.0 / 4.5     IPOPT 44 ms   gap 1e-6 / 9e-5
    N = 20, dt = 0.025 s                    8.1 / 23 / 37       IPOPT 197 ms  gap 1e-6 / 4e-5

Routes not kept: those of docs/performance.md (IPOPT, sqpmethod with qrqp or HPIPM,
fatrop; 3.5-12.8 ms median at N = 5 as measured there); measured here, for the condensed QP, qpOASES
and qrqp through CasADi (0.40 and 0.95 ms per QP against DAQP's 0.02 ms); the condensing
itself compiled into the CasADi function (0.22 ms per call: its generated matrix products
lose to numpy's BLAS, 0.05 ms). One SQP iteration per solve (max_iterations=1, a real-time
iteration) takes 0.5 ms median, with a cost gap of 1e-3 median and up to 10x right after a kick.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass

import numpy as np

from m4.airframe import Airframe, load_airframe
from companion.core import rom
from companion.core.nmpc import Nmpc
from companion.core.nmpc_config import NmpcConfig
from research.nmpc_ipopt import IpoptReference
from research.rom_sim import (
    PlantMismatch,
    RotorFault,
    SimConfig,
    hold_reference,
    simulate,
)

_FAILED_INDEX = 3                # rotor 4


@dataclass(frozen=True)
class BenchReport:
    horizon: int
    dt_s: float
    control_period_s: float         # one solve per control period (the model keeps dt_s)
    solves: int
    setup_s: float                  # building (and, on a cold cache, compiling) the solver
    solve_ms_median: float
    solve_ms_p99: float
    solve_ms_max: float
    iterations_median: float
    fallbacks: int
    ipopt_ms_median: float
    ipopt_ms_p99: float
    ipopt_failures: int
    speedup_vs_ipopt: float         # IPOPT median / ours median
    cost_gap_rel_median: float      # (ours - IPOPT) / |IPOPT|, over solves both converged
    cost_gap_rel_max: float

    def as_dict(self) -> dict:
        return asdict(self)

    def table(self) -> str:
        rows = [("route", "median ms", "p99 ms", "max ms"),
                ("GN-SQP + DAQP (ours)", f"{self.solve_ms_median:.3f}", f"{self.solve_ms_p99:.3f}",
                 f"{self.solve_ms_max:.3f}"),
                ("IPOPT (reference)", f"{self.ipopt_ms_median:.3f}", f"{self.ipopt_ms_p99:.3f}", "")]
        widths = [max(len(r[i]) for r in rows) for i in range(4)]
        lines = [(f"NMPC bench: N = {self.horizon}, dt = {self.dt_s} s, re-solved every {self.control_period_s} s, "
                  f"{self.solves} warm-started solves (setup {self.setup_s:.1f} s)")]
        lines += ["  ".join(c.ljust(w) for c, w in zip(r, widths)) for r in rows]
        lines.append(f"speed-up vs IPOPT: {self.speedup_vs_ipopt:.1f} x   SQP iterations (median): "
                     f"{self.iterations_median:g}   fallbacks: {self.fallbacks}   "
                     f"IPOPT failures: {self.ipopt_failures}")
        lines.append(f"relative cost gap to IPOPT: median {self.cost_gap_rel_median:.2e}, "
                     f"max {self.cost_gap_rel_max:.2e}")
        return "\n".join(lines)


def bench_sequence(af: Airframe, nmpc: Nmpc, solves: int, seed: int = 0):
    """The closed-loop-like sequence of `solves` control steps (one solve each)."""
    period = nmpc.config.dt_s * nmpc.config.warm_start_shift
    duration = solves * period
    fault = RotorFault(duration / 2, _FAILED_INDEX, 1.0)
    sim = SimConfig(duration_s=duration, control_period_s=period, faults=(fault,),
                    mismatch=PlantMismatch(mass_scale=1.1, thrust_scale=0.95, wind_force_ned_n=(1.0, -0.5, 0.0)),
                    estimator_gain=0.3, kick_every_s=1.0, noise_scale=1.0, seed=seed)
    x0 = rom.hover_state(af)
    return simulate(nmpc, x0, hold_reference(x0, nmpc.config.horizon), sim)


def run_bench(horizon: int = 5, dt_s: float = 0.1, solves: int = 300, seed: int = 0,
              control_period_s: float | None = None) -> BenchReport:
    """control_period_s: re-solve this often (None: every dt_s)."""
    af = load_airframe()
    t0 = time.perf_counter()
    nmpc = Nmpc(af, NmpcConfig(horizon=horizon, dt_s=dt_s, control_period_s=control_period_s, scheme="sqp"))
    setup_s = time.perf_counter() - t0
    log = bench_sequence(af, nmpc, solves, seed)
    ipopt = IpoptReference(nmpc)
    ipopt_ms, gaps, failures = np.zeros(solves), [], 0
    for k in range(solves):
        res = ipopt.solve(log.x_measured[k], log.x_ref[k], log.thrust_max_known_n[k], log.disturbance[k])
        ipopt_ms[k] = res.solve_ms
        if not res.ok:
            failures += 1
        elif not log.fallback[k]:
            gaps.append((log.cost[k] - res.cost) / max(abs(res.cost), 1e-12))
    gaps_arr = np.array(gaps) if gaps else np.array([np.nan])
    ours = log.solve_ms
    return BenchReport(
        horizon=horizon, dt_s=dt_s, control_period_s=dt_s if control_period_s is None else control_period_s,
        solves=solves, setup_s=setup_s,
        solve_ms_median=float(np.median(ours)), solve_ms_p99=float(np.percentile(ours, 99)),
        solve_ms_max=float(ours.max()), iterations_median=float(np.median(log.iterations)),
        fallbacks=int(log.fallback.sum()), ipopt_ms_median=float(np.median(ipopt_ms)),
        ipopt_ms_p99=float(np.percentile(ipopt_ms, 99)), ipopt_failures=failures,
        speedup_vs_ipopt=float(np.median(ipopt_ms) / np.median(ours)),
        cost_gap_rel_median=float(np.median(gaps_arr)), cost_gap_rel_max=float(np.max(gaps_arr)))
