"""The NMPC's two schemes side by side: `python -m benchmarks.rti [--rate-hz 50] [--seconds 6]`.

Both fly the same closed loop on the reduced-order model (research.rom_sim, as `m4-companion
bench`): hover with measurement noise, a kick (velocity and body-rate jump) every second, a
10 % heavier robot with 5 % weaker thrusters in a light wind (the disturbance estimate moves),
rotor 4 lost halfway and known to the NMPC 40 ms later. The SQP ("sqp") solves each step to
convergence; the real-time iteration ("rti") feeds back one prepared QP per step and
prepares the next after it. Printed: the time from the state to the command (the SQP's solve,
the RTI's feedback) and the RTI's preparation, median / p99 / max in ms; then the RTI's cost
gap along its own flight: at every step the cost of its plan (by the model's rollout) against
the converged SQP's optimum of the same problem, relative, as a median and as the worst
over the whole flight, the 0.5 s after the fault and the 0.5 s after each kick.
"""

from __future__ import annotations

import argparse

import numpy as np

from m4.airframe import load_airframe
from m4.arguments import positive_number
from companion.core import rom
from companion.core.nmpc import Nmpc, NmpcResult
from companion.core.nmpc_config import NmpcConfig
from research.rom_sim import PlantMismatch, RotorFault, SimConfig, hold_reference, simulate

_SETTLE_S = 0.5                # "after" an event: this long


class _Recorded:
    """An Nmpc whose solves (with their problems) and preparation times are kept."""

    def __init__(self, nmpc: Nmpc):
        self.nmpc, self.af, self.config = nmpc, nmpc.af, nmpc.config
        self.problems: list[tuple] = []
        self.results: list[NmpcResult] = []
        self.prepare_ms: list[float] = []

    def solve(self, x0, x_ref, thrust_bound_n, disturbance=None) -> NmpcResult:
        res = self.nmpc.solve(x0, x_ref, thrust_bound_n, disturbance)
        self.problems.append((np.array(x0), np.array(x_ref), np.array(thrust_bound_n), np.array(disturbance)))
        self.results.append(res)
        return res

    def prepare(self, x_ref, thrust_bound_n, disturbance=None) -> None:
        self.nmpc.prepare(x_ref, thrust_bound_n, disturbance)
        if self.config.scheme == "rti":
            self.prepare_ms.append(self.nmpc.prepare_ms)


def fly(scheme: str, sim: SimConfig) -> _Recorded:
    af = load_airframe()
    nmpc = _Recorded(Nmpc(af, NmpcConfig(control_period_s=sim.control_period_s, scheme=scheme)))
    x0 = rom.hover_state(af)
    simulate(nmpc, x0, hold_reference(x0, nmpc.config.horizon), sim)
    return nmpc


def cost_gaps(rti: _Recorded, period_s: float) -> np.ndarray:
    """(K,) relative gap of each RTI plan's cost to the converged SQP's optimum of its problem."""
    optimum = Nmpc(rti.af, NmpcConfig(control_period_s=period_s, max_iterations=50, cost_tol_rel=1e-9, scheme="sqp"))
    gaps = np.full(len(rti.results), np.nan)
    for k, ((x0, x_ref, bound, d), res) in enumerate(zip(rti.problems, rti.results)):
        best = optimum.solve(x0, x_ref, bound, d)
        if res.ok and best.ok:
            gaps[k] = (rti.nmpc.plan_cost(x0, x_ref, res.u_pred, d) - best.cost) / max(abs(best.cost), 1e-12)
    return gaps


def _figures(ms) -> str:
    a = np.asarray(ms)
    return f"{np.median(a):.3f} / {np.percentile(a, 99):.3f} / {a.max():.3f}"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.rti", description=__doc__.split("\n\n")[0])
    p.add_argument("--rate-hz", type=positive_number, default=50.0, help="control rate (default 50)")
    p.add_argument("--seconds", type=positive_number, default=6.0, help="flight length (default 6 s)")
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)
    period = 1.0 / args.rate_hz
    fault_s = args.seconds / 2
    sim = SimConfig(duration_s=args.seconds, control_period_s=period, faults=(RotorFault(fault_s, 3, 1.0),),
                    known_delay_s=0.04, mismatch=PlantMismatch(mass_scale=1.1, thrust_scale=0.95,
                                                               wind_force_ned_n=(1.0, -0.5, 0.0)),
                    estimator_gain=0.3, kick_every_s=1.0, noise_scale=1.0, seed=args.seed)
    runs = {scheme: fly(scheme, sim) for scheme in ("sqp", "rti")}
    steps = len(runs["rti"].results)
    print(f"NMPC schemes on the ROM closed loop: N = 5, dt = 0.1 s, {args.rate_hz:g} Hz, {steps} steps, "
          f"rotor 4 lost at {fault_s:g} s, a kick every 1 s (ms: median / p99 / max)")
    print("scheme  state -> command         preparation (after the send)  iterations (median)  fallbacks")
    for scheme, run in runs.items():
        prep = _figures(run.prepare_ms) if run.prepare_ms else "-"
        print(f"{scheme:6}  {_figures([r.solve_ms for r in run.results]):23}  {prep:28}  "
              f"{np.median([r.iterations for r in run.results]):<19g}  {sum(r.fallback for r in run.results)}")
    gaps = cost_gaps(runs["rti"], period)
    t = np.arange(steps) * period
    after_fault = (t >= fault_s) & (t < fault_s + _SETTLE_S)
    kicks = np.arange(1.0, args.seconds, 1.0)
    after_kick = np.any([(t >= k) & (t < k + _SETTLE_S) for k in kicks if k != fault_s], axis=0)
    print("RTI cost gap to the converged SQP, relative ((rti - optimum) / optimum):")
    print(f"  median {np.nanmedian(gaps):.2e}   worst {np.nanmax(gaps):.2e}   worst in the {_SETTLE_S:g} s after the "
          f"fault {np.nanmax(gaps[after_fault]):.2e}   after a kick {np.nanmax(gaps[after_kick]):.2e}   "
          f"median after the fault {np.nanmedian(gaps[after_fault]):.2e}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
