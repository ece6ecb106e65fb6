"""The air the robot flies in: a scenario's [wind] as the air's velocity over the ground, NED.

    wind(t) = mean + turbulence(t) + sum of the gusts(t)

- Mean: constant, as the scenario gives it (no shear: the robot stays within metres of its
  start height).
- Turbulence: Dryden, MIL-HDBK-1797's low-altitude form. Intensities from the wind at 20 ft
  (6 m), W20 = 15 / 30 / 45 kt for light / moderate / severe, whatever the mean wind the
  scenario gives (the handbook's levels; they are not scaled by the mean):
      sigma_w = 0.1 W20,  sigma_u = sigma_v = sigma_w / (0.177 + 0.000823 h)^0.4
      L_u = 2 L_v = h / (0.177 + 0.000823 h)^1.2,  2 L_w = h          (h in ft)
  at h the start height, floored at 10 ft (the form is not meant for the ground itself). The
  spatial field is frozen and carried past the robot at the mean wind's horizontal speed, at
  least MIN_CONVECTION_M_S (a hovering robot meets the turbulence the wind brings): each
  component is white noise through its Dryden filter with time constant T = L / V,
      u: 1 / (1 + T s),      v, w: (1 + sqrt(3) T s) / (1 + T s)^2,
  u along the mean wind's horizontal direction (north in calm air), v across it (to its
  right), w down. The filters are stepped on a fixed grid of STEP_S with the noise held over
  each step, and scaled so that each component's stationary standard deviation is exactly its
  sigma. The noise comes from the flight's seed: the same seed gives the same air.
- Gusts: discrete 1-cosine gusts, peak x (1 - cos(2 pi (t - at) / duration)) / 2 for
  at <= t <= at + duration: the whole gust rises to its peak at mid-duration and dies away
  (MIL-F-8785C's discrete gust, rise and fall).
"""

from __future__ import annotations

import math

import numpy as np

from m4.scenario import Gust, Wind

KNOT_M_S = 0.514444
FOOT_M = 0.3048
W20_KT = {"light": 15.0, "moderate": 30.0, "severe": 45.0}
MIN_HEIGHT_FT = 10.0
MIN_CONVECTION_M_S = 1.0
STEP_S = 0.005
_SEED_STREAM = 0x57494E44            # "WIND": the wind's random stream, apart from the sensors' on the same seed


def dryden_low_altitude(level: str, height_m: float) -> tuple[np.ndarray, np.ndarray]:
    """(sigma_uvw m/s, length_uvw m) of MIL-HDBK-1797's low-altitude Dryden form."""
    h = max(height_m / FOOT_M, MIN_HEIGHT_FT)
    k = 0.177 + 0.000823 * h
    sigma_w = 0.1 * W20_KT[level] * KNOT_M_S
    sigma_uv = sigma_w / k ** 0.4
    length_u_ft = h / k ** 1.2
    return (np.array([sigma_uv, sigma_uv, sigma_w]),
            np.array([length_u_ft, length_u_ft / 2.0, h / 2.0]) * FOOT_M)


def gust_ned_m_s(gusts: tuple[Gust, ...], time_s: float) -> np.ndarray:
    """Every 1-cosine gust's contribution at time_s, NED."""
    total = np.zeros(3)
    for g in gusts:
        x = (time_s - g.at_s) / g.duration_s
        if 0.0 <= x <= 1.0:
            total += 0.5 * (1.0 - math.cos(2.0 * math.pi * x)) * np.asarray(g.peak_ned_m_s)
    return total


class _DrydenAxis:
    """One component: z <- a z + (1 - a) n, g <- a g + (1 - a) z (two lags of time constant T on
    the held noise n), out = gain (c_z z + c_g g): c = (1, 0) for u's 1 / (1 + T s), and
    (sqrt 3, 1 - sqrt 3) for (1 + sqrt(3) T s) / (1 + T s)^2 = sqrt 3 / (1 + T s) + (1 - sqrt 3) /
    (1 + T s)^2. The gain makes the stationary standard deviation sigma (discrete Lyapunov)."""

    def __init__(self, sigma_m_s: float, time_constant_s: float, second_order: bool, dt_s: float):
        a = math.exp(-dt_s / time_constant_s)
        self._a = np.array([[a, 0.0], [1.0 - a, a]])
        self._b = np.array([1.0 - a, 0.0])
        c = np.array([math.sqrt(3.0), 1.0 - math.sqrt(3.0)]) if second_order else np.array([1.0, 0.0])
        # P = A P A^T + b b^T, solved as vec(P) = (I - A kron A)^-1 vec(b b^T)
        p = np.linalg.solve(np.eye(4) - np.kron(self._a, self._a), np.outer(self._b, self._b).ravel()).reshape(2, 2)
        self._c = c * sigma_m_s / math.sqrt(float(c @ p @ c))
        self._stationary = np.linalg.cholesky(p)
        self._x = np.zeros(2)

    def start(self, rng: np.random.Generator) -> None:
        """Draw the state from its stationary distribution, so the air is turbulent from t = 0."""
        self._x = self._stationary @ rng.standard_normal(2)

    def step(self, noise: float) -> None:
        self._x = self._a @ self._x + self._b * noise

    @property
    def value_m_s(self) -> float:
        return float(self._c @ self._x)


class WindField:
    """The air's velocity over the ground at the robot, NED: velocity_ned_m_s(time_s), for times
    that never go back (the turbulence is stepped forward on its own fixed grid)."""

    def __init__(self, wind: Wind, height_m: float, seed: int = 0, step_s: float = STEP_S):
        self.wind = wind
        self._mean = np.asarray(wind.mean_ned_m_s, dtype=float)
        self._step_s = step_s
        self._steps = 0
        self._axes: list[_DrydenAxis] = []
        self.sigma_m_s = np.zeros(3)
        if wind.turbulence != "none":
            self.sigma_m_s, length_m = dryden_low_altitude(wind.turbulence, height_m)
            speed_m_s = max(math.hypot(self._mean[0], self._mean[1]), MIN_CONVECTION_M_S)
            self._axes = [_DrydenAxis(s, length / speed_m_s, i > 0, step_s)
                          for i, (s, length) in enumerate(zip(self.sigma_m_s, length_m))]
            self._rng = np.random.default_rng([seed, _SEED_STREAM])
            for axis in self._axes:
                axis.start(self._rng)
        heading = math.atan2(self._mean[1], self._mean[0])          # calm air: north
        c, s = math.cos(heading), math.sin(heading)
        self._ned_from_uvw = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])

    def turbulence_ned_m_s(self, time_s: float) -> np.ndarray:
        if not self._axes:
            return np.zeros(3)
        target = math.floor(time_s / self._step_s + 1e-9)
        while self._steps < target:
            for axis, noise in zip(self._axes, self._rng.standard_normal(3)):
                axis.step(float(noise))
            self._steps += 1
        return self._ned_from_uvw @ np.array([axis.value_m_s for axis in self._axes])

    def velocity_ned_m_s(self, time_s: float) -> np.ndarray:
        return self._mean + self.turbulence_ned_m_s(time_s) + gust_ned_m_s(self.wind.gusts, time_s)
