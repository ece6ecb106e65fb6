"""The flight controller's own failsafe: hold position, then land, then cut the motors.

Used before the first setpoint and whenever the companion's setpoints are stale. It is a
plain cascaded controller on the FC's own state estimate (position PD -> tilt and collective
thrust -> attitude PD -> moments), the legs at the nominal posture, and a 4x4 allocation of
force and moments to the rotors.

HOLD keeps the position and yaw where it engaged. LAND (entered after `LAND_AFTER_S` of
HOLD when the FC allows it, or at once when engaged to land: LAND was selected) lowers the
target at `LAND_SPEED_M_S`; on touchdown (ground
contact, or the descent stalled on the ground) the thrust is cut: LANDED.

A lost rotor (`set_lost_rotor`: from the companion's last M4_FAULT_STATUS, or the FC's own
ESC check, sitl/fc/rotor_watch.py): the failsafe
flies on the three live rotors (sitl/fc/failsafe_posture.py: the legs move so the centre of mass
sits inside their triangle, yaw is let go and the vehicle spins) and lands at once, without
holding first: on three rotors every second in the air is a risk.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from m4.airframe import ROTOR_COUNT, Airframe
from sitl.fc.failsafe_posture import ThreeRotorController
from sitl.fc.modes import FcMode

LAND_AFTER_S = 2.0
LAND_SPEED_M_S = 0.5
MAX_TILT_RAD = math.radians(30.0)
MAX_HORIZONTAL_ACCEL_M_S2 = 4.0
TOUCHDOWN_LAG_M = 0.3        # the target this far below the hull with no descent: on the ground
TOUCHDOWN_SPEED_M_S = 0.1


@dataclass(frozen=True)
class Gains:
    pos_1_s2: float = 1.5           # desired acceleration per metre of position error
    vel_1_s: float = 2.2            # per m/s of velocity error
    att_rad_s: float = 9.0          # roll/pitch loop natural frequency
    yaw_rad_s: float = 3.0
    damping: float = 0.8


def _wrap(a: float) -> float:
    return (a + math.pi) % (2.0 * math.pi) - math.pi


class HoldController:
    """Position and yaw hold at the nominal posture: thrusts from the state and a target."""

    def __init__(self, airframe: Airframe, gains: Gains = Gains()):
        self.af = airframe
        self.gains = gains
        self.hip_rad = np.full(ROTOR_COUNT, airframe.nominal_hip_rad)
        r = airframe.thruster_positions_frd_m(self.hip_rad) - airframe.com_offset_frd_m(self.hip_rad)
        wrench_from_thrust = np.vstack([np.ones(ROTOR_COUNT), -r[:, 1], r[:, 0],
                                        airframe.moment_coefficient_m * np.array(airframe.spin_sign, dtype=float)])
        self._thrust_from_wrench = np.linalg.inv(wrench_from_thrust)
        legs = airframe.leg_mass_kg * sum(np.dot(ri, ri) * np.eye(3) - np.outer(ri, ri) for ri in r)
        self._inertia_diag = np.array(airframe.body_inertia_diag_kg_m2) + np.diag(legs)

    def accel_ned_m_s2(self, state, target_ned_m, target_vel_ned_m_s=(0.0, 0.0, 0.0)) -> np.ndarray:
        """The acceleration the position loop asks for (horizontal part bounded)."""
        g = self.gains
        accel = (g.pos_1_s2 * (np.asarray(target_ned_m) - state.pos_ned_m)
                 + g.vel_1_s * (np.asarray(target_vel_ned_m_s) - state.vel_ned_m_s))
        horizontal = np.linalg.norm(accel[:2])
        if horizontal > MAX_HORIZONTAL_ACCEL_M_S2:
            accel[:2] *= MAX_HORIZONTAL_ACCEL_M_S2 / horizontal
        return accel

    def three_rotor(self, dead: int) -> ThreeRotorController:
        """The same loops' gains on three rotors, rotor `dead` (1..4) off."""
        return ThreeRotorController(self.af, dead, self._inertia_diag, self.gains.att_rad_s, self.gains.damping)

    def thrust_n(self, state, target_ned_m, target_yaw_rad: float, target_vel_ned_m_s=(0.0, 0.0, 0.0)) -> np.ndarray:
        g, af = self.gains, self.af
        accel = self.accel_ned_m_s2(state, target_ned_m, target_vel_ned_m_s)
        roll, pitch, yaw = state.euler_rad
        c, s = math.cos(yaw), math.sin(yaw)
        forward = c * accel[0] + s * accel[1]
        right = -s * accel[0] + c * accel[1]
        roll_t = float(np.clip(right / af.gravity_m_s2, -MAX_TILT_RAD, MAX_TILT_RAD))
        pitch_t = float(np.clip(-forward / af.gravity_m_s2, -MAX_TILT_RAD, MAX_TILT_RAD))
        tilt_cos = max(math.cos(roll) * math.cos(pitch), math.cos(MAX_TILT_RAD))
        collective = af.total_mass_kg * max(af.gravity_m_s2 - accel[2], 0.2 * af.gravity_m_s2) / tilt_cos
        error = np.array([roll_t - roll, pitch_t - pitch, _wrap(target_yaw_rad - yaw)])
        w = np.array([g.att_rad_s, g.att_rad_s, g.yaw_rad_s])
        moments = self._inertia_diag * (w * w * error - 2.0 * g.damping * w * state.rates_frd_rad_s)
        thrust = self._thrust_from_wrench @ np.concatenate([[collective], moments])
        return np.clip(thrust, af.thrust_min_n, af.thrust_max_n)


