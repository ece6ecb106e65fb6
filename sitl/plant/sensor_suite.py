"""The raw sensors of a `[sensors] profile` other than "ideal" (figures: m4/sensor_profiles.py).

The plant calls `sample()` at every IMU instant with its true state; the flight controller
takes what it has heard with `take()`, in the order it was heard. The IMU reads the hull
centre (where PlantState's position is): its accelerometer the specific force over the last
IMU period (the change of velocity, as a delta-velocity IMU integrates it), its gyro the body
rates, each with white noise at the datasheet's density, a bias that starts at the boot
calibration's residue and walks, and the range's saturation. The accelerometer also feels
each rotor's imbalance (vibration at the rotor's speed, larger with a damaged propeller). The
barometer reads the height with noise and a drifting offset, the compass the earth's field in
the body; GNSS (position and velocity) or motion capture (position and heading) measure at
their rate and are heard their delay later.

Noise is a function of the seed and the sample's instant only (a generator seeded with both,
as sitl/plant/sensors.py); the biases and the rotor phases are states advanced at every IMU
instant, which come on a fixed grid whatever lengths the plant is stepped by.
"""

from __future__ import annotations

import collections
import math

import numpy as np

from m4.airframe import ROTOR_COUNT
from m4.attitude import euler_from_quat_wxyz, rotation_ned_from_quat_wxyz
from m4.fault_kind import FaultKind
from m4.sensor_profiles import SensorProfile
from sitl.plant.state import BaroSample, CompassSample, FixSample, ImuSample, SensorSample

_STREAM = 18                  # keeps these draws apart from sitl/plant/sensors.py's (seed, instant)
_IMU, _BARO, _COMPASS, _FIX, _TURN_ON = range(5)


