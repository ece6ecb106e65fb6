"""The reduced-order model (ROM) of the M4 in flight, in CasADi: the NMPC's prediction model.

State x (20), in this order:
    p_ned_m (3)       centre of mass of the whole robot, local NED
    euler_rad (3)     roll, pitch, yaw (ZYX convention: R = Rz(yaw) Ry(pitch) Rx(roll), body FRD -> NED)
    hip_rad (4)       sagittal hip angles, rotors 1..4
    v_ned_m_s (3)     velocity of the centre of mass, NED
    rates_frd_rad_s (3) body angular velocity, FRD
    hip_rate_rad_s (4)
Input u (8): thrust_n (4), hip_accel_rad_s2 (4).
Disturbance d (6): force_ned_n (3), torque_frd_n_m (3), constant over the horizon; the
offset-free estimate of what the model does not explain (mass, thrust and inertia errors, wind).

The body is a 6-DoF rigid body; each leg is three point masses (hip block, link, wheel +
thruster, as the airframe places them), so posture moves the centre of mass, the thrust moment
arms and the inertia; the legs' motion itself exerts no force on the body in this model. Thrust acts along -z (up) of
the body at each thruster; each rotor adds the reaction moment spin * k_m * T about body z.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from companion.core.rom_layout import EULER, HIP, HIP_ACCEL, HIP_RATE, ND, NU, NX, P, RATES, THRUST, V
from m4.airframe import ROTOR_COUNT, Airframe
from m4.attitude import rotation_rows


_SMOOTH_ABS_EPS = 1e-6   # |a| ~ sqrt(a^2 + eps): keeps the quadratic drag differentiable at 0


def rotation_ned_from_frd(euler):
    """ZYX Euler angles (roll, pitch, yaw) -> rotation matrix body FRD -> NED (CasADi or numpy)."""
    lib = ca if isinstance(euler, (ca.SX, ca.MX)) else np
    rows = rotation_rows(*(f(euler[i]) for i in range(3) for f in (lib.cos, lib.sin)))
    if lib is np:
        return np.array(rows, dtype=float)
    return ca.vertcat(*[ca.horzcat(*r) for r in rows])


def euler_rates_from_body_rates(euler, rates):
    """d(roll, pitch, yaw)/dt from body rates (FRD), ZYX convention (singular at pitch +-90 deg)."""
    roll, pitch = euler[0], euler[1]
    p, q, r = rates[0], rates[1], rates[2]
    sr, cr, tp, cp = ca.sin(roll), ca.cos(roll), ca.tan(pitch), ca.cos(pitch)
    return ca.vertcat(p + sr * tp * q + cr * tp * r, cr * q - sr * r, (sr * q + cr * r) / cp)


@dataclass(frozen=True)
class RomFunctions:
    """CasADi functions of the ROM; all take and return column vectors."""

    f: ca.Function              # (x, u, d) -> xdot
    step: ca.Function           # (x, u, d) -> x after dt (RK4, inputs held)
    dt_s: float
    substeps: int


def thruster_positions(af: Airframe, hip):
    """(3, 4) CasADi matrix of thruster positions in FRD for symbolic hip angles."""
    signs = af.leg_direction_signs
    cols = []
    for i in range(ROTOR_COUNT):
        hx, hy, hz = af.hip_frd_m[i]
        cols.append(ca.vertcat(hx + af.leg_length_m * signs[i, 0] * ca.cos(hip[i]),
                               hy + af.leg_length_m * signs[i, 1] * ca.sin(hip[i]),
                               hz))
    return ca.horzcat(*cols)


def _skew_inertia(r):
    """Inertia of a unit point mass at r about the origin: |r|^2 I - r r^T."""
    return ca.dot(r, r) * ca.DM.eye(3) - r @ r.T


def mass_properties(af: Airframe, hip):
    """(centre of mass offset FRD (3,), inertia about the centre of mass (3, 3)) for posture hip."""
    hips = ca.DM(np.array(af.hip_frd_m).T)
    reach = thruster_positions(af, hip) - hips                      # hip -> hub, per leg
    lumps = [(m, hips + f * reach) for m, f in af.leg_lumps]
    com = sum(m * ca.sum2(r) for m, r in lumps) / af.total_mass_kg
    inertia = ca.diag(ca.DM(af.body_inertia_diag_kg_m2)) + af.body_mass_kg * _skew_inertia(-com)
    for m, r in lumps:
        for i in range(ROTOR_COUNT):
            inertia += m * _skew_inertia(r[:, i] - com)
    return com, inertia


def thrust_torque_frd(af: Airframe, hip, com, thrust):
    """Torque (FRD, about the centre of mass com) of the thrusts at posture hip: each thrust
    along -z at its thruster, plus each rotor's reaction moment about body z."""
    arms = thruster_positions(af, hip) - ca.repmat(com, 1, ROTOR_COUNT)
    torque_frd = ca.SX.zeros(3)
    for i in range(ROTOR_COUNT):
        torque_frd += ca.cross(arms[:, i], ca.vertcat(0, 0, -thrust[i]))
        torque_frd[2] += af.spin_sign[i] * af.moment_coefficient_m * thrust[i]
    return torque_frd