@dataclass(frozen=True)
class FailsafeOutput:
    mode: FcMode                   # HOLD, LAND or LANDED
    thrust_n: np.ndarray
    hip_rad: np.ndarray


class Failsafe:
    """HOLD -> (after LAND_AFTER_S, if allowed) LAND -> LANDED, on the FC's clock in ms."""

    def __init__(self, airframe: Airframe):
        self.controller = HoldController(airframe)
        self.land_after_s = LAND_AFTER_S        # a parameter (sitl/fc/params.py)
        self.mode = FcMode.HOLD
        self._since_ms = 0
        self._may_land = False
        self._target_ned_m = np.zeros(3)
        self._yaw_rad = 0.0
        self.three_rotor: ThreeRotorController | None = None

    def set_lost_rotor(self, rotor: int | None) -> None:
        """Rotor 1..4 is lost (None: all four work)."""
        if rotor != (self.three_rotor.dead if self.three_rotor is not None else None):
            self.three_rotor = None if rotor is None else self.controller.three_rotor(rotor)

    @property
    def hip_rad(self) -> np.ndarray:
        return self.controller.hip_rad if self.three_rotor is None else self.three_rotor.hip_rad

    def engage(self, state, now_ms: int, may_land: bool, land: bool = False) -> None:
        """Hold here from `now_ms`; with `may_land`, land once held for LAND_AFTER_S; with
        `land`, land from here now."""
        self.mode = FcMode.LAND if land else FcMode.HOLD
        self._since_ms = now_ms
        self._may_land = may_land
        self._target_ned_m = np.array(state.pos_ned_m, dtype=float)
        self._yaw_rad = float(state.euler_rad[2])

    def _thrust_n(self, state, target_ned_m, target_vel_ned_m_s=(0.0, 0.0, 0.0)) -> np.ndarray:
        if self.three_rotor is None:
            return self.controller.thrust_n(state, target_ned_m, self._yaw_rad, target_vel_ned_m_s)
        return self.three_rotor.thrust_n(state, self.controller.accel_ned_m_s2(state, target_ned_m, target_vel_ned_m_s))

    def update(self, state, now_ms: int) -> FailsafeOutput:
        held_ms = now_ms - self._since_ms
        if self.mode == FcMode.HOLD and (self.three_rotor is not None
                                               or (self._may_land and held_ms >= self.land_after_s * 1000)):
            self.mode = FcMode.LAND
            self._since_ms = now_ms
            self._target_ned_m = np.array(state.pos_ned_m, dtype=float)
        if self.mode == FcMode.LAND:
            descent = LAND_SPEED_M_S * (now_ms - self._since_ms) / 1000.0
            target_ned_m = self._target_ned_m + np.array([0.0, 0.0, descent])
            stalled = (target_ned_m[2] - state.pos_ned_m[2] > TOUCHDOWN_LAG_M
                       and abs(state.vel_ned_m_s[2]) < TOUCHDOWN_SPEED_M_S)
            if state.on_ground or stalled:
                self.mode = FcMode.LANDED
            else:
                thrust = self._thrust_n(state, target_ned_m, (0.0, 0.0, LAND_SPEED_M_S))
                return FailsafeOutput(self.mode, thrust, self.hip_rad)
        if self.mode == FcMode.LANDED:
            return FailsafeOutput(self.mode, np.zeros(ROTOR_COUNT), self.hip_rad)
        return FailsafeOutput(self.mode, self._thrust_n(state, self._target_ned_m), self.hip_rad)
