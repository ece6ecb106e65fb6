"""Static thrust allocation over posture: why moving the legs matters after a rotor loss.

With one rotor off, the three live thrusts are fixed by hover alone (total force = weight,
no roll or pitch moment about the centre of mass); the posture decides how large they are
and how much yaw moment is left. This module evaluates that balance for many postures at
once (numpy, vectorised) and searches the posture that needs the smallest largest thrust.

As the figures of docs/airframe.md do, this static analysis lumps each whole leg at its
thruster; the reduced-order model and the plant spread it over three lumps, which moves the
centre of mass a little less (the best posture then needs about 1 % more thrust).
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import product

import numpy as np

from m4.airframe import ROTOR_COUNT, Airframe


@dataclass(frozen=True)
class Allocation:
    hip_rad: np.ndarray            # (4,)
    thrust_n: np.ndarray           # (4,), 0 on the failed rotor
    yaw_moment_n_m: float          # about body z (FRD), from the reaction moments

    @property
    def max_thrust_n(self) -> float:
        return float(self.thrust_n.max())


def hover_thrusts(af: Airframe, hip_rad, failed_index: int) -> np.ndarray:
    """Thrusts (K, 4) that hover the robot in postures hip_rad (K, 4) with rotor
    `failed_index` (0..3: rotor - 1) off. Negative entries mean the posture cannot hover."""
    q = np.atleast_2d(np.asarray(hip_rad, dtype=float))
    r = af.thruster_positions_frd_m(q)[..., :2]                        # (K, 4, 2)
    com = af.leg_mass_kg * r.sum(axis=1) / af.total_mass_kg          # (K, 2)
    live = [i for i in range(ROTOR_COUNT) if i != failed_index]
    arms = r[:, live, :] - com[:, None, :]                              # (K, 3, 2)
    a = np.stack([np.ones(arms.shape[:2]), arms[..., 1], arms[..., 0]], axis=1)  # rows: force, roll, pitch
    rhs = np.array([af.total_mass_kg * af.gravity_m_s2, 0.0, 0.0])
    thrust = np.zeros((q.shape[0], ROTOR_COUNT))
    thrust[:, live] = np.linalg.solve(a, np.broadcast_to(rhs, (q.shape[0], 3))[..., None])[..., 0]
    return thrust


def allocate(af: Airframe, hip_rad, failed_index: int) -> Allocation:
    """The hover balance for one posture with the rotor at `failed_index` (0..3) off."""
    q = np.asarray(hip_rad, dtype=float)
    thrust = hover_thrusts(af, q[None, :], failed_index)[0]
    yaw = af.moment_coefficient_m * float(np.dot(af.spin_sign, thrust))
    return Allocation(hip_rad=q, thrust_n=thrust, yaw_moment_n_m=yaw)


def admissible(af: Airframe, hip_rad: np.ndarray) -> np.ndarray:
    """(K,) mask of postures within the hip range and the same-side sum limit."""
    q = np.atleast_2d(hip_rad)
    ok = np.all((q >= af.hip_min_rad - 1e-9) & (q <= af.hip_max_rad + 1e-9), axis=1)
    for side in af.same_side_pairs:
        ok &= q[:, list(side)].sum(axis=1) <= af.same_side_sum_max_rad + 1e-9
    return ok


def best_posture(af: Airframe, failed_index: int, grid_step_deg: float = 3.0) -> Allocation:
    """The admissible posture that hovers with the smallest largest thrust (rotor off).

    A grid over the four hip angles, then a pattern search that halves its step around the
    best point until it is below 0.01 deg.
    """
    def score(q: np.ndarray) -> np.ndarray:
        t = hover_thrusts(af, q, failed_index)
        s = t.max(axis=1)
        s[(t.min(axis=1) < -1e-9) | ~admissible(af, q)] = np.inf
        return s

    axis = np.arange(af.hip_min_rad, af.hip_max_rad + 1e-9, np.radians(grid_step_deg))
    grid = np.array(list(product(axis, repeat=ROTOR_COUNT)))
    scores = score(grid)
    best = grid[np.argmin(scores)]
    step = np.radians(grid_step_deg)
    moves = np.array([m for m in product((-1, 0, 1), repeat=ROTOR_COUNT) if any(m)], dtype=float)
    while step > np.radians(0.01):
        candidates = np.clip(best + step * moves, af.hip_min_rad, af.hip_max_rad)
        cand_scores = score(candidates)
        if cand_scores.min() < score(best[None, :])[0] - 1e-12:
            best = candidates[np.argmin(cand_scores)]
        else:
            step /= 2
    return allocate(af, best, failed_index)
