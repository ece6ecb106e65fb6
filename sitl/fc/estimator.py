"""The flight controller's state estimate from its raw sensors (profiles "mocap" and "gps").

Two filters of the kinds flight controllers run, on the samples of sitl/plant/state.py:

- Attitude: a nonlinear complementary filter (Mahony et al. 2008) as PX4's
  attitude_estimator_q runs it: the gyro integrated, corrected towards the accelerometer's
  "up" (the accelerometer low-passed at ArduPilot's INS_ACCEL_FILTER, 20 Hz, against the
  rotors' vibration) and towards a heading (compass, or motion capture's yaw compared with
  the estimate at the instant it was measured), with PX4's weights (ATT_W_ACC 0.2,
  ATT_W_MAG / ATT_W_EXT_HDG 0.1, ATT_W_GYRO_BIAS 0.1) and gyro bias estimate (clamped at
  PX4's 0.05 rad/s).
- Position and velocity: a linear Kalman filter, the accelerometer rotated into NED as its
  input and its bias in NED as a state (it holds both the accelerometer's bias and what the
  attitude's tilt error makes of gravity, as EKF3's delta-velocity bias does), on a delayed fusion horizon as PX4's EKF2 and ArduPilot's EKF3 run theirs: it lags
  the present by the position source's delay, so a GNSS or motion-capture fix and the
  barometer are fused at the instant they were measured, and the present is predicted from
  the horizon with the IMU samples since (exact for a linear filter: the IMU's own
  integration is kept, and the horizon's correction is carried to the present).

The estimate starts where the scenario starts (at rest at its start position and heading,
as a flight controller aligned on the ground); the biases start unknown (zero).
"""

from __future__ import annotations

import collections
import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from m4.attitude import euler_from_quat_wxyz, rotation_ned_from_quat_wxyz
from m4.sensor_profiles import SensorProfile
from sitl.plant.state import BaroSample, CompassSample, FixSample, ImuSample, PlantState, SensorSample

W_ACC = 0.2                   # PX4 ATT_W_ACC
W_HEADING = 0.1               # PX4 ATT_W_MAG, ATT_W_EXT_HDG
W_GYRO_BIAS = 0.1             # PX4 ATT_W_GYRO_BIAS
GYRO_BIAS_MAX_RAD_S = 0.05    # PX4 attitude_estimator_q's clamp
ACCEL_FILTER_HZ = 20.0        # ArduPilot INS_ACCEL_FILTER
ACCEL_PROCESS_NOISE_M_S2 = 0.35   # ArduPilot EK3_ACC_P_NSE: the accelerometer as the filter's input
ACCEL_BIAS_WALK_M_S3 = 0.02       # how fast the NED accelerometer bias may move: a tilt error changes as the robot turns
START_ACCEL_BIAS_M_S2 = 0.2
START_SIGMA_M = 0.1


def _wrap(angle_rad: float) -> float:
    return (angle_rad + math.pi) % (2 * math.pi) - math.pi


def _rotate(q: np.ndarray, rot_vec: np.ndarray, world: bool) -> np.ndarray:
    """q turned by the rotation vector rot_vec (rad), in the world frame or the body's."""
    angle = float(np.linalg.norm(rot_vec))
    if angle == 0.0:
        return q
    s = math.sin(angle / 2) / angle
    dq = np.array([math.cos(angle / 2), *(s * rot_vec)])
    a, b = (dq, q) if world else (q, dq)
    out = np.array([a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3],
                    a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2],
                    a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1],
                    a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0]])
    return out / np.linalg.norm(out)


@dataclass
class _Instant:
    """One IMU instant in the buffer between the fusion horizon and the present."""
    time_s: float
    accel_ned_m_s2: np.ndarray
    dt_s: float
    open_pos_m: np.ndarray        # the IMU alone, integrated from the start
    open_vel_m_s: np.ndarray
    yaw_rad: float                # the attitude filter's heading then


