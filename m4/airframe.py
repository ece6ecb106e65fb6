"""The airframe: one TOML file read into a frozen dataclass, shared by every model. Figures
derived from the file (total mass, hover thrust, side pairs...) are computed once per
airframe (cached_property): the control loop and the plant read them every step.

Frames: body FRD (x forward, y right, z down); world local NED. Rotors are indexed 0..3 in
code and numbered 1..4 (PX4 quad-X) wherever a person reads them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from importlib import resources
from pathlib import Path

import numpy as np

from m4.toml_fields import ConfigError, Table, load_toml

ROTOR_COUNT = 4
REFERENCE_AIRFRAME = "m4_reference.toml"
# Where each leg lump sits along its leg, as a fraction of the hip-to-hub length: the hip
# block at the hip, the link's centre at mid-leg, the wheel + thruster at the hub.
LEG_LUMP_FRACTIONS = (0.0, 0.5, 1.0)


@dataclass(frozen=True)
class Airframe:
    name: str
    gravity_m_s2: float
    body_mass_kg: float
    body_inertia_diag_kg_m2: tuple[float, float, float]
    body_box_size_m: tuple[float, float, float]
    leg_hip_block_mass_kg: float
    leg_link_mass_kg: float
    leg_wheel_mass_kg: float
    leg_length_m: float
    wheel_radius_m: float
    wheel_width_m: float                # MuJoCo plant only (lump inertias, contact)
    hip_block_size_m: float             # MuJoCo plant only
    link_radius_m: float                # MuJoCo plant only
    hip_min_rad: float
    hip_max_rad: float
    same_side_sum_max_rad: float
    nominal_hip_rad: float
    hip_accel_max_rad_s2: float
    hip_rate_max_rad_s: float
    servo_time_constant_s: float
    frontal_servo_stiffness_n_m_per_rad: float
    frontal_servo_time_constant_s: float
    rotor_names: tuple[str, ...]
    hip_frd_m: tuple[tuple[float, float, float], ...]
    spin_sign: tuple[int, ...]          # +1: reaction moment +k_m T about body z (ccw), -1: cw
    moment_coefficient_m: float
    thrust_min_n: float
    thrust_max_n: float
    thrust_max_tight_n: float
    motor_time_constant_s: float        # plant only from here: the rotor's speed dynamics
    thrust_coefficient_n_s2: float      # k_t: thrust k_t w^2 at rotor speed w (rad/s)
    motor_kv_rpm_per_v: float
    motor_no_load_current_a: float
    motor_pole_pairs: int
    battery_cells: int
    battery_nominal_voltage_v: float    # the rotors' ratings hold at this pack voltage
    battery_capacity_mah: float
    battery_internal_resistance_ohm: float
    esc_telemetry_delay_s: float
    esc_serial_telemetry_hz: float
    esc_ambient_temperature_c: float
    esc_temperature_rise_c_per_a: float
    esc_thermal_time_constant_s: float
    drag_linear_n_s_m: float
    drag_quadratic_n_s2_m2: float
    drag_rotational_linear_n_m_s: float
    drag_yaw_quadratic_n_m_s2: float
    drag_rotor_n_s_m_per_rad_s: float   # plant only, in wind: rotor drag per rotor speed (sitl/plant/rotor_aero.py)
    inflow_reference_speed_m_s: float   # plant only, in wind: axial inflow that would cancel a rotor's thrust
    position_noise_m: float             # [sensors]: plant only, standard deviations
    velocity_noise_m_s: float
    attitude_noise_rad: float
    rate_noise_rad_s: float
    hip_noise_rad: float
    esc_rpm_noise_fraction: float
    esc_current_noise_a: float
    esc_voltage_noise_v: float

    # Derived quantities: computed from the fields above, never stored twice.
    @cached_property
    def leg_mass_kg(self) -> float:
        return self.leg_hip_block_mass_kg + self.leg_link_mass_kg + self.leg_wheel_mass_kg

    @cached_property
    def total_mass_kg(self) -> float:
        return self.body_mass_kg + ROTOR_COUNT * self.leg_mass_kg

    @cached_property
    def hover_thrust_per_rotor_n(self) -> float:
        return self.total_mass_kg * self.gravity_m_s2 / ROTOR_COUNT

    @cached_property
    def rotor_speed_max_rad_s(self) -> float:
        """Rotor speed at thrust_max_n: full throttle on the nominal battery voltage."""
        return math.sqrt(self.thrust_max_n / self.thrust_coefficient_n_s2)

    @cached_property
    def drag_torque_coefficient_n_m_s2(self) -> float:
        """k_q: the propeller's drag torque k_q w^2 (its reaction moment is k_m times its thrust)."""
        return self.moment_coefficient_m * self.thrust_coefficient_n_s2

    @cached_property
    def motor_back_emf_v_s_rad(self) -> float:
        """k_e of the motor (V per rad/s), which is also its torque constant (N m per A)."""
        return 60.0 / (2.0 * math.pi * self.motor_kv_rpm_per_v)

    @cached_property
    def motor_resistance_ohm(self) -> float:
        """Winding resistance that makes full throttle on the nominal voltage turn the propeller
        at rotor_speed_max_rad_s: V = k_e w + R (k_q w^2 / k_e + i0)."""
        w, k_e = self.rotor_speed_max_rad_s, self.motor_back_emf_v_s_rad
        current_a = self.drag_torque_coefficient_n_m_s2 * w * w / k_e + self.motor_no_load_current_a
        return (self.battery_nominal_voltage_v - k_e * w) / current_a

    @cached_property
    def leg_lumps(self) -> tuple[tuple[float, float], ...]:
        """(mass_kg, fraction of the leg length from the hip) of the hip block, link and wheel."""
        masses = (self.leg_hip_block_mass_kg, self.leg_link_mass_kg, self.leg_wheel_mass_kg)
        return tuple(zip(masses, LEG_LUMP_FRACTIONS))

    @cached_property
    def hip_positions_frd_m(self) -> np.ndarray:
        """(4, 3) hip_frd_m as an array (read-only: built once, shared by every caller)."""
        return _read_only(np.array(self.hip_frd_m, dtype=float))

    @cached_property
    def leg_direction_signs(self) -> np.ndarray:
        """(4, 2): signs (sx, sy) of each hip's x and y; the leg points along (sx cos q, sy sin q)
        (read-only)."""
        return _read_only(np.sign(self.hip_positions_frd_m[:, :2]))

    @cached_property
    def same_side_pairs(self) -> tuple[tuple[int, int], tuple[int, int]]:
        """Rotor indices on the right (y > 0) and on the left (y < 0) side of the body."""
        y = np.array(self.hip_frd_m)[:, 1]
        right = tuple(int(i) for i in np.flatnonzero(y > 0))
        left = tuple(int(i) for i in np.flatnonzero(y < 0))
        return right, left  # type: ignore[return-value]

    @cached_property
    def leg_swing_mass_kg(self) -> float:
        """Sum over a leg's lumps of mass x fraction of the reach: the mass that, carried at the
        hub, moves the centre of mass as the leg does."""
        return sum(m * f for m, f in self.leg_lumps)

    def thruster_positions_frd_m(self, hip_rad) -> np.ndarray:
        """(..., 4, 3) thruster hub positions in the body frame for sagittal angles hip_rad (..., 4);
        NaN for an angle that is not finite (an infinite angle has no position)."""
        q = _angles(hip_rad)
        s = self.leg_direction_signs
        out = np.broadcast_to(self.hip_positions_frd_m, q.shape + (3,)).copy()
        out[..., 0] += self.leg_length_m * s[:, 0] * np.cos(q)
        out[..., 1] += self.leg_length_m * s[:, 1] * np.sin(q)
        return out

    def com_offset_frd_m(self, hip_rad) -> np.ndarray:
        """Centre of mass of the whole robot relative to the hull centre, body frame, from the
        three lumps of every leg."""
        reach = self.thruster_positions_frd_m(hip_rad) - self.hip_positions_frd_m          # hip -> hub, per leg
        return (self._legs_at_hips_kg_m + self.leg_swing_mass_kg * reach.sum(axis=0)) / self.total_mass_kg

    @cached_property
    def _legs_at_hips_kg_m(self) -> np.ndarray:
        """The legs' masses at their hips: the first moment com_offset_frd_m starts from."""
        return _read_only(self.leg_mass_kg * self.hip_positions_frd_m.sum(axis=0))

    def com_offset_rate_frd_m_s(self, hip_rad, hip_rate_rad_s) -> np.ndarray:
        """d/dt of com_offset_frd_m(hip_rad) while the hips move at hip_rate_rad_s (NaN for an
        angle that is not finite)."""
        q, qd = _angles(hip_rad), np.asarray(hip_rate_rad_s, dtype=float)
        s = self.leg_direction_signs
        reach_rate = np.zeros((len(q), 3))
        reach_rate[:, 0] = -self.leg_length_m * s[:, 0] * np.sin(q) * qd
        reach_rate[:, 1] = self.leg_length_m * s[:, 1] * np.cos(q) * qd
        return self.leg_swing_mass_kg * reach_rate.sum(axis=0) / self.total_mass_kg