def dynamics(af: Airframe) -> ca.Function:
    """Continuous-time ROM: xdot = f(x, u, d)."""
    x, u, d = ca.SX.sym("x", NX), ca.SX.sym("u", NU), ca.SX.sym("d", ND)
    euler, hip, v, w, hip_rate = x[EULER], x[HIP], x[V], x[RATES], x[HIP_RATE]
    thrust, hip_accel = u[THRUST], u[HIP_ACCEL]

    com, inertia = mass_properties(af, hip)
    force_frd = ca.vertcat(0, 0, -ca.sum1(thrust))
    torque_frd = thrust_torque_frd(af, hip, com, thrust)

    speed = ca.sqrt(ca.dot(v, v) + _SMOOTH_ABS_EPS)
    drag_ned = -(af.drag_linear_n_s_m + af.drag_quadratic_n_s2_m2 * speed) * v
    yaw_abs = ca.sqrt(w[2] ** 2 + _SMOOTH_ABS_EPS)
    drag_torque = -af.drag_rotational_linear_n_m_s * w - ca.vertcat(0, 0, af.drag_yaw_quadratic_n_m_s2 * yaw_abs * w[2])

    rot = rotation_ned_from_frd(euler)
    accel_ned = (rot @ force_frd + drag_ned + d[0:3]) / af.total_mass_kg + ca.vertcat(0, 0, af.gravity_m_s2)
    wdot = ca.solve(inertia, torque_frd + drag_torque + d[3:6] - ca.cross(w, inertia @ w))

    xdot = ca.vertcat(v, euler_rates_from_body_rates(euler, w), hip_rate, accel_ned, wdot, hip_accel)
    return ca.Function("m4_rom_f", [x, u, d], [xdot], ["x", "u", "d"], ["xdot"])


def rk4(f: ca.Function, x, u, d, duration, substeps: int = 1):
    """Expression of x after `duration` (a number or a symbol) of f with u and d held:
    `substeps` RK4 stages in sequence."""
    h = duration / substeps
    xk = x
    for _ in range(substeps):
        k1 = f(xk, u, d)
        k2 = f(xk + h / 2 * k1, u, d)
        k3 = f(xk + h / 2 * k2, u, d)
        k4 = f(xk + h * k3, u, d)
        xk = xk + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return xk


def rk4_step(f: ca.Function, dt_s: float, substeps: int = 1) -> ca.Function:
    """Discrete step of f over dt_s with the inputs held."""
    x, u, d = ca.SX.sym("x", NX), ca.SX.sym("u", NU), ca.SX.sym("d", ND)
    return ca.Function("m4_rom_step", [x, u, d], [rk4(f, x, u, d, dt_s, substeps)], ["x", "u", "d"], ["x_next"])


def build_rom(af: Airframe, dt_s: float, substeps: int = 1) -> RomFunctions:
    f = dynamics(af)
    return RomFunctions(f=f, step=rk4_step(f, dt_s, substeps), dt_s=dt_s, substeps=substeps)


def hover_state(af: Airframe, p_ned_m=(0.0, 0.0, -2.0), yaw_rad: float = 0.0, hip_rad=None) -> np.ndarray:
    """State vector of a robot hovering at rest (the posture defaults to the nominal one)."""
    x = np.zeros(NX)
    x[P] = p_ned_m
    x[EULER.stop - 1] = yaw_rad
    x[HIP] = af.nominal_hip_rad if hip_rad is None else hip_rad
    return x


def hover_input(af: Airframe) -> np.ndarray:
    """Input that holds a symmetric posture in hover: equal thrusts carrying the weight."""
    u = np.zeros(NU)
    u[THRUST] = af.hover_thrust_per_rotor_n
    return u
