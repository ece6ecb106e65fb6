"""Closed loop on the reduced-order model as plant: the NMPC's first test bench (no MuJoCo).

The plant is the ROM of a possibly different robot (mass, inertia and thrust scaled, a
constant wind force), integrated with fine RK4 substeps, the controller's input held over
each control period. Each rotor has a true thrust limit (lowered by faults) and a limit the
controller knows (lowered `known_delay_s` later; 0 is the paper's assumption). Optional
kicks (random velocity and rate jumps) and measurement noise make the closed-loop-like
sequences of the bench. Everything is returned as arrays.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from m4.airframe import ROTOR_COUNT, Airframe
from companion.core import rom
from companion.core.disturbance import DisturbanceEstimator
from companion.core.nmpc import Nmpc

# Measurement noise shape (one standard deviation per state entry) at noise_scale = 1.
_NOISE_STD = np.r_[np.full(3, 0.01), np.full(3, 0.005), np.full(4, 0.002), np.full(3, 0.02), np.full(3, 0.02),
                   np.full(4, 0.01)]


@dataclass(frozen=True)
class RotorFault:
    at_s: float
    index: int                  # the rotor's, 0..3 (rotor - 1)
    loss: float                 # loss of effectiveness: the limit becomes (1 - loss) x hover thrust


@dataclass(frozen=True)
class PlantMismatch:
    mass_scale: float = 1.0
    inertia_scale: float = 1.0
    thrust_scale: float = 1.0   # delivered / commanded thrust
    wind_force_ned_n: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def airframe(self, af: Airframe) -> Airframe:
        m = self.mass_scale
        return dataclasses.replace(
            af, body_mass_kg=af.body_mass_kg * m, leg_hip_block_mass_kg=af.leg_hip_block_mass_kg * m,
            leg_link_mass_kg=af.leg_link_mass_kg * m, leg_wheel_mass_kg=af.leg_wheel_mass_kg * m,
            body_inertia_diag_kg_m2=tuple(i * m * self.inertia_scale for i in af.body_inertia_diag_kg_m2))


@dataclass(frozen=True)
class SimConfig:
    duration_s: float
    control_period_s: float = 0.02
    plant_substeps: int = 4                  # RK4 substeps of the plant per control period
    faults: tuple[RotorFault, ...] = ()
    thrust_cap_n: float | None = None        # every rotor's limit (plant and controller); None: the airframe's
    known_delay_s: float = 0.0               # the controller learns of a fault this much later
    mismatch: PlantMismatch = field(default_factory=PlantMismatch)
    estimator_gain: float | None = None      # None: no disturbance estimate (d = 0)
    kick_every_s: float | None = None        # random velocity (+-0.5 m/s) and rate (+-1 rad/s) jumps
    noise_scale: float = 0.0
    seed: int = 0


@dataclass(frozen=True)
class SimLog:
    t_s: np.ndarray                 # (K,) time of each control step
    x: np.ndarray                   # (K + 1, 20) true plant state (last row: after the last step)
    x_measured: np.ndarray          # (K, 20) what the controller saw
    x_ref: np.ndarray               # (K, N + 1, 20)
    u: np.ndarray                   # (K, 8) commanded
    thrust_delivered_n: np.ndarray  # (K, 4)
    thrust_max_known_n: np.ndarray  # (K, 4)
    disturbance: np.ndarray         # (K, 6) estimate given to the NMPC
    solve_ms: np.ndarray            # (K,)
    cost: np.ndarray                # (K,) NMPC cost of each solve (inf on a fallback)
    iterations: np.ndarray          # (K,)
    fallback: np.ndarray            # (K,) bool
    status: tuple[str, ...]


def hold_reference(x_hold: np.ndarray, horizon: int) -> Callable[[float], np.ndarray]:
    """Reference that holds one state (position, level attitude, at rest)."""
    ref = np.tile(np.asarray(x_hold, dtype=float), (horizon + 1, 1))
    return lambda t: ref


def thrust_limits(af: Airframe, sim: SimConfig, t_s: float, delay_s: float = 0.0) -> np.ndarray:
    """Per-rotor thrust limit at time t_s for the faults of sim, taking effect delay_s after at_s."""
    cap = af.thrust_max_n if sim.thrust_cap_n is None else min(sim.thrust_cap_n, af.thrust_max_n)
    limit = np.full(ROTOR_COUNT, cap)
    for f in sim.faults:
        if t_s >= f.at_s + delay_s:
            limit[f.index] = min(limit[f.index], (1.0 - f.loss) * af.hover_thrust_per_rotor_n)
    return limit


def simulate(nmpc: Nmpc, x_init: np.ndarray, reference: Callable[[float], np.ndarray], sim: SimConfig) -> SimLog:
    af = nmpc.af
    period = sim.control_period_s
    plant = rom.build_rom(sim.mismatch.airframe(af), period, sim.plant_substeps).step
    d_true = np.r_[sim.mismatch.wind_force_ned_n, np.zeros(3)]
    estimator = None if sim.estimator_gain is None else DisturbanceEstimator(af, period, sim.estimator_gain)
    rng = np.random.default_rng(sim.seed)
    kick_steps = None if sim.kick_every_s is None else max(1, round(sim.kick_every_s / period))
    steps = round(sim.duration_s / period)
    n = nmpc.config.horizon
    xs, xm, refs = np.zeros((steps + 1, rom.NX)), np.zeros((steps, rom.NX)), np.zeros((steps, n + 1, rom.NX))
    us, delivered, known = np.zeros((steps, rom.NU)), np.zeros((steps, ROTOR_COUNT)), np.zeros((steps, ROTOR_COUNT))
    dist, solve_ms, cost = np.zeros((steps, rom.ND)), np.zeros(steps), np.zeros(steps)
    iters, fallback = np.zeros(steps, int), np.zeros(steps, bool)
    status = []
    xs[0] = x_init
    d = np.zeros(rom.ND)
    for k in range(steps):
        t = k * period
        xm[k] = xs[k] + sim.noise_scale * _NOISE_STD * rng.standard_normal(rom.NX)
        if estimator is not None and k:
            d = estimator.update(xm[k - 1], us[k - 1], xm[k])
        known[k] = thrust_limits(af, sim, t, sim.known_delay_s)
        refs[k] = reference(t)
        res = nmpc.solve(xm[k], refs[k], known[k], d)
        us[k], dist[k], solve_ms[k], cost[k] = res.u, d, res.solve_ms, res.cost
        iters[k], fallback[k] = res.iterations, res.fallback
        status.append(res.status)
        u_plant = res.u.copy()
        delivered[k] = np.clip(res.u[rom.THRUST] * sim.mismatch.thrust_scale, 0.0, thrust_limits(af, sim, t))
        u_plant[rom.THRUST] = delivered[k]
        xs[k + 1] = np.asarray(plant(xs[k], u_plant, d_true)).ravel()
        nmpc.prepare(reference(t + period), known[k], d)          # the real-time iteration's preparation
        if kick_steps is not None and (k + 1) % kick_steps == 0:
            xs[k + 1, rom.V] += rng.uniform(-0.5, 0.5, 3)
            xs[k + 1, rom.RATES] += rng.uniform(-1.0, 1.0, 3)
    return SimLog(t_s=np.arange(steps) * period, x=xs, x_measured=xm, x_ref=refs, u=us,
                  thrust_delivered_n=delivered, thrust_max_known_n=known, disturbance=dist, solve_ms=solve_ms,
                  cost=cost, iterations=iters, fallback=fallback, status=tuple(status))


@dataclass(frozen=True)
class RotorLossFigures:
    max_tilt_deg: float             # largest |roll| or |pitch| after the fault
    settle_s: float                 # time after the fault until |roll|, |pitch| stay below tilt_deg
    max_altitude_error_m: float     # largest |altitude - reference| after the fault
    max_thrust_n: float             # largest delivered thrust after the fault
    final_yaw_rate_rad_s: float
    final_hip_deg: tuple[float, ...]


def rotor_loss_figures(log: SimLog, fault_at_s: float, tilt_deg: float = 10.0) -> RotorLossFigures:
    after = log.t_s >= fault_at_s
    x = log.x[:-1][after]
    tilt = np.degrees(np.max(np.abs(x[:, rom.EULER.start:rom.EULER.start + 2]), axis=1))
    t = log.t_s[after]
    over = np.flatnonzero(tilt >= tilt_deg)
    settle = 0.0 if over.size == 0 else float(t[over[-1]] + (t[1] - t[0]) - fault_at_s)
    alt_err = np.abs(x[:, rom.P.start + 2] - log.x_ref[after][:, 0, rom.P.start + 2])
    return RotorLossFigures(
        max_tilt_deg=float(tilt.max()), settle_s=settle, max_altitude_error_m=float(alt_err.max()),
        max_thrust_n=float(log.thrust_delivered_n[after].max()),
        final_yaw_rate_rad_s=float(log.x[-1, rom.RATES.start + 2]),
        final_hip_deg=tuple(float(v) for v in np.degrees(log.x[-1, rom.HIP])))