def _angles(hip_rad) -> np.ndarray:
    """Hip angles as floats, NaN where not finite: an infinite angle has no sine or cosine."""
    q = np.asarray(hip_rad, dtype=float)
    return np.where(np.isfinite(q), q, np.nan)


def _read_only(a: np.ndarray) -> np.ndarray:
    a.setflags(write=False)
    return a


def load_airframe(path: str | Path | None = None) -> Airframe:
    """Read an airframe file; None reads the bundled reference airframe."""
    if path is None:
        with resources.as_file(resources.files("m4.airframes") / REFERENCE_AIRFRAME) as p:
            return _parse(load_toml(p), p.name)
    return _parse(load_toml(path), Path(path).name)


def _parse(data: dict, filename: str) -> Airframe:
    top = Table(data, filename)
    body, leg, rotors, battery, esc, drag, sensors = (
        top.table(k, required=True) for k in ("body", "leg", "rotors", "battery", "esc", "drag", "sensors"))
    deg = math.radians
    spins = rotors.strings("spin", ROTOR_COUNT, choices=("ccw", "cw"))
    af = Airframe(
        name=top.string("name"),
        gravity_m_s2=top.number("gravity_m_s2", lo=0.0, lo_open=True),
        body_mass_kg=body.number("mass_kg", lo=0.0, lo_open=True),
        body_inertia_diag_kg_m2=body.vector("inertia_diag_kg_m2", 3, lo=1e-6),
        body_box_size_m=body.vector("box_size_m", 3, lo=1e-3),
        leg_hip_block_mass_kg=leg.number("hip_block_mass_kg", lo=0.0),
        leg_link_mass_kg=leg.number("link_mass_kg", lo=0.0),
        leg_wheel_mass_kg=leg.number("wheel_mass_kg", lo=0.0),
        leg_length_m=leg.number("length_m", lo=0.0, lo_open=True),
        wheel_radius_m=leg.number("wheel_radius_m", lo=0.0, lo_open=True),
        wheel_width_m=leg.number("wheel_width_m", lo=0.0, lo_open=True),
        hip_block_size_m=leg.number("hip_block_size_m", lo=0.0, lo_open=True),
        link_radius_m=leg.number("link_radius_m", lo=0.0, lo_open=True),
        hip_min_rad=deg(leg.number("hip_min_deg", lo=-180.0, hi=180.0)),
        hip_max_rad=deg(leg.number("hip_max_deg", lo=-180.0, hi=180.0)),
        same_side_sum_max_rad=deg(leg.number("same_side_sum_max_deg", lo=0.0, hi=360.0)),
        nominal_hip_rad=deg(leg.number("nominal_hip_deg", lo=-180.0, hi=180.0)),
        hip_accel_max_rad_s2=leg.number("hip_accel_max_rad_s2", lo=0.0, lo_open=True),
        hip_rate_max_rad_s=leg.number("hip_rate_max_rad_s", lo=0.0, lo_open=True),
        servo_time_constant_s=leg.number("servo_time_constant_s", lo=0.0),
        frontal_servo_stiffness_n_m_per_rad=leg.number("frontal_servo_stiffness_n_m_per_rad", lo=0.0, lo_open=True),
        frontal_servo_time_constant_s=leg.number("frontal_servo_time_constant_s", lo=0.0, lo_open=True),
        rotor_names=rotors.strings("names", ROTOR_COUNT),
        hip_frd_m=rotors.matrix("hip_frd_m", ROTOR_COUNT, 3, lo=-2.0, hi=2.0),
        spin_sign=tuple(1 if s == "ccw" else -1 for s in spins),
        moment_coefficient_m=rotors.number("moment_coefficient_m", lo=0.0),
        thrust_min_n=rotors.number("thrust_min_n", lo=0.0),
        thrust_max_n=rotors.number("thrust_max_n", lo=0.0, lo_open=True),
        thrust_max_tight_n=rotors.number("thrust_max_tight_n", lo=0.0, lo_open=True),
        motor_time_constant_s=rotors.number("motor_time_constant_s", lo=0.0, lo_open=True),
        thrust_coefficient_n_s2=rotors.number("thrust_coefficient_n_s2", lo=0.0, lo_open=True),
        motor_kv_rpm_per_v=rotors.number("motor_kv_rpm_per_v", lo=0.0, lo_open=True),
        motor_no_load_current_a=rotors.number("motor_no_load_current_a", lo=0.0),
        motor_pole_pairs=rotors.integer("motor_pole_pairs", lo=1, hi=50),
        battery_cells=battery.integer("cells", lo=1, hi=24),
        battery_nominal_voltage_v=battery.number("nominal_voltage_v", lo=0.0, lo_open=True),
        battery_capacity_mah=battery.number("capacity_mah", lo=0.0, lo_open=True),
        battery_internal_resistance_ohm=battery.number("internal_resistance_ohm", lo=0.0),
        esc_telemetry_delay_s=esc.number("telemetry_delay_s", lo=0.0, hi=0.1),
        esc_serial_telemetry_hz=esc.number("serial_telemetry_hz", lo=0.0, lo_open=True, hi=1000.0),
        esc_ambient_temperature_c=esc.number("ambient_temperature_c", lo=-40.0, hi=80.0),
        esc_temperature_rise_c_per_a=esc.number("temperature_rise_c_per_a", lo=0.0),
        esc_thermal_time_constant_s=esc.number("thermal_time_constant_s", lo=0.0, lo_open=True),
        drag_linear_n_s_m=drag.number("linear_n_s_m", lo=0.0),
        drag_quadratic_n_s2_m2=drag.number("quadratic_n_s2_m2", lo=0.0),
        drag_rotational_linear_n_m_s=drag.number("rotational_linear_n_m_s", lo=0.0),
        drag_yaw_quadratic_n_m_s2=drag.number("yaw_quadratic_n_m_s2", lo=0.0),
        drag_rotor_n_s_m_per_rad_s=drag.number("rotor_n_s_m_per_rad_s", lo=0.0),
        inflow_reference_speed_m_s=rotors.number("inflow_reference_speed_m_s", lo=0.0, lo_open=True),
        position_noise_m=sensors.number("position_noise_m", lo=0.0),
        velocity_noise_m_s=sensors.number("velocity_noise_m_s", lo=0.0),
        attitude_noise_rad=sensors.number("attitude_noise_rad", lo=0.0),
        rate_noise_rad_s=sensors.number("rate_noise_rad_s", lo=0.0),
        hip_noise_rad=sensors.number("hip_noise_rad", lo=0.0),
        esc_rpm_noise_fraction=sensors.number("esc_rpm_noise_fraction", lo=0.0, hi=0.5),
        esc_current_noise_a=sensors.number("esc_current_noise_a", lo=0.0),
        esc_voltage_noise_v=sensors.number("esc_voltage_noise_v", lo=0.0),
    )
    for t in (top, body, leg, rotors, battery, esc, drag, sensors):
        t.finish()
    if not af.hip_min_rad < af.nominal_hip_rad < af.hip_max_rad:
        raise ConfigError(f"{filename}: [leg] nominal_hip_deg must lie between hip_min_deg and hip_max_deg")
    if af.thrust_min_n >= af.thrust_max_n:
        raise ConfigError(f"{filename}: [rotors] thrust_min_n must be below thrust_max_n")
    if af.motor_resistance_ohm <= 0.0:
        raise ConfigError(f"{filename}: [rotors] motor_kv_rpm_per_v is too low to reach thrust_max_n on "
                          f"[battery] nominal_voltage_v (the motor's back-EMF alone exceeds it)")
    if np.any(af.leg_direction_signs == 0):
        raise ConfigError(f"{filename}: [rotors] hip_frd_m must put every hip off both body axes")
    return af
