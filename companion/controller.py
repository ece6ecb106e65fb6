"""One control step of the companion: measured ROM state and time in, a safe setpoint out.

Pure logic (no MAVLink, no sockets): the mission reference, the disturbance estimate, the
fault detector and the NMPC, and after a touchdown during the landing the thrust cut. A
confirmed fault only lowers that rotor's thrust bound in the NMPC (no controller switch)
and, with on_fault = "hold", turns the reference into a hold.

The setpoint answers the instant of the state: thrusts are the NMPC's first input. The hips
follow the planned joint motion: the controller integrates the NMPC's hip accelerations into
a hip goal (angle and rate; the ROM's double integrator) and hands the FC's servo a
trajectory (M4_SETPOINT: an angle at that instant and the rate it moves at) that starts on
the goal and reaches the planned hip angle one control period later. The NMPC's hip states
are that goal, not the measured joints: a servo holding a load deflects a little, and
planning from the deflected angle would feed the deflection back into the goal (the legs
creep). The measured joints still place the centre of mass; when goal and joints drift
apart by more than HIP_RESYNC_RAD (a blocked leg) or after a gap, the goal restarts from
the measured joints. `safe_setpoint` is the last word before anything leaves the
process: every value finite, thrusts within [thrust_min, bound], hips within the joint range
and the same-side sum, rates within the servo's limit; whatever is not finite becomes a
safe value (hover thrust, the measured or nominal hip, zero rate).

Fault detection input: the FC's per-rotor delivered thrust when it reports one (NaN: the
model residual is used instead) and the command in force over the last period (ours). The
FC's per-rotor limits count only as a common cap (the largest of them): a limit that drops
on one rotor is exactly what the detector must find itself, so it is not handed to it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from m4.airframe import ROTOR_COUNT, Airframe
from companion.config import CompanionConfig
from companion.core import rom
from companion.core.disturbance import DisturbanceEstimator
from companion.core.fault_detector import FaultDetector, FaultState, FaultStatus
from companion.core.nmpc import Nmpc, NmpcResult, thrust_bounds
from companion.core.reference import MissionReference
from companion.core.touchdown import TouchdownDetector

_CONSECUTIVE_TOLERANCE = 0.5     # steps closer than (1 +- this) periods count as consecutive
HIP_RESYNC_RAD = 0.2             # hip goal this far from the measured joint: restart it there
_HIP_MARGIN_RAD = 0.5            # measured hips beyond the joint range by more than this are broken
_PLAUSIBLE = ((rom.P, 1e5), (rom.EULER, 2 * np.pi), (rom.V, 100.0), (rom.RATES, 100.0), (rom.HIP_RATE, 100.0))


@dataclass(frozen=True)
class Setpoint:
    thrust_n: np.ndarray          # (4,)
    hip_angle_rad: np.ndarray     # (4,) servo goal at the answered instant ...
    hip_rate_rad_s: np.ndarray    # (4,) ... moving at this rate: on the planned hip one period later
    thrust_cut: bool = False


@dataclass(frozen=True)
class ControlStep:
    time_s: float
    setpoint: Setpoint
    state: np.ndarray             # (20,) the ROM state planned from: measured, the hips their goal
    reference: np.ndarray | None  # (N+1, 20); None before a reference could start
    nmpc: NmpcResult | None       # None when no solve ran (thrust cut, no reference)
    fault: FaultStatus
    fault_confirmed_now: bool     # the step at which the fault was confirmed (announce it)
    disturbance: np.ndarray       # (6,) estimate handed to the NMPC


def plausible_state(af: Airframe, x) -> bool:
    """Finite and physically possible (a state outside this is a broken measurement: the
    controller falls back instead of planning from it)."""
    x = np.asarray(x, dtype=float)
    if not np.all(np.isfinite(x)):
        return False
    hip = x[rom.HIP]
    hip_ok = np.all(hip >= af.hip_min_rad - _HIP_MARGIN_RAD) and np.all(hip <= af.hip_max_rad + _HIP_MARGIN_RAD)
    return bool(hip_ok and all(np.all(np.abs(x[part]) <= limit) for part, limit in _PLAUSIBLE))


def safe_setpoint(af: Airframe, thrust_n, hip_rad, hip_rate_rad_s, thrust_max_n, measured_hip_rad=None,
                  thrust_cut: bool = False) -> Setpoint:
    """A setpoint that is finite and within every bound, whatever goes in (NaN, inf, out of range)."""
    bound = thrust_bounds(af, thrust_max_n)
    thrust = np.asarray(thrust_n, dtype=float).reshape(ROTOR_COUNT)
    thrust = np.clip(np.where(np.isfinite(thrust), thrust, af.hover_thrust_per_rotor_n), af.thrust_min_n, bound)
    if thrust_cut:
        thrust = np.zeros(ROTOR_COUNT)
    fallback_hip = np.full(ROTOR_COUNT, af.nominal_hip_rad)
    if measured_hip_rad is not None:
        measured = np.asarray(measured_hip_rad, dtype=float).reshape(ROTOR_COUNT)
        fallback_hip = np.where(np.isfinite(measured), measured, fallback_hip)
    hip = np.asarray(hip_rad, dtype=float).reshape(ROTOR_COUNT)
    hip = np.clip(np.where(np.isfinite(hip), hip, fallback_hip), af.hip_min_rad, af.hip_max_rad)
    for pair in af.same_side_pairs:
        excess = hip[list(pair)].sum() - af.same_side_sum_max_rad
        if excess > 0:
            hip[list(pair)] = np.maximum(hip[list(pair)] - excess / 2, af.hip_min_rad)
    rate = np.asarray(hip_rate_rad_s, dtype=float).reshape(ROTOR_COUNT)
    rate = np.clip(np.where(np.isfinite(rate), rate, 0.0), -af.hip_rate_max_rad_s, af.hip_rate_max_rad_s)
    return Setpoint(thrust_n=_float32_within(thrust, 0.0 if thrust_cut else af.thrust_min_n, bound),
                    hip_angle_rad=_float32_within(hip, af.hip_min_rad, hip),
                    hip_rate_rad_s=_float32_within(rate, -af.hip_rate_max_rad_s, af.hip_rate_max_rad_s),
                    thrust_cut=thrust_cut)


def _float32_within(values: np.ndarray, lo, hi) -> np.ndarray:
    """Values that stay within [lo, hi] as the float32 MAVLink carries (rounding to the nearest
    float32 may step past a bound such as pi/2); the hips pass hi = themselves, so they never
    round up and a pair's sum stays within its bound."""
    v32 = values.astype(np.float32)
    v32 = np.where(v32.astype(float) > hi, np.nextafter(v32, np.float32(-np.inf)), v32)
    v32 = np.where(v32.astype(float) < lo, np.nextafter(v32, np.float32(np.inf)), v32)
    return v32.astype(float)


