"""The plant's state as the rest of the project sees it: NED/FRD, SI units, numpy arrays."""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np


@dataclass(frozen=True)
class PlantState:
    time_s: float
    pos_ned_m: np.ndarray          # hull centre (where the IMU sits), local NED
    vel_ned_m_s: np.ndarray
    quat_wxyz: np.ndarray          # rotation body FRD -> NED, scalar first
    euler_rad: np.ndarray          # roll, pitch, yaw (ZYX)
    rates_frd_rad_s: np.ndarray
    hip_rad: np.ndarray            # (4,) sagittal angles, rotors 1..4
    hip_rate_rad_s: np.ndarray
    thrust_cmd_n: np.ndarray       # (4,) sent to the ESCs: the request clamped to [0, rated max]
    thrust_n: np.ndarray           # (4,) delivered (truth)
    thrust_limit_n: np.ndarray     # (4,) what each rotor settles at on the largest command, fault and pack
                                   # voltage applied (truth, for metrics)
    thrust_rated_max_n: np.ndarray  # (4,) max per rotor as configured (all the FC knows)
    rotor_speed_rad_s: np.ndarray  # (4,) truth; the FC hears it through the ESC telemetry
    esc_current_a: np.ndarray      # (4,) drawn from the pack by each ESC (truth)
    fault_kind: np.ndarray         # (4,) int: m4.fault_kind.FaultKind, -1 healthy (truth)
    battery_voltage_v: float
    battery_consumed_mah: float
    com_ned_m: np.ndarray          # whole-robot centre of mass (truth, for metrics)
    on_ground: bool                # any contact with the floor
    wind_ned_m_s: np.ndarray | None = None   # (3,) the air's velocity over the ground at the robot (truth);
                                             # None: a still-air scenario (no [wind])


class RotorState(NamedTuple):
    """What the ESCs measure and are told, alone (truth; the names of PlantState's fields):
    cheap to read at every FC tick, without the rest of the plant's state (Python floats,
    not arrays: four numbers each; a named tuple, cheaper to make than a frozen dataclass)."""
    rotor_speed_rad_s: list[float]  # (4,)
    esc_current_a: list[float]      # (4,) drawn from the pack by each ESC
    battery_voltage_v: float
    thrust_cmd_n: list[float]       # (4,) sent to the ESCs


@dataclass(frozen=True)
class ImuSample:
    """One IMU reading, as the sensor outputs it (noise, bias, vibration, range)."""
    time_s: float
    gyro_frd_rad_s: np.ndarray
    accel_frd_m_s2: np.ndarray     # specific force: (0, 0, -g) at rest, level


@dataclass(frozen=True)
class BaroSample:
    time_s: float
    height_m: float                # above the local NED origin (-down), with noise and drift


@dataclass(frozen=True)
class CompassSample:
    time_s: float
    field_frd: np.ndarray          # the earth's field in the body, unit length plus noise


@dataclass(frozen=True)
class FixSample:
    """A GNSS or motion-capture fix heard at `time_s`, measured `delay` earlier (the FC knows
    its sensor's delay, as a flight controller's GPS_DELAY / EKF2_EV_DELAY)."""
    time_s: float
    pos_ned_m: np.ndarray
    vel_ned_m_s: np.ndarray | None  # GNSS only
    yaw_rad: float | None           # motion capture only


SensorSample = ImuSample | BaroSample | CompassSample | FixSample
