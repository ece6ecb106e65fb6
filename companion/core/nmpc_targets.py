"""Offset-free targets: the attitude and thrust a hover needs under the estimated disturbance.

Offset-free MPC needs more than a disturbance in the model: the cost must not pull towards a
state and input that cannot be held. A level attitude and the nominal hover thrust cannot
be held against a steady wind or with a heavier robot, and a cost that pulls towards them
trades a small position offset for a smaller attitude and thrust error. So the roll, pitch
and thrust the cost tracks are those of the equilibrium under the disturbance estimate:
the thrust must cancel weight plus disturbance force, which fixes its size and the
direction of the body z axis; with the yaw (free, possibly spinning) extrapolated along
the horizon, that direction gives roll and pitch at every stage.

One CasADi function: the real-time iteration's compiled feedback calls it inside its own
graph, every other user through its compiled library on numpy buffers.
"""

from __future__ import annotations

import casadi as ca

from m4.airframe import ROTOR_COUNT, Airframe
from companion.core import rom

ROLL, PITCH, YAW = rom.EULER.start, rom.EULER.start + 1, rom.EULER.start + 2
YAW_RATE = rom.RATES.start + 2


def hover_targets(af: Airframe, horizon: int, dt_s: float, hip_rad: float) -> ca.Function:
    """(x0 (20), x_ref ((N+1) * 20), d (6)) -> (reference ((N+1) * 20), input reference (N * 8)),
    the references stage after stage (numpy's (N+1, 20) and (N, 8) raveled), consistent with
    the disturbance d.

    Position, velocity, yaw and the rest come from x_ref; hips are set to hip_rad; roll and
    pitch are the equilibrium tilt; each rotor's thrust reference is a quarter of the
    equilibrium thrust (hip accelerations: 0).
    """
    x0, d = ca.SX.sym("x0", rom.NX), ca.SX.sym("d", rom.ND)
    x_ref = ca.SX.sym("x_ref", (horizon + 1) * rom.NX)
    need = d[:3] + ca.DM([0.0, 0.0, af.total_mass_kg * af.gravity_m_s2])   # what the thrust must cancel
    total = ca.sqrt(ca.sumsqr(need))
    z_n, z_e, z_d = ca.vertsplit(ca.if_else(total > 1e-9, need / total, ca.DM([0.0, 0.0, 1.0])))   # body z
    yaw = x0[YAW] + x0[YAW_RATE] * dt_s * ca.DM(range(horizon + 1))
    c, s = ca.cos(yaw), ca.sin(yaw)
    along = c * z_n + s * z_e                        # body z in the yawed frame: (s_p c_r, -s_r, c_p c_r)
    across = -s * z_n + c * z_e
    stages = ca.reshape(x_ref, rom.NX, horizon + 1)  # column k: stage k
    rows = [stages[i, :] for i in range(rom.NX)]
    rows[ROLL] = -ca.asin(ca.fmin(ca.fmax(across, -1.0), 1.0)).T
    rows[PITCH] = ca.atan2(along, z_d).T
    for i in range(rom.HIP.start, rom.HIP.stop):
        rows[i] = ca.SX(ca.DM.ones(1, horizon + 1) * hip_rad)
    inputs = ca.SX.zeros(rom.NU, horizon)
    inputs[rom.THRUST, :] = ca.repmat(total / ROTOR_COUNT, ROTOR_COUNT, horizon)
    return ca.Function(f"m4_nmpc_targets_n{horizon}", [x0, x_ref, d],
                       [ca.vec(ca.vertcat(*rows)), ca.vec(inputs)], ["x0", "x_ref", "d"], ["ref", "u_ref"])