class Controller:
    """The companion's controller for `config` (its airframe, mission, NMPC and detector settings)."""

    def __init__(self, config: CompanionConfig, nmpc: Nmpc | None = None):
        self.config = config
        self.af = af = config.airframe
        self.period_s = config.control_period_s
        self.nmpc = nmpc or Nmpc(af, config.nmpc)
        self.disturbance = DisturbanceEstimator(af, self.period_s, config.disturbance_gain)
        self.detector = FaultDetector(af, config.fault_detector)
        self.reference: MissionReference | None = None
        self.touchdown: TouchdownDetector | None = None
        self._prev: tuple[float, np.ndarray, np.ndarray] | None = None    # (t, x, u applied)
        self._hip_goal: tuple[np.ndarray, np.ndarray] | None = None         # (angle, rate) now
        self._fault_announced = False

    def resume(self) -> None:
        """After a gap in the telemetry (link loss): the previous plan, state and hip goal are
        stale. The disturbance estimate is kept (it describes the robot, not the moment)."""
        self.nmpc.reset()
        self._prev = None
        self._hip_goal = None

    def restart(self) -> None:
        """The flight controller rebooted: its clock, and so the mission's time, starts over.
        Everything about the flight so far is forgotten but the NMPC itself."""
        self.resume()
        self.disturbance.reset()
        self.detector = FaultDetector(self.af, self.config.fault_detector)
        self.reference = self.touchdown = None
        self._fault_announced = False

    def step(self, time_s: float, x_measured, thrust_delivered_n=None, thrust_limit_n=None) -> ControlStep:
        """The setpoint answering the telemetry instant time_s for the measured ROM state."""
        af = self.af
        x = np.asarray(x_measured, dtype=float).reshape(rom.NX)
        thrust_delivered_n = self._thrust_telemetry(thrust_delivered_n)
        thrust_limit_n = self._thrust_telemetry(thrust_limit_n)
        usable = plausible_state(af, x)
        if usable:
            x = self._with_hip_goal(x)
        if self.reference is None and usable:
            self.reference = MissionReference(self.config.mission, x[rom.P], af, self.config.reference, t0_s=time_s)
            self.touchdown = TouchdownDetector(self.reference.ground_com_z_ned_m, self.config.touchdown)
        fault, confirmed_now = self._detect(time_s, x, usable, thrust_delivered_n, thrust_limit_n)
        if confirmed_now:
            self.disturbance.reset()      # it held the lost rotor's effect, which the bound now models
        d = self._estimate_disturbance(time_s, x, usable, fault.thrust_max_estimate_n)
        if self.reference is None or not usable:
            return self._fallback(time_s, x, fault, confirmed_now, d)
        if self._touched_down(time_s, x):
            sp = safe_setpoint(af, np.zeros(ROTOR_COUNT), x[rom.HIP], np.zeros(ROTOR_COUNT),
                               fault.thrust_max_estimate_n, x[rom.HIP], thrust_cut=True)
            self._prev = self._hip_goal = None
            return ControlStep(time_s, sp, x, None, None, fault, confirmed_now, d)
        c = self.nmpc.config
        x_ref = self.reference.reference(time_s, c.horizon, c.dt_s)
        res = self.nmpc.solve(x, x_ref, fault.thrust_max_estimate_n, d)
        sp = self._setpoint(x, res, fault.thrust_max_estimate_n)
        self._prev = (time_s, x, np.r_[sp.thrust_n, res.u[rom.HIP_ACCEL]])
        return ControlStep(time_s, sp, x, x_ref, res, fault, confirmed_now, d)

    # ------------------------------------------------------------------------------------------
    def _thrust_telemetry(self, thrust_n) -> np.ndarray | None:
        """Per-rotor thrusts from the FC with what cannot be a thrust (non-finite, negative,
        beyond twice the airframe's maximum) as NaN: unknown."""
        if thrust_n is None:
            return None
        t = np.asarray(thrust_n, dtype=float).reshape(ROTOR_COUNT)
        return np.where(np.isfinite(t) & (t >= 0.0) & (t <= 2.0 * self.af.thrust_max_n), t, np.nan)

    def _consecutive(self, time_s: float) -> bool:
        if self._prev is None:
            return False
        dt = time_s - self._prev[0]
        return abs(dt - self.period_s) <= _CONSECUTIVE_TOLERANCE * self.period_s

    def _detect(self, time_s, x, usable, delivered_n, limit_n) -> tuple[FaultStatus, bool]:
        if not usable or self._prev is None:
            return self.detector.status, False
        cap = self.af.thrust_max_n
        if limit_n is not None and np.any(np.isfinite(limit_n)):          # already a (4,) array (_thrust_telemetry)
            cap = float(np.clip(np.nanmax(limit_n), self.af.thrust_min_n, self.af.thrust_max_n))
        status = self.detector.update(time_s, x, self._prev[2][rom.THRUST], np.full(ROTOR_COUNT, cap),
                                      delivered_n)
        confirmed_now = status.state is FaultState.CONFIRMED and not self._fault_announced
        if confirmed_now:
            self._fault_announced = True
            if self.reference is not None:
                self.reference.fault_detected(time_s, x[rom.P])
        return status, confirmed_now

    def _estimate_disturbance(self, time_s, x, usable, thrust_max_n) -> np.ndarray:
        """Updated over the last period with our command within the current bounds. A rotor lost
        but not yet confirmed shows up here as a disturbance within a few periods, so the NMPC
        compensates it before the detector confirms it (measured on the SITL at 50 Hz: altitude
        loss 0.14 m against 0.43 m when the update used the FC's delivered thrust, which hides
        the loss); at confirmation the estimate restarts, the bound taking over."""
        if not (usable and self._consecutive(time_s)):
            return self.disturbance.estimate.copy()
        u = self._prev[2].copy()
        u[rom.THRUST] = np.minimum(u[rom.THRUST], thrust_bounds(self.af, thrust_max_n))
        return self.disturbance.update(self._prev[1], u, x)

    def _touched_down(self, time_s: float, x: np.ndarray) -> bool:
        if not self.reference.landing_started(time_s):
            return False
        return self.touchdown.update(time_s, float(x[rom.P][2]), float(x[rom.V][2]))

    def _with_hip_goal(self, x_measured: np.ndarray) -> np.ndarray:
        """The NMPC's state: measured, but the hip goal in place of the measured joints."""
        hip = x_measured[rom.HIP]
        goal = self._hip_goal
        if goal is None or not np.all(np.isfinite(goal[0])) or np.max(np.abs(goal[0] - hip)) > HIP_RESYNC_RAD:
            fixed = self.nmpc.config.fixed_hip_rad        # the fixed-posture variant: the legs go there
            start = np.clip(hip, self.af.hip_min_rad, self.af.hip_max_rad) if fixed is None else np.full(ROTOR_COUNT, fixed)
            goal = self._hip_goal = (start, np.zeros(ROTOR_COUNT))
        x = x_measured.copy()
        x[rom.HIP], x[rom.HIP_RATE] = goal
        return x

    def _setpoint(self, x: np.ndarray, res: NmpcResult, thrust_max_n) -> Setpoint:
        """Thrusts now; the hips from the goal now to the planned goal one period later (the FC's
        servo moves its goal from the angle at the rate, so the rate is the chord's)."""
        af, tau = self.af, self.period_s
        accel = res.u[rom.HIP_ACCEL]
        planned = x[rom.HIP] + x[rom.HIP_RATE] * tau + 0.5 * accel * tau**2
        sp = safe_setpoint(af, res.u[rom.THRUST], x[rom.HIP], (planned - x[rom.HIP]) / tau, thrust_max_n, x[rom.HIP])
        next_rate = np.clip(x[rom.HIP_RATE] + accel * tau, -af.hip_rate_max_rad_s, af.hip_rate_max_rad_s)
        self._hip_goal = (np.clip(sp.hip_angle_rad + sp.hip_rate_rad_s * tau, af.hip_min_rad, af.hip_max_rad),
                          np.where(np.isfinite(next_rate), next_rate, 0.0))
        return sp

    def _fallback(self, time_s, x, fault, confirmed_now, d) -> ControlStep:
        """No usable state: hover thrust within the bounds, hips held where they are, legs stopped."""
        sp = safe_setpoint(self.af, np.full(ROTOR_COUNT, np.nan), x[rom.HIP], np.zeros(ROTOR_COUNT),
                           fault.thrust_max_estimate_n, x[rom.HIP])
        self._prev = self._hip_goal = None
        return ControlStep(time_s, sp, x, None, None, fault, confirmed_now, d)
