"""The rate feedback the flight controller closes around our plan (m4.setpoint.RateFeedback).

Planned rates: the NMPC plans from the state predicted to the instant the setpoint takes
effect, so that state's body rates are what the robot should have then, and the plan's next
node (one NMPC step later, the first input held) gives their change per second.

Gain: a rate error e (roll, pitch) asks for the torque bandwidth x inertia x e about the
centre of mass, at the posture the plan starts from, made by the live rotors with no change
of their sum (the altitude is the plan's). With thrust along -z at arm a from the centre of
mass, a rotor's thrust f gives the torque (-a_y f, a_x f) about x and y, so the live rotors'
changes solve [-a_y; a_x; 1] df = [tau_x; tau_y; 0] (least norm with four rotors, exact with
three). Yaw is left to the plan: after a rotor loss the robot spins on purpose, and yaw
torque comes only from the rotors' drag moments, which would spend the thrust the tilt needs.
A rotor whose bound is below LIVE_SHARE of hover thrust takes no part; with fewer than three
live rotors there is no feedback.

Shortfall cover: while all four rotors are live, a rotor that falls short by s (as the FC sees
in its ESC's speed or on its gyro) is covered by the other three, whose changes df solve the
same rows: [-a_y; a_x; 1]_others df = [-a_y; a_x; 1]_short s, so the sum and the roll and
pitch torque stay as planned (the yaw moment does not: the robot spins up, as after a
confirmed loss).
Once the detector has confirmed a fault the plan knows it (a lost rotor's bound, a damaged
propeller's effectiveness) and no cover is sent: covering it as well would count the
shortfall twice. With the cover goes each rotor's effectiveness, the roll and pitch
acceleration a newton of its thrust gives at the planned posture (the inverse inertia times
[-a_y; a_x; spin k_m], the reaction moment included for the products of inertia): the FC
measures on its gyro what the robot lacks of the planned angular acceleration and explains
it by the rotors that fall short, which is how it covers a rotor without ESC telemetry.

Each step's gain and cover are kept for the posture (and live rotors, confirmed fault) they
were designed at: `prepare`, called after the send, designs them for the posture the next
step is expected to start from (the controller's hip goal), so that step's answer finds them
ready instead of solving for them between the state's arrival and the setpoint's send.

Pure logic: no clock, no I/O.
"""

from __future__ import annotations

import math
from array import array

import casadi as ca
import numpy as np

from companion.core import rom
from companion.core.casadi_call import BufferedFunction
from m4.airframe import ROTOR_COUNT, Airframe
from m4.setpoint import (EFFECTIVENESS_MAX_RAD_S2_PER_N, RATE_GAIN_MAX_N_PER_RAD_S, SHORTFALL_GAIN_MAX, RateFeedback,
                         ShortfallCover)

LIVE_SHARE = 0.5


class _Kept:
    """The last value made, kept for the key it was made for: a step's gain and cover are asked
    for again at the same posture until the posture moves."""

    def __init__(self):
        self._key: bytes | None = None
        self._value = None

    def get(self, key: bytes, make):
        if self._key != key:
            self._key, self._value = key, make()
        return self._value