class Estimator:
    def __init__(self, profile: SensorProfile, gravity_m_s2: float, start_ned_m, start_yaw_rad: float):
        self.profile = profile
        self._gravity_ned = np.array([0.0, 0.0, gravity_m_s2])
        self._delay_s = profile.fix.delay_ms / 1000.0
        self.quat_wxyz = np.array([math.cos(start_yaw_rad / 2), 0.0, 0.0, math.sin(start_yaw_rad / 2)])
        self.gyro_bias_rad_s = np.zeros(3)
        self.rates_frd_rad_s = np.zeros(3)
        self._accel_frd = np.array([0.0, 0.0, -gravity_m_s2])
        self._x = np.concatenate([np.asarray(start_ned_m, dtype=float), np.zeros(6)])  # p, v, accel bias: the horizon's
        self._p = np.diag([START_SIGMA_M ** 2] * 6 + [START_ACCEL_BIAS_M_S2 ** 2] * 3)
        self._model: dict[float, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
        self._buffer = collections.deque([_Instant(0.0, np.zeros(3), 0.0, np.zeros(3), np.zeros(3), start_yaw_rad)])
        self._pending: list[BaroSample | FixSample] = []
        field = profile.compass.field_ned if profile.compass is not None else (1.0, 0.0, 0.0)
        self._declination_rad = math.atan2(field[1], field[0])

    # -- the present ---------------------------------------------------------------------------
    @property
    def pos_ned_m(self) -> np.ndarray:
        return self._present()[:3]

    @property
    def vel_ned_m_s(self) -> np.ndarray:
        return self._present()[3:]

    def _present(self) -> np.ndarray:
        h, now = self._buffer[0], self._buffer[-1]
        span_s = now.time_s - h.time_s
        vel, bias = self._x[3:6], self._x[6:]
        pos = (self._x[:3] + vel * span_s + (now.open_pos_m - h.open_pos_m - h.open_vel_m_s * span_s)
               - 0.5 * bias * span_s * span_s)
        return np.concatenate([pos, vel + now.open_vel_m_s - h.open_vel_m_s - bias * span_s])

    def report(self, measured: PlantState) -> PlantState:
        """The measured state with the estimate's attitude, rates, position and velocity."""
        present = self._present()
        return dataclasses.replace(measured, pos_ned_m=present[:3], vel_ned_m_s=present[3:],
                                   quat_wxyz=self.quat_wxyz.copy(), euler_rad=euler_from_quat_wxyz(self.quat_wxyz),
                                   rates_frd_rad_s=self.rates_frd_rad_s.copy())

    # -- samples -------------------------------------------------------------------------------
    def feed(self, samples: list[SensorSample]) -> None:
        for s in samples:
            if isinstance(s, ImuSample):
                self._imu(s)
            elif isinstance(s, CompassSample):
                self._compass(s)
            elif isinstance(s, FixSample):
                if s.yaw_rad is not None:
                    self._external_heading(s)
                self._pending.append(s)
            else:
                self._pending.append(s)
        self._fuse_due()

    def _imu(self, s: ImuSample) -> None:
        last = self._buffer[-1]
        dt = s.time_s - last.time_s
        alpha = dt / (dt + 1.0 / (2 * math.pi * ACCEL_FILTER_HZ))
        self._accel_frd = self._accel_frd + alpha * (s.accel_frd_m_s2 - self._accel_frd)
        r = rotation_ned_from_quat_wxyz(self.quat_wxyz)
        correction = np.zeros(3)
        norm = float(np.linalg.norm(self._accel_frd))
        if norm > 0.0:
            up_frd = r[2] * -1.0                 # R^T (0, 0, -1): "up" as the body sees it
            correction = W_ACC * np.cross(self._accel_frd / norm, up_frd)
        self.gyro_bias_rad_s = np.clip(self.gyro_bias_rad_s - W_GYRO_BIAS * correction * dt,
                                       -GYRO_BIAS_MAX_RAD_S, GYRO_BIAS_MAX_RAD_S)
        self.rates_frd_rad_s = s.gyro_frd_rad_s - self.gyro_bias_rad_s
        self.quat_wxyz = _rotate(self.quat_wxyz, (self.rates_frd_rad_s + correction) * dt, world=False)
        accel_ned = rotation_ned_from_quat_wxyz(self.quat_wxyz) @ self._accel_frd + self._gravity_ned
        vel = last.open_vel_m_s + accel_ned * dt
        pos = last.open_pos_m + last.open_vel_m_s * dt + 0.5 * accel_ned * dt * dt
        self._buffer.append(_Instant(s.time_s, accel_ned, dt, pos, vel, float(euler_from_quat_wxyz(self.quat_wxyz)[2])))
        while len(self._buffer) > 1 and self._buffer[1].time_s <= s.time_s - self._delay_s + 1e-9:
            self._buffer.popleft()
            self._predict(self._buffer[0])
            self._fuse_due()

    def _turn_heading(self, error_rad: float, period_ms: int) -> None:
        """Turn the attitude about the vertical towards a measured heading, and learn the
        gyro bias from it, as the filter's heading weight over the sensor's period."""
        turn_ned = np.array([0.0, 0.0, W_HEADING * error_rad])
        turn_frd = rotation_ned_from_quat_wxyz(self.quat_wxyz).T @ turn_ned
        period_s = period_ms / 1000.0
        self.gyro_bias_rad_s = np.clip(self.gyro_bias_rad_s - W_GYRO_BIAS * turn_frd * period_s,
                                       -GYRO_BIAS_MAX_RAD_S, GYRO_BIAS_MAX_RAD_S)
        self.quat_wxyz = _rotate(self.quat_wxyz, turn_ned * period_s, world=True)

    def _compass(self, s: CompassSample) -> None:
        field_ned = rotation_ned_from_quat_wxyz(self.quat_wxyz) @ s.field_frd
        heading = math.atan2(field_ned[1], field_ned[0])
        self._turn_heading(_wrap(self._declination_rad - heading), self.profile.compass.period_ms)

    def _external_heading(self, s: FixSample) -> None:
        measured_at = s.time_s - self._delay_s
        then = next((i for i in reversed(self._buffer) if i.time_s <= measured_at + 1e-9), self._buffer[0])
        self._turn_heading(_wrap(s.yaw_rad - then.yaw_rad), self.profile.fix.period_ms)

    # -- the horizon's Kalman filter -----------------------------------------------------------
    def _transition(self, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(F, B, Q) of one IMU period: x' = F x + B a for the state (p, v, bias), Q its noise."""
        if dt not in self._model:
            eye = np.eye(3)
            b = np.vstack([0.5 * dt * dt * eye, dt * eye, 0.0 * eye])
            f = np.eye(9)
            f[:3, 3:6], f[:6, 6:] = dt * eye, -b[:6]
            q = ACCEL_PROCESS_NOISE_M_S2 ** 2 * (b @ b.T)
            q[6:, 6:] += ACCEL_BIAS_WALK_M_S3 ** 2 * dt * eye
            self._model[dt] = f, b, q
        return self._model[dt]

    def _predict(self, i: _Instant) -> None:
        f, b, q = self._transition(i.dt_s)
        self._x = f @ self._x + b @ i.accel_ned_m_s2
        self._p = f @ self._p @ f.T + q

    def _fuse_due(self) -> None:
        horizon_s = self._buffer[0].time_s
        due = [m for m in self._pending if self._measured_at(m) <= horizon_s + 1e-9]
        if due:
            self._pending = [m for m in self._pending if m not in due]
            for m in due:
                self._fuse(m)

    def _measured_at(self, m: BaroSample | FixSample) -> float:
        return m.time_s - self._delay_s if isinstance(m, FixSample) else m.time_s

    def _fuse(self, m: BaroSample | FixSample) -> None:
        if isinstance(m, BaroSample):
            self._update(-np.eye(9)[2:3], np.array([m.height_m]), [self.profile.baro.noise_m])
            return
        f = self.profile.fix
        rows, z, sigma = [], [], []
        for axis in range(3):
            if self.profile.baro is None or axis < 2:       # with a barometer, height from it (EKF3's default)
                rows.append(np.eye(9)[axis])
                z.append(m.pos_ned_m[axis])
                sigma.append(f.pos_noise_ne_m if axis < 2 else f.pos_noise_d_m)
        if m.vel_ned_m_s is not None:
            rows += list(np.eye(9)[3:6])
            z += list(m.vel_ned_m_s)
            sigma += [f.vel_noise_m_s] * 3
        self._update(np.array(rows), np.array(z), sigma)

    def _update(self, h: np.ndarray, z: np.ndarray, sigma) -> None:
        s = h @ self._p @ h.T + np.diag(np.square(sigma))
        k = np.linalg.solve(s, h @ self._p).T
        self._x = self._x + k @ (z - h @ self._x)
        self._p = (np.eye(9) - k @ h) @ self._p
