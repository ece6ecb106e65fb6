"""The sensors behind a scenario's `[sensors] profile` ("mocap", "gps"), with their figures and
where each figure comes from. The plant's sensor models (sitl/plant/sensor_suite.py) draw
their samples with them; the flight controller's estimator (sitl/fc/estimator.py) is tuned
with the same figures, as a flight controller is configured with its sensors' noise and
delay (PX4's EKF2_*_NOISE / EKF2_*_DELAY, ArduPilot's EK3_*_NSE / GPS_DELAY_MS).

Units in the names; frames: body FRD, local NED. Rates are whole divisors of the 1 kHz physics.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

_DEG = math.pi / 180.0
_MICRO_G = 9.81e-6


@dataclass(frozen=True)
class Imu:
    period_ms: int
    gyro_noise_density_rad_s_rthz: float
    gyro_bias_walk_rad_s2_rthz: float     # the gyro bias's random walk
    gyro_bias_turn_on_rad_s: float        # standard deviation of the bias left at take-off, per axis
    gyro_range_rad_s: float
    accel_noise_density_m_s2_rthz: float
    accel_bias_walk_m_s3_rthz: float
    accel_bias_turn_on_m_s2: float
    accel_range_m_s2: float
    # Vibration: each rotor's residual imbalance u (kg m) shakes the robot with u w^2 / mass at
    # its speed w; a damaged propeller adds loss x blade_moment, a lost one leaves its hub's.
    imbalance_kg_m: float
    blade_moment_kg_m: float
    hub_imbalance_kg_m: float


@dataclass(frozen=True)
class Baro:
    period_ms: int
    noise_m: float
    drift_m_rths: float                   # random walk of the height error (temperature, weather)


@dataclass(frozen=True)
class Compass:
    period_ms: int
    noise: float                          # white noise on each axis, a fraction of the field
    field_ned: tuple[float, float, float]  # the earth's field, unit length


@dataclass(frozen=True)
class Fix:
    """A position source: GNSS or motion capture, measured at one instant, heard `delay_ms` later."""
    period_ms: int
    delay_ms: int
    pos_noise_ne_m: float
    pos_noise_d_m: float
    vel_noise_m_s: float | None           # None: no velocity measured (motion capture)
    yaw_noise_rad: float | None           # None: no heading measured (GNSS)


@dataclass(frozen=True)
class SensorProfile:
    name: str
    imu: Imu
    fix: Fix
    baro: Baro | None                     # None: height from the fix (motion capture)
    compass: Compass | None               # None: heading from the fix (motion capture)


# Bosch BMI088 datasheet (BST-BMI088-DS001): gyro 0.014 deg/s/rtHz, accel 175 ug/rtHz (typ.),
# ranges 2000 deg/s and 24 g. The bias random walks are not in datasheets: the Allan-variance
# figures of a MEMS IMU of that class, as used in Kalibr's IMU noise model (ADIS16448:
# 3.9e-5 rad/s^2/rtHz, 4.3e-4 m/s^3/rtHz; a BMI088 is worse, doubled here). Turn-on bias: what
# the autopilot's gyro and accel calibration at boot leaves (about 0.1 deg/s; 20 mg offset of
# the datasheet trimmed to 2 mg). 500 Hz: the rate of ArduCopter's main loop and IMU sampling
# is 400 Hz; 500 Hz divides the 1 kHz physics.
IMU = Imu(period_ms=2,
          gyro_noise_density_rad_s_rthz=0.014 * _DEG,
          gyro_bias_walk_rad_s2_rthz=8e-5,
          gyro_bias_turn_on_rad_s=0.1 * _DEG,
          gyro_range_rad_s=2000.0 * _DEG,
          accel_noise_density_m_s2_rthz=175.0 * _MICRO_G,
          accel_bias_walk_m_s3_rthz=9e-4,
          accel_bias_turn_on_m_s2=2000.0 * _MICRO_G,
          accel_range_m_s2=24.0 * 9.81,
          # A balanced 15-inch propeller: ISO 21940-11 grade G6.3 on a 50 g rotor at hover speed
          # gives 5e-7 kg m; field propellers are worse (blade mass mismatch): 1e-5 kg m,
          # about 0.5 m/s^2 of vibration per rotor at hover, the "good" level of the PX4 and
          # ArduPilot vibration guides. A blade of 10 g with its centre of mass at 70 mm.
          imbalance_kg_m=1e-5,
          blade_moment_kg_m=7e-4,
          hub_imbalance_kg_m=5e-5)

# MEAS MS5611 datasheet (on most Pixhawks): 0.012 mbar RMS at OSR 4096, about 0.1 m; drift
# about 1 m in 10 minutes (temperature), 0.04 m/rts. 50 Hz, ArduPilot's baro rate.
BARO = Baro(period_ms=20, noise_m=0.1, drift_m_rths=0.04)

# A 3-axis magnetometer (IST8310 / HMC5883L class): about 0.3 deg of heading noise, 100 Hz.
# The field at PX4's default home (Zurich, WMM): 2.2 deg east declination, 63.5 deg inclination.
COMPASS = Compass(period_ms=10, noise=0.005,
                  field_ned=(math.cos(63.5 * _DEG) * math.cos(2.2 * _DEG),
                             math.cos(63.5 * _DEG) * math.sin(2.2 * _DEG), math.sin(63.5 * _DEG)))

# u-blox M8/M9 (NEO-M8N / NEO-M9N data sheets): 5 Hz (ArduPilot's GPS_RATE_MS default 200 ms),
# velocity accuracy 0.05 m/s; position jitter 0.3 m horizontal, 0.5 m vertical (the short-term
# part of the 1.5-2.5 m CEP). Delay 120 ms: ArduPilot's measured u-blox lag (its GPS driver's
# get_lag; the EKF's old EKF_GPS_DELAY default was 220 ms), PX4's EKF2_GPS_DELAY is 110 ms.
GNSS = Fix(period_ms=200, delay_ms=120, pos_noise_ne_m=0.3, pos_noise_d_m=0.5, vel_noise_m_s=0.05,
           yaw_noise_rad=None)

# Motion capture (Vicon / OptiTrack): 100 Hz streamed, 15 ms from exposure to the autopilot
# (camera, processing and the radio link), sub-millimetre markers: 1 mm, 0.1 deg of heading.
MOCAP = Fix(period_ms=10, delay_ms=15, pos_noise_ne_m=0.001, pos_noise_d_m=0.001, vel_noise_m_s=None,
            yaw_noise_rad=0.1 * _DEG)

PROFILES = {
    "gps": SensorProfile("gps", IMU, GNSS, BARO, COMPASS),
    "mocap": SensorProfile("mocap", IMU, MOCAP, None, None),
}