class SensorSuite:
    def __init__(self, profile: SensorProfile, *, seed: int, mass_kg: float, gravity_m_s2: float,
                 turn_sense_frd_z: np.ndarray, start_vel_ned_m_s: np.ndarray):
        self.profile = profile
        imu = profile.imu
        self.period_ms = imu.period_ms
        self._seed = seed
        self._gravity_ned = np.array([0.0, 0.0, gravity_m_s2])
        self._mass_kg = mass_kg
        self._turn = np.asarray(turn_sense_frd_z, dtype=float)   # +1: a rotor turns about +z (FRD)
        turn_on = np.random.default_rng((seed, _STREAM, _TURN_ON))
        self.gyro_bias_rad_s = turn_on.normal(0.0, imu.gyro_bias_turn_on_rad_s, 3)
        self.accel_bias_m_s2 = turn_on.normal(0.0, imu.accel_bias_turn_on_m_s2, 3)
        self.baro_offset_m = 0.0
        self._rotor_phase_rad = turn_on.uniform(0.0, 2 * math.pi, ROTOR_COUNT)
        self._vel_prev = np.array(start_vel_ned_m_s, dtype=float)
        self._heard: list[SensorSample] = []
        self._delayed: collections.deque[FixSample] = collections.deque()

    def _rng(self, kind: int, time_ms: int) -> np.random.Generator:
        return np.random.default_rng((self._seed, _STREAM, kind, time_ms))

    def sample(self, time_ms: int, pos_ned_m, vel_ned_m_s, quat_wxyz, rates_frd_rad_s,
               rotor_speed_rad_s, fault_kind, fault_loss) -> None:
        """The sensors at an IMU instant (time_ms a multiple of the IMU period), from the truth."""
        p, t_s = self.profile, time_ms / 1000.0
        r = rotation_ned_from_quat_wxyz(quat_wxyz)
        self._imu(time_ms, r, np.asarray(vel_ned_m_s), np.asarray(rates_frd_rad_s),
                  np.asarray(rotor_speed_rad_s), fault_kind, fault_loss)
        if p.baro is not None and time_ms % p.baro.period_ms == 0:
            rng, b = self._rng(_BARO, time_ms), p.baro
            self.baro_offset_m += rng.normal(0.0, b.drift_m_rths * math.sqrt(b.period_ms / 1000.0))
            self._heard.append(BaroSample(t_s, -float(pos_ned_m[2]) + self.baro_offset_m + rng.normal(0.0, b.noise_m)))
        if p.compass is not None and time_ms % p.compass.period_ms == 0:
            c = p.compass
            field = r.T @ np.array(c.field_ned) + self._rng(_COMPASS, time_ms).normal(0.0, c.noise, 3)
            self._heard.append(CompassSample(t_s, field))
        if time_ms % p.fix.period_ms == 0:
            self._delayed.append(self._fix(time_ms, np.asarray(pos_ned_m), np.asarray(vel_ned_m_s), quat_wxyz))

    def _imu(self, time_ms: int, r, vel_ned_m_s, rates_frd_rad_s, rotor_speed_rad_s, fault_kind, fault_loss) -> None:
        imu, dt_s = self.profile.imu, self.period_ms / 1000.0
        n = self._rng(_IMU, time_ms).normal(0.0, 1.0, 12)
        root_rate = math.sqrt(1.0 / dt_s)
        self.gyro_bias_rad_s = self.gyro_bias_rad_s + imu.gyro_bias_walk_rad_s2_rthz * math.sqrt(dt_s) * n[6:9]
        self.accel_bias_m_s2 = self.accel_bias_m_s2 + imu.accel_bias_walk_m_s3_rthz * math.sqrt(dt_s) * n[9:12]
        gyro = rates_frd_rad_s + self.gyro_bias_rad_s + imu.gyro_noise_density_rad_s_rthz * root_rate * n[0:3]
        accel_ned = (vel_ned_m_s - self._vel_prev) / dt_s
        self._vel_prev = vel_ned_m_s.copy()
        accel = (r.T @ (accel_ned - self._gravity_ned) + self._vibration_frd_m_s2(rotor_speed_rad_s, fault_kind,
                                                                                   fault_loss, dt_s)
                 + self.accel_bias_m_s2 + imu.accel_noise_density_m_s2_rthz * root_rate * n[3:6])
        self._heard.append(ImuSample(time_ms / 1000.0, np.clip(gyro, -imu.gyro_range_rad_s, imu.gyro_range_rad_s),
                                     np.clip(accel, -imu.accel_range_m_s2, imu.accel_range_m_s2)))

    def imbalance_kg_m(self, fault_kind, fault_loss) -> np.ndarray:
        """Each rotor's imbalance: the residue of a balanced propeller, plus the part of a blade
        a damaged propeller lost (in proportion to the thrust lost), or a lost propeller's hub."""
        imu = self.profile.imu
        kind = np.asarray(fault_kind)
        return (imu.imbalance_kg_m + np.where(kind == FaultKind.DAMAGE, np.asarray(fault_loss) * imu.blade_moment_kg_m, 0.0)
                + np.where(kind == FaultKind.PROPELLER, imu.hub_imbalance_kg_m, 0.0))

    def _vibration_frd_m_s2(self, rotor_speed_rad_s, fault_kind, fault_loss, dt_s: float) -> np.ndarray:
        """The rotors' imbalance forces on the robot, turning in the rotor plane (taken as the
        body's x-y plane) at each rotor's speed and in its sense of rotation."""
        self._rotor_phase_rad = (self._rotor_phase_rad + rotor_speed_rad_s * dt_s) % (2 * math.pi)
        amp = self.imbalance_kg_m(fault_kind, fault_loss) * rotor_speed_rad_s ** 2 / self._mass_kg
        phase = self._rotor_phase_rad
        return np.array([float(amp @ np.cos(phase)), float(amp @ (self._turn * np.sin(phase))), 0.0])

    def _fix(self, time_ms: int, pos_ned_m, vel_ned_m_s, quat_wxyz) -> FixSample:
        f = self.profile.fix
        n = self._rng(_FIX, time_ms).normal(0.0, 1.0, 7)
        pos = pos_ned_m + np.array([f.pos_noise_ne_m, f.pos_noise_ne_m, f.pos_noise_d_m]) * n[0:3]
        vel = None if f.vel_noise_m_s is None else vel_ned_m_s + f.vel_noise_m_s * n[3:6]
        yaw = None
        if f.yaw_noise_rad is not None:
            yaw = float(euler_from_quat_wxyz(quat_wxyz)[2]) + f.yaw_noise_rad * float(n[6])
            yaw = (yaw + math.pi) % (2 * math.pi) - math.pi
        return FixSample((time_ms + f.delay_ms) / 1000.0, pos, vel, yaw)

    def take(self, time_ms: int) -> list[SensorSample]:
        """What the FC has heard up to time_ms, in the order heard (at one instant the IMU first)."""
        heard, self._heard = self._heard, []
        limit_s = time_ms / 1000.0 + 1e-9
        while self._delayed and self._delayed[0].time_s <= limit_s:
            heard.append(self._delayed.popleft())
        heard.sort(key=lambda s: (s.time_s, not isinstance(s, ImuSample)))
        return heard
