"""The FC's failsafe on three rotors: a posture that puts the centre of mass inside the
triangle of the live rotors, and a thrust-axis controller that ignores yaw.

With one rotor gone a multirotor keeps three controllable axes: collective thrust and the
roll and pitch moments. Yaw is let go: the vehicle spins up under the live rotors' drag
moments, so the attitude loop works on the thrust axis alone (the body z axis against the
one the position loop asks for, as in Mueller and D'Andrea's reduced-attitude control), in
the body frame, with the gyroscopic term of the spin cancelled. The legs move to the posture
that minimises the largest rotor thrust in a level hover (`three_rotor_posture`, a grid
search over the hip range within the same-side limit), and each tick the allocation uses the
hips as measured, so it stays right while the legs travel.
"""

from __future__ import annotations

import functools
import itertools
import math

import numpy as np

from m4.airframe import ROTOR_COUNT, Airframe
from m4.attitude import rotation_ned_from_frd

POSTURE_GRID = 9                  # hip angles tried per leg
MAX_TILT_RAD = math.radians(25.0)


def _arms_frd_m(af: Airframe, hip_rad: np.ndarray) -> np.ndarray:
    """(..., 4, 3) thruster positions relative to the centre of mass, for hips (..., 4)."""
    hubs = af.thruster_positions_frd_m(hip_rad)
    hips = np.array(af.hip_frd_m)
    com = (af.leg_mass_kg * hips.sum(axis=0) + af.leg_swing_mass_kg * (hubs - hips).sum(axis=-2)) / af.total_mass_kg
    return hubs - com[..., None, :]


def _allocation(arms_frd_m: np.ndarray, live: list[int]) -> np.ndarray:
    """(..., 3, 3): (collective, roll, pitch) from the live rotors' thrusts."""
    r = arms_frd_m[..., live, :]
    return np.stack([np.ones(r.shape[:-1]), -r[..., 1], r[..., 0]], axis=-2)


@functools.lru_cache(maxsize=8)
def three_rotor_posture(af: Airframe, dead: int) -> np.ndarray:
    """The hips (4,) that minimise the largest live thrust of a level hover with rotor `dead`
    (1..4) off."""
    live = [i for i in range(ROTOR_COUNT) if i != dead - 1]
    grid = np.linspace(af.hip_min_rad, af.hip_max_rad, POSTURE_GRID)
    hips = np.array(list(itertools.product(grid, repeat=ROTOR_COUNT)))
    right, left = af.same_side_pairs
    ok = ((hips[:, list(right)].sum(axis=1) <= af.same_side_sum_max_rad + 1e-9)
          & (hips[:, list(left)].sum(axis=1) <= af.same_side_sum_max_rad + 1e-9))
    hips = hips[ok]
    a = _allocation(_arms_frd_m(af, hips), live)
    weight = np.array([af.total_mass_kg * af.gravity_m_s2, 0.0, 0.0])
    feasible = np.abs(np.linalg.det(a)) > 1e-6
    thrust = np.full((len(hips), 3), np.inf)
    thrust[feasible] = np.linalg.solve(a[feasible], np.broadcast_to(weight, (feasible.sum(), 3))[..., None])[..., 0]
    cost = np.where(np.all(thrust >= 0.0, axis=1), thrust.max(axis=1), np.inf)
    return hips[int(np.argmin(cost))]


class ThreeRotorController:
    """Thrusts (4,) for a desired acceleration (NED) with rotor `dead` off, yaw let go."""

    def __init__(self, airframe: Airframe, dead: int, inertia_diag_kg_m2: np.ndarray,
                 att_rad_s: float, damping: float):
        self.af = airframe
        self.dead = dead
        self.live = [i for i in range(ROTOR_COUNT) if i != dead - 1]
        self.hip_rad = three_rotor_posture(airframe, dead)
        self.inertia = np.asarray(inertia_diag_kg_m2, dtype=float)
        self.att_rad_s = att_rad_s
        self.damping = damping

    def thrust_n(self, state, accel_ned_m_s2: np.ndarray) -> np.ndarray:
        af = self.af
        force = af.total_mass_kg * (np.asarray(accel_ned_m_s2, dtype=float) - np.array([0.0, 0.0, af.gravity_m_s2]))
        axis_goal = -force / np.linalg.norm(force)              # body z (down) the force asks for
        if math.acos(np.clip(axis_goal[2], -1.0, 1.0)) > MAX_TILT_RAD:
            horizontal = axis_goal[:2] / max(np.linalg.norm(axis_goal[:2]), 1e-9)
            axis_goal = np.array([*(math.sin(MAX_TILT_RAD) * horizontal), math.cos(MAX_TILT_RAD)])
        rot = rotation_ned_from_frd(state.euler_rad)
        axis = rot[:, 2]
        error_frd = rot.T @ np.cross(axis, axis_goal)           # small rotation taking the axis to its goal
        w, rates = self.att_rad_s, np.asarray(state.rates_frd_rad_s, dtype=float)
        gyro = np.cross(rates, self.inertia * rates)
        moments = self.inertia[:2] * (w * w * error_frd[:2] - 2.0 * self.damping * w * rates[:2]) + gyro[:2]
        collective = max(float(-force @ axis), 0.2 * af.total_mass_kg * af.gravity_m_s2)
        a = _allocation(_arms_frd_m(af, np.asarray(state.hip_rad, dtype=float)), self.live)
        thrust = np.zeros(ROTOR_COUNT)
        thrust[self.live] = np.linalg.solve(a, np.array([collective, *moments]))
        return np.clip(thrust, af.thrust_min_n, af.thrust_max_n) * (np.arange(ROTOR_COUNT) != self.dead - 1)
