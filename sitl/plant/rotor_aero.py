"""What the air does to the rotors, with a scenario's [wind] (sitl/plant/wind.py).

For rotor i, hub velocity relative to the air v (world frame), thrust axis n (the hub's +z),
rotor speed w (rad/s), from the airframe:
- Rotor drag (Faessler, Franchi, Scaramuzza 2018, "Differential flatness of quadrotor dynamics
  subject to rotor drag"; Martin and Salaun 2010): a force at the hub against the air's
  velocity in the rotor plane, proportional to the rotor's speed,
      F_i = -c w_i (v - (v . n) n),          c = [drag] rotor_n_s_m_per_rad_s.
  A stopped rotor or a lost propeller feels none.
- Inflow: the thrust falls with the air's axial velocity through the disk (positive when the
  rotor moves along its thrust axis, climbing into the air) and rises when the air comes from
  below, T_i = k_t w_i^2 f_i with f_i = 1 - (v . n) / v_ref clipped to [0, INFLOW_FACTOR_MAX],
  v_ref = [rotors] inflow_reference_speed_m_s (linearised blade-element momentum theory; the
  airframe file gives the numbers). The rotor's reaction moment scales with it (both are the
  actuators' gear x f_i); the motor's speed does not feel the changed load (the ESC's RPM is
  what the rotor model says), so the flight controller's ESC-implied thrust k_t w^2 misses f_i
  as a real one would.

Both act on MuJoCo's side: the drag through each hub's `xfrc_applied` (the hub is its body's
centre of mass), the inflow through the thrust actuators' gear. They are refreshed with the
hull drag, once per servo period, from the state of the previous physics step.
"""

from __future__ import annotations

import mujoco
import numpy as np

from m4.airframe import ROTOR_COUNT, Airframe

INFLOW_FACTOR_MAX = 1.5          # descending into its own wake a rotor meets the vortex ring: not modelled


class RotorAero:
    def __init__(self, af: Airframe, model: mujoco.MjModel, data: mujoco.MjData,
                 thrust_actuators: tuple[slice, slice]):
        """thrust_actuators: the `thrust{i}` and `thrustsq{i}` actuators (their gears are scaled)."""
        self._m, self._d = model, data
        self._c = af.drag_rotor_n_s_m_per_rad_s
        self._v_ref = af.inflow_reference_speed_m_s
        self._hubs = [model.body(f"wheel{i + 1}").id for i in range(ROTOR_COUNT)]
        self._actuators = thrust_actuators
        self._gear = [model.actuator_gear[a].copy() for a in thrust_actuators]
        self._velocity = np.zeros(6)
        self.inflow_factor = np.ones(ROTOR_COUNT)

    def update(self, air_world_m_s: np.ndarray, speed_rad_s: np.ndarray) -> None:
        m, d = self._m, self._d
        for i, body in enumerate(self._hubs):
            mujoco.mj_objectVelocity(m, d, mujoco.mjtObj.mjOBJ_BODY, body, self._velocity, 0)
            v = self._velocity[3:] - air_world_m_s
            n = d.xmat[body, 2::3]                       # the hub's z axis in the world: xmat's third column
            axial = float(v @ n)
            d.xfrc_applied[body, :3] = -self._c * speed_rad_s[i] * (v - axial * n)
            self.inflow_factor[i] = min(max(1.0 - axial / self._v_ref, 0.0), INFLOW_FACTOR_MAX)
        for actuators, gear in zip(self._actuators, self._gear):
            m.actuator_gear[actuators] = gear * self.inflow_factor[:, None]
