"""Aerodynamic drag on the hull, per the airframe's [drag] table (the same law as the ROM).

    force   = -(linear + quadratic |v|) v              world frame, at the hull centre
    torque  = -(rotational_linear) w - yaw_quadratic |w_z| w_z e_z      body frame

Both laws keep their form under the NWU/FLU <-> NED/FRD flip, so they are applied directly
to the free joint's generalized forces: its first three dofs are the world-frame translation
of the hull centre, the last three the body-frame rotation. Pure Python floats, once per
physics step.
"""

from __future__ import annotations

import math

import numpy as np

from companion.airframe import Airframe


class HullDrag:
    def __init__(self, af: Airframe, qvel: np.ndarray, qfrc: np.ndarray):
        """qvel, qfrc: views of the free joint's six dofs in MjData.qvel and MjData.qfrc_applied."""
        self._lin, self._quad = af.drag_linear_n_s_m, af.drag_quadratic_n_s2_m2
        self._rot, self._yaw_quad = af.drag_rotational_linear_n_m_s, af.drag_yaw_quadratic_n_m_s2
        self._qvel, self._qfrc = qvel, qfrc

    def apply(self) -> None:
        vx, vy, vz, wx, wy, wz = self._qvel.tolist()
        c = -(self._lin + self._quad * math.sqrt(vx * vx + vy * vy + vz * vz))
        rot = -self._rot
        self._qfrc[:] = (c * vx, c * vy, c * vz, rot * wx, rot * wy, (rot - self._yaw_quad * abs(wz)) * wz)