class RateFeedbackDesign:
    def __init__(self, af: Airframe, bandwidth_rad_s: float, shortfall_cover: bool = False):
        self.af = af
        self.bandwidth_rad_s = float(bandwidth_rad_s)
        self.shortfall_cover = shortfall_cover
        self._design_gain_fn, self._design_cover_fn = (BufferedFunction(f) for f in _design_functions(
            af, self.bandwidth_rad_s))
        self._gain = _Kept()              # by posture and live rotors
        self._cover = _Kept()             # by posture and fault

    def prepare(self, hip_rad, thrust_bound_n, fault_confirmed: bool) -> None:
        """Design the gain and the cover for a step expected at posture hip_rad with these bounds
        (off the critical path: the step that comes there finds them designed)."""
        self.gain(hip_rad, thrust_bound_n)
        self.cover(hip_rad, fault_confirmed)

    def gain(self, hip_rad, thrust_bound_n) -> np.ndarray | None:
        """(4, 3) thrust change per rotor per unit rate error (N per rad/s) at posture hip_rad;
        None without feedback (bandwidth 0, fewer than three live rotors, a posture the model
        cannot take)."""
        designed = self._designed_gain(hip_rad, thrust_bound_n)
        return None if designed is None else designed[0]

    def _designed_gain(self, hip_rad, thrust_bound_n) -> tuple[np.ndarray, np.ndarray] | None:
        """The gain and, once, the same as MAVLink's float32 carries it (read-only: every
        setpoint at the posture shares it)."""
        live = np.asarray(thrust_bound_n, dtype=float) > LIVE_SHARE * self.af.hover_thrust_per_rotor_n
        hip = np.asarray(hip_rad, dtype=float)
        return self._gain.get(hip.tobytes() + live.tobytes(), lambda: _with_float32(self._design_gain(hip, live)))

    def _design_gain(self, hip: np.ndarray, live: np.ndarray) -> np.ndarray | None:
        if self.bandwidth_rad_s <= 0 or live.sum() < 3 or not np.isfinite(hip).all():
            return None
        gain, = self._design_gain_fn(hip, live)
        gain[~live] = 0.0                 # +0.0 (the zeroed columns leave -0.0 where an arm is negative)
        return gain if np.abs(gain).max() <= RATE_GAIN_MAX_N_PER_RAD_S else None   # NaN: a singular allocation

    def cover(self, hip_rad, fault_confirmed: bool) -> ShortfallCover | None:
        """The other rotors' cover for each rotor's shortfall at posture hip_rad; None when
        switched off, a fault is confirmed, or the posture cannot keep sum and torque."""
        hip = np.asarray(hip_rad, dtype=float)
        return self._cover.get(hip.tobytes() + bytes([fault_confirmed]),
                               lambda: self._design_cover(hip, fault_confirmed))

    def _design_cover(self, hip: np.ndarray, fault_confirmed: bool) -> ShortfallCover | None:
        if not self.shortfall_cover or fault_confirmed or not np.isfinite(hip).all():
            return None
        gain, effectiveness = self._design_cover_fn(hip)      # NaN: a singular allocation or inertia
        if not (np.abs(gain).max() <= SHORTFALL_GAIN_MAX
                and np.abs(effectiveness).max() <= EFFECTIVENESS_MAX_RAD_S2_PER_N):
            return None
        f32 = lambda v: v.astype(np.float32).astype(float)     # as MAVLink carries them
        return ShortfallCover(f32(gain), f32(effectiveness))

    def feedback(self, x_start, x_next, dt_s: float, thrust_bound_n) -> RateFeedback | None:
        """The feedback for a plan from ROM state x_start whose next node, dt_s later, is x_next."""
        x_start, x_next = np.asarray(x_start, dtype=float), np.asarray(x_next, dtype=float)
        designed = self._designed_gain(x_start[rom.HIP], thrust_bound_n)
        if designed is None:
            return None
        start, after = x_start[rom.RATES].tolist(), x_next[rom.RATES].tolist()     # six floats: cheaper than numpy's
        change = [(a - s) / dt_s for a, s in zip(after, start, strict=True)]
        planned = array("f", start + change).tolist()      # as MAVLink carries them (beyond float32's range: inf)
        if not all(map(math.isfinite, planned)):
            return None
        return RateFeedback(np.array(planned[:3]), np.array(planned[3:]), designed[1])


def _with_float32(gain: np.ndarray | None) -> tuple[np.ndarray, np.ndarray] | None:
    if gain is None:
        return None
    carried = gain.astype(np.float32).astype(float)
    carried.flags.writeable = False
    return gain, carried


def _design_functions(af: Airframe, bandwidth_rad_s: float) -> tuple[ca.Function, ca.Function]:
    """The gain's and the cover's design as CasADi functions of the posture (one call each
    instead of a dozen small numpy solves): (hip (4), live (4): 1 a rotor that takes part, else
    0) -> gain (4, 3); (hip (4)) -> cover gain (4, 4), effectiveness (2, 4). Singular systems
    give non-finite values (the caller then designs none)."""
    hip, live = ca.SX.sym("hip", ROTOR_COUNT), ca.SX.sym("live", ROTOR_COUNT)
    com, inertia = rom.mass_properties(af, hip)
    arms = rom.thruster_positions(af, hip) - ca.repmat(com, 1, ROTOR_COUNT)
    allocation = ca.vertcat(-arms[1, :], arms[0, :], ca.DM.ones(1, ROTOR_COUNT))   # roll, pitch torque, sum per N
    rows = allocation * ca.repmat(live.T, 3, 1)          # a rotor out is a zero column: it takes no part
    least_norm = ca.solve(rows @ rows.T, rows).T         # rows^T (rows rows^T)^-1: full row rank with three live
    gain = ca.horzcat(least_norm[:, :2] @ (bandwidth_rad_s * inertia[:2, :2]), ca.SX.zeros(ROTOR_COUNT, 1))
    cover = ca.SX.zeros(ROTOR_COUNT, ROTOR_COUNT)
    for short in range(ROTOR_COUNT):
        others = [i for i in range(ROTOR_COUNT) if i != short]
        covered = ca.solve(allocation[:, others], allocation[:, short])
        for j, other in enumerate(others):
            cover[other, short] = covered[j]
    torque = ca.vertcat(allocation[:2, :], af.moment_coefficient_m * ca.DM(af.spin_sign).T)
    effectiveness = ca.solve(inertia, torque)[:2, :]
    return (ca.Function("m4_rate_feedback_gain", [hip, live], [gain]),
            ca.Function("m4_rate_feedback_cover", [hip], [cover, effectiveness]))
