"""Sensor noise on the measured state: white, Gaussian, seeded, sized by the airframe's [sensors].

The noise of a sample is a function of the seed and the sample's simulated instant only (a
generator seeded with both), not of how many samples were drawn before: the flight
controller may measure an instant more than once, or measure extra instants when a command
or a resent frame arrives at a wall-clock-dependent moment, and the same seed must still
give the same flight.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from m4.airframe import ROTOR_COUNT, Airframe
from m4.attitude import quat_wxyz_from_euler
from sitl.plant.state import PlantState


class SensorNoise:
    def __init__(self, af: Airframe, seed: int):
        self._af = af
        self._seed = seed
        self._last: tuple[float, _Noise] | None = None     # the last instant's draw: the gyro and the state share it

    def measure(self, truth: PlantState) -> PlantState:
        """The truth plus noise on position, velocity, attitude (through the Euler angles, the
        quaternion rebuilt from them), body rates, hip angles and hip rates (the gyro's noise).
        Thrusts, the centre of mass and the ground flag are not measured quantities: kept."""
        n = self._draw(truth.time_s)
        euler = truth.euler_rad + n.euler_rad
        euler[2] = (euler[2] + np.pi) % (2 * np.pi) - np.pi
        return dataclasses.replace(
            truth,
            pos_ned_m=truth.pos_ned_m + n.pos_ned_m,
            vel_ned_m_s=truth.vel_ned_m_s + n.vel_ned_m_s,
            euler_rad=euler,
            quat_wxyz=quat_wxyz_from_euler(euler),
            rates_frd_rad_s=truth.rates_frd_rad_s + n.rates_frd_rad_s,
            hip_rad=truth.hip_rad + n.hip_rad,
            hip_rate_rad_s=truth.hip_rate_rad_s + n.hip_rate_rad_s,
        )

    def measure_rates(self, time_s: float, rates_frd_rad_s: np.ndarray) -> np.ndarray:
        """The gyro alone: what measure() gives as rates_frd_rad_s at the instant time_s."""
        return rates_frd_rad_s + self._draw(time_s).rates_frd_rad_s

    def _draw(self, time_s: float) -> "_Noise":
        """The instant's noise (a generator seeded for it costs more than its draws: built once an instant)."""
        if self._last is None or self._last[0] != time_s:
            self._last = (time_s, self._new_draw(time_s))
        return self._last[1]

    def _new_draw(self, time_s: float) -> "_Noise":
        af, rng = self._af, np.random.default_rng((self._seed, round(time_s * 1e6)))
        return _Noise(euler_rad=rng.normal(0.0, af.attitude_noise_rad, 3),
                      pos_ned_m=rng.normal(0.0, af.position_noise_m, 3),
                      vel_ned_m_s=rng.normal(0.0, af.velocity_noise_m_s, 3),
                      rates_frd_rad_s=rng.normal(0.0, af.rate_noise_rad_s, 3),
                      hip_rad=rng.normal(0.0, af.hip_noise_rad, ROTOR_COUNT),
                      hip_rate_rad_s=rng.normal(0.0, af.rate_noise_rad_s, ROTOR_COUNT))


@dataclasses.dataclass(frozen=True)
class _Noise:
    """One instant's noise, drawn in this order from the instant's generator."""
    euler_rad: np.ndarray
    pos_ned_m: np.ndarray
    vel_ned_m_s: np.ndarray
    rates_frd_rad_s: np.ndarray
    hip_rad: np.ndarray
    hip_rate_rad_s: np.ndarray
