"""Aerodynamic drag on the hull, per the airframe's [drag] table (the same law as the ROM).

    force   = -(linear + quadratic |v|) v              world frame, at the hull centre
              v: the hull's velocity relative to the air (over the ground in still air)
    torque  = -(rotational_linear) w - yaw_quadratic |w_z| w_z e_z      body frame

Both laws keep their form under the NWU/FLU <-> NED/FRD flip. They are applied as the
damping of the free joint's six dofs (its first three are the world-frame translation of
the hull centre, the last three the body-frame rotation), which MuJoCo integrates implicitly
at every physics step: the coefficients are linear + quadratic |v| for the translation and
rotational_linear (+ yaw_quadratic |w_z| about z) for the rotation. Only the speeds inside
the coefficients are refreshed, once per `update()` call (every servo period); drag time
constants are seconds, so the coefficients lag by a negligible 5 ms.

In wind (air velocity w over the ground) the damping stays -c v on the hull's own velocity,
integrated implicitly as before, and the rest of -c (v - w), the force c w, is applied through
the hull's `xfrc_applied` (at its centre of mass, the hull centre), with c from |v - w|. Still
air takes the first branch alone, the numbers of the calibrated plant unchanged.
"""

from __future__ import annotations

import math

import numpy as np

from m4.airframe import Airframe


class HullDrag:
    def __init__(self, af: Airframe, qvel: np.ndarray, damping: np.ndarray, force: np.ndarray | None = None):
        """qvel, damping: views of the free joint's six dofs in MjData.qvel and MjModel.dof_damping;
        force: the view of the hull's force in MjData.xfrc_applied (world frame), needed in wind."""
        self._lin, self._quad = af.drag_linear_n_s_m, af.drag_quadratic_n_s2_m2
        self._rot, self._yaw_quad = af.drag_rotational_linear_n_m_s, af.drag_yaw_quadratic_n_m_s2
        self._qvel, self._damping, self._force = qvel, damping, force
        self.update()

    def update(self, air_world_m_s: np.ndarray | None = None) -> None:
        """air_world_m_s: the air's velocity over the ground in MuJoCo's world frame (None: still air)."""
        vx, vy, vz, _, _, wz = self._qvel.tolist()
        if air_world_m_s is not None:
            ax, ay, az = air_world_m_s.tolist()
            vx, vy, vz = vx - ax, vy - ay, vz - az
        c = self._lin + self._quad * math.sqrt(vx * vx + vy * vy + vz * vz)
        if air_world_m_s is not None:
            self._force[:] = c * air_world_m_s
        rot = self._rot
        self._damping[:] = (c, c, c, rot, rot, rot + self._yaw_quad * abs(wz))
