"""The high-fidelity plant: the MuJoCo model of the M4 in flight, driven in NED/FRD.

Inputs are per-rotor thrusts (N) and sagittal hip angle targets (rad, with optional rates);
the plant adds what the reduced-order model leaves out: three lumps per leg, the frontal
joints and their stiff hold, the thrusters' motors and propellers (sitl/plant/thrusters.py) on a
battery (sitl/plant/battery.py), servo rate and acceleration limits, hull drag and ground contact,
and with a scenario's [wind] the air (sitl/plant/wind.py) and what it does to the rotors
(sitl/plant/rotor_aero.py). Faults and the scenario's [plant] mismatch are applied here. Frames are
converted in `sitl.plant.frames` only; everything public is NED/FRD.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from m4.airframe import ROTOR_COUNT, Airframe
from m4.attitude import euler_from_quat_wxyz, quat_wxyz_from_euler, rotation_ned_from_frd
from m4.fault_kind import INJECTABLE, FaultKind
from m4.scenario import PlantOptions, Wind
from m4.sensor_profiles import SensorProfile
from sitl.plant import frames
from sitl.plant.battery import Battery
from sitl.plant.drag import HullDrag
from sitl.plant.mjcf import PHYSICS_DT_S, compile_model
from sitl.plant.sensor_suite import SensorSuite
from sitl.plant.sensors import SensorNoise
from sitl.plant.hip_servos import REFERENCE_PERIOD_S, HipReference
from sitl.plant.rotor_aero import RotorAero
from sitl.plant.state import PlantState, RotorState, SensorSample
from sitl.plant.thrusters import Thrusters
from sitl.plant.wind import WindField

__all__ = ["Plant", "PlantOptions", "PlantState"]

_STEP_TOLERANCE_S = 1e-9
# Collision detection costs about a quarter of a physics step. It is skipped while the hull is
# so high that no part of the robot can reach the floor before the next check (every servo
# period: falling 1 m in 5 ms would take 200 m/s).
_CONTACT_CHECK_MARGIN_M = 1.0
_CONTACT_BIT = int(mujoco.mjtDisableBit.mjDSBL_CONTACT)
_NOMINAL_PLANT = PlantOptions()       # frozen: safe as a shared default


class Plant:
    physics_dt_s = PHYSICS_DT_S

    def __init__(self, airframe: Airframe, options: PlantOptions = _NOMINAL_PLANT, *,
                 start_ned_m=(0.0, 0.0, -2.0), start_yaw_rad: float = 0.0, seed: int = 0,
                 wind: Wind | None = None, sensors: SensorProfile | None = None):
        """Starts hovering at rest: nominal hips, every rotor at the hover thrust of this plant.
        wind None: still air, the calibrated plant alone (no rotor drag, no inflow). sensors
        None: no raw sensors (the FC reads measured_state(), the "ideal" profile)."""
        start = _vector("start_ned_m", start_ned_m, 3)
        if not (np.all(np.isfinite(start)) and math.isfinite(start_yaw_rad)):
            raise ValueError(f"start_ned_m and start_yaw_rad must be finite, got {start}, {start_yaw_rad}")
        self.airframe, self.options = airframe, options
        self.model = compile_model(airframe)
        self.data = mujoco.MjData(self.model)
        self._apply_mismatch()

        m, d = self.model, self.data
        mujoco.mj_resetDataKeyframe(m, d, m.key("hover").id)
        self._thrust = slice(m.actuator("thrust1").id, m.actuator("thrust1").id + ROTOR_COUNT)
        self._thrust_sq = slice(m.actuator("thrustsq1").id, m.actuator("thrustsq1").id + ROTOR_COUNT)
        self._hip_ctrl = slice(m.actuator("hip1").id, m.actuator("hip1").id + ROTOR_COUNT)
        self._rate_ctrl = slice(m.actuator("hiprate1").id, m.actuator("hiprate1").id + ROTOR_COUNT)
        self._thrust_act = _contiguous(m.actuator_actadr[self._thrust], "thrust filter states")
        self._thrust_sq_act = _contiguous(m.actuator_actadr[self._thrust_sq], "thrust filter states")
        # both filters' states in one write
        self._thrust_filters = _contiguous(m.actuator_actadr[self._thrust.start:self._thrust_sq.stop],
                                           "thrust filter states")
        self._hip_act = _contiguous(m.actuator_actadr[self._hip_ctrl], "hip reference states")
        # hip{i} and hiprate{i} both take the reference rate: one write for the eight of them.
        self._servo_ctrl = slice(self._hip_ctrl.start, self._rate_ctrl.stop)
        if self._rate_ctrl.start != self._hip_ctrl.stop:
            raise ValueError("the MJCF must list the hiprate actuators right after the hip ones")
        joints = [m.joint(f"sagittal{i + 1}") for i in range(ROTOR_COUNT)]
        self._hip_qpos = _evenly_spaced(np.array([m.jnt_qposadr[j.id] for j in joints]), "hip joints' positions")
        self._hip_qvel = _evenly_spaced(np.array([m.jnt_dofadr[j.id] for j in joints]), "hip joints' velocities")
        self._hull = m.body("hull").id
        root = m.joint("root")
        qpos0, qvel0 = m.jnt_qposadr[root.id], m.jnt_dofadr[root.id]
        self._pos, self._quat = slice(qpos0, qpos0 + 3), slice(qpos0 + 3, qpos0 + 7)
        self._vel, self._rates = slice(qvel0, qvel0 + 3), slice(qvel0 + 3, qvel0 + 6)
        self._drag = HullDrag(airframe, d.qvel[qvel0:qvel0 + 6], m.dof_damping[qvel0:qvel0 + 6],
                              d.xfrc_applied[self._hull, :3])
        self.wind: WindField | None = None
        self._wind_t0_s = 0.0
        self._rotor_aero: RotorAero | None = None
        if wind is not None:
            self.blow(wind, height_m=-float(start[2]), seed=seed)
        self._air_world_m_s: np.ndarray | None = None
        self._noise = SensorNoise(airframe, seed)

        self._thrust_max_n = airframe.thrust_max_n if options.thrust_max_n is None else options.thrust_max_n
        self._thrust_rated_max_n = np.full(ROTOR_COUNT, self._thrust_max_n)     # copied into every state
        self.hover_thrust_n = m.body_subtreemass[self._hull] * airframe.gravity_m_s2 / ROTOR_COUNT
        self._thrust_request_n = [float(self.hover_thrust_n)] * ROTOR_COUNT
        self.battery = Battery(airframe, options.battery, options.battery_charge)
        self.thrusters = Thrusters(airframe, self.hover_thrust_n, self.battery.voltage_v)
        d.ctrl[self._thrust_sq] = 0.0        # the second thrust filter only decays from the state it is set to
        self._apply_thrust()

        d.qpos[self._pos] = frames.flip_vector(start)
        d.qpos[self._quat] = frames.flip_quat_wxyz(quat_wxyz_from_euler((0.0, 0.0, start_yaw_rad)))
        self._hip_target = [float(airframe.nominal_hip_rad)] * ROTOR_COUNT      # Python floats
        self._hips = HipReference(self._hip_target, rate_max_rad_s=airframe.hip_rate_max_rad_s,
                                  accel_max_rad_s2=airframe.hip_accel_max_rad_s2,
                                  hip_min_rad=airframe.hip_min_rad, hip_max_rad=airframe.hip_max_rad,
                                  dt_s=REFERENCE_PERIOD_S)
        self._state: PlantState | None = None      # state() at the current instant, until anything changes
        self._servo_period_steps = round(REFERENCE_PERIOD_S / self.physics_dt_s)
        self._servo_countdown = 0
        self._contact_height_m = _reach_m(airframe) + _CONTACT_CHECK_MARGIN_M
        self._contact_off: bool | None = None      # None: the option not yet set by the gate
        self._gate_contact()
        d.act[self._hip_act] = self._hips.pos_rad
        d.ctrl[self._hip_ctrl] = d.ctrl[self._rate_ctrl] = 0.0
        mujoco.mj_forward(m, d)
        self.sensors = None if sensors is None else SensorSuite(
            sensors, seed=seed, mass_kg=float(m.body_subtreemass[self._hull]), gravity_m_s2=airframe.gravity_m_s2,
            turn_sense_frd_z=-np.array(airframe.spin_sign), start_vel_ned_m_s=np.zeros(3))

    def _apply_mismatch(self) -> None:
        """[plant] mass_scale scales every mass; inertia_scale scales every body's own inertia
        on top of that (the leg lumps stay where they are)."""
        m, o = self.model, self.options
        m.body_mass[1:] *= o.mass_scale
        m.body_inertia[1:] *= o.mass_scale * o.inertia_scale
        mujoco.mj_setConst(m, self.data)

    def _apply_thrust(self) -> None:
        self._state = None
        lo_n, hi_n = self.airframe.thrust_min_n, self._thrust_max_n
        # np.clip on floats, its max and min written out (the builtins' calls cost more at every tick)
        esc_cmd_n = [lo_n if lo_n > t else t for t in self._thrust_request_n]
        self._esc_cmd_n = [hi_n if hi_n < t else t for t in esc_cmd_n]
        self.thrusters.command(self._esc_cmd_n)
        self._update_rotors()

    def _update_rotors(self) -> None:
        """The rotors' targets on the present pack voltage, written into the two thrust filters
        of every rotor (sitl/plant/mjcf.py): with w = w_s + d exp(-t / tau), k_t w^2 is
        k_t w_s^2 + 2 k_t w_s d exp(-t / tau) + k_t d^2 exp(-2 t / tau)."""
        rotors, d = self.thrusters, self.data
        rotors.update(self.battery.voltage_v)
        # the four rotors written out, on Python floats: this runs at every FC tick
        (k0, k1, k2, k3), (s0, s1, s2, s3), (w0, w1, w2, w3) = rotors.filter_inputs()
        g0, g1, g2, g3 = w0 - s0, w1 - s1, w2 - s2, w3 - s3
        d.ctrl[self._thrust] = (k0 * (s0 * s0), k1 * (s1 * s1), k2 * (s2 * s2), k3 * (s3 * s3))
        d.act[self._thrust_filters] = (k0 * s0 * (s0 + 2.0 * g0), k1 * s1 * (s1 + 2.0 * g1), k2 * s2 * (s2 + 2.0 * g2),
                                       k3 * s3 * (s3 + 2.0 * g3),
                                       k0 * (g0 * g0), k1 * (g1 * g1), k2 * (g2 * g2), k3 * (g3 * g3))

    def command_thrust(self, thrust_n) -> None:
        """Thrusts alone (N, rotors 1..4), the hips' targets kept: the FC's rate feedback
        between setpoints. Clamped as in command(); a non-finite entry keeps its value."""
        thrust = _floats("thrust_n", thrust_n, ROTOR_COUNT)
        self._thrust_request_n = [t if math.isfinite(t) else kept for t, kept in zip(thrust, self._thrust_request_n)]
        self._apply_thrust()

    def command(self, thrust_n, hip_rad, hip_rate_rad_s=None) -> None:
        """Thrusts (N, rotors 1..4) and hip targets (rad) with their rates (rad/s, default 0).
        Thrusts are clamped to [thrust_min, current limit], hip angles to the joint range and
        rates to the servo's rate limit; a non-finite entry keeps that entry's previous value
        (a rate: 0)."""
        self.command_thrust(thrust_n)
        self.command_hips(hip_rad, hip_rate_rad_s)

    def command_throttle(self, throttle) -> None:
        """Throttles 0..1 (rotors 1..4, clamped): each ESC drives its motor at throttle x pack
        voltage (an autopilot's PWM output, which linearises thrust itself), the hips' targets
        kept. thrust_cmd_n then reports what the nominal rotor settles at on that throttle."""
        throttle = _vector("throttle", throttle, ROTOR_COUNT)
        if not np.all(np.isfinite(throttle)):
            raise ValueError(f"throttle must be finite, got {throttle}")
        self._state = None
        self.thrusters.command_duty(throttle.tolist())
        self._esc_cmd_n = self.thrusters.duty_thrust_n(self.battery.voltage_v)
        self._update_rotors()

    def command_hips(self, hip_rad, hip_rate_rad_s=None) -> None:
        """Hip targets (rad) with their rates (rad/s, default 0), the thrusts kept; clamped and
        kept as in command()."""
        hip = _floats("hip_rad", hip_rad, ROTOR_COUNT)
        rate = [0.0] * ROTOR_COUNT if hip_rate_rad_s is None else _floats("hip_rate_rad_s", hip_rate_rad_s, ROTOR_COUNT)
        self._hip_target = [q if math.isfinite(q) else kept for q, kept in zip(hip, self._hip_target)]
        self._hips.set_target(self._hip_target, [r if math.isfinite(r) else 0.0 for r in rate])
        self._servo_countdown = 0           # the servo controller (and drag, gate) react at the next step

    def set_rotor_loss(self, rotor: int, loss: float, kind: FaultKind = FaultKind.DEGRADED) -> None:
        """Rotor 1..4 fails as `kind` (sitl/plant/thrusters.py); loss 0 restores it. The default,
        DEGRADED: its max thrust becomes (1 - loss) x the airframe's hover thrust, 1.0 stops it."""
        if isinstance(rotor, bool) or not isinstance(rotor, (int, np.integer)) or not 1 <= rotor <= ROTOR_COUNT:
            raise ValueError(f"rotor must be an integer 1..{ROTOR_COUNT}, got {rotor!r}")
        if not (isinstance(loss, (int, float)) and 0.0 <= loss <= 1.0):
            raise ValueError(f"loss must be a number in [0, 1], got {loss!r}")
        if kind not in INJECTABLE:
            raise ValueError(f"kind must be one of {', '.join(k.label for k in INJECTABLE)}, got {kind!r}")
        self.thrusters.set_fault(rotor - 1, float(loss), FaultKind(kind))
        self._state = None
        self._update_rotors()

    def step(self, duration_s: float) -> None:
        """Advance the physics by duration_s, a whole number of physics steps."""
        n = round(duration_s / self.physics_dt_s)
        if n < 0 or abs(n * self.physics_dt_s - duration_s) > _STEP_TOLERANCE_S:
            raise ValueError(f"duration_s must be a non-negative multiple of {self.physics_dt_s} s, got {duration_s}")
        # The servo controller, the drag coefficients and the contact gate update once per servo
        # period; MuJoCo runs the physics steps in between in one call.
        m, d, dt_s = self.model, self.data, self.physics_dt_s
        if n > 0:
            self._state = None
        while n > 0:
            if self._servo_countdown == 0:
                self._servo_countdown = self._servo_period_steps
                self._gate_contact()
                self._update_air()
                if not self._hips.settled:
                    self._update_servo_reference()
            k = min(n, self._servo_countdown)
            if self.sensors is not None:
                k = min(k, self._sensor_countdown())
            # The rotor model and the pack advance one physics step at a time, so the same flight
            # gives the same numbers whatever lengths the caller steps by (those depend on when
            # commands arrive); a sagging pack feeds back into the thrusts at every step.
            if self.battery.sags:
                for _ in range(k):
                    mujoco.mj_step(m, d)
                    self.battery.draw(self.thrusters.advance_drawing(dt_s, 1)[0], dt_s)
                    self._update_rotors()        # the rotors head for their targets on the pack's new voltage
            else:
                mujoco.mj_step(m, d, nstep=k)
                self.battery.draw_each(self.thrusters.advance_drawing(dt_s, k), dt_s)
            self._servo_countdown -= k
            n -= k
            if self.sensors is not None and self._sensor_countdown() == self.sensors.period_ms:
                self._sense()

    def _now_ms(self) -> int:
        return round(self.data.time * 1000.0)

    def _sensor_countdown(self) -> int:
        """Physics steps (1 ms) to the next IMU instant."""
        return self.sensors.period_ms - self._now_ms() % self.sensors.period_ms

    def _sense(self) -> None:
        d, rotors = self.data, self.thrusters
        self.sensors.sample(self._now_ms(), frames.flip_vector(d.qpos[self._pos]), frames.flip_vector(d.qvel[self._vel]),
                            frames.flip_quat_wxyz(d.qpos[self._quat]), frames.flip_vector(d.qvel[self._rates]),
                            rotors.speed_rad_s, rotors.kind, rotors.loss)

    def blow(self, wind: Wind, height_m: float, seed: int = 0) -> None:
        """From now on the robot flies in `wind`: its turbulence that of `height_m` above the
        ground, its gusts timed from now. For a plant that waits in still air for its scenario
        (ArduPilot's JSON physics boots on the floor; the scenario starts once it holds its start)."""
        self.wind = WindField(wind, height_m=height_m, seed=seed)
        self._wind_t0_s = float(self.data.time)
        self._rotor_aero = RotorAero(self.airframe, self.model, self.data, (self._thrust, self._thrust_sq))

    def _wind_ned_m_s(self) -> np.ndarray | None:
        """The air's velocity over the ground now, NED (None: still air)."""
        return None if self.wind is None else self.wind.velocity_ned_m_s(float(self.data.time) - self._wind_t0_s)

    def take_sensor_samples(self) -> list[SensorSample]:
        """The raw sensors' samples heard since the last call, up to now (none without [sensors])."""
        return [] if self.sensors is None else self.sensors.take(self._now_ms())

    def _update_air(self) -> None:
        """Hull drag, and in wind the air's loads on the hull and the rotors, for the next servo period."""
        if self.wind is not None:
            self._air_world_m_s = frames.flip_vector(self._wind_ned_m_s())
            self._rotor_aero.update(self._air_world_m_s, self.thrusters.speed_rad_s)
        self._drag.update(self._air_world_m_s)

    def _gate_contact(self) -> None:
        """Contacts off above the contact height, on below it (MuJoCo's option written only when
        that changes: a write through the bindings costs more than the test)."""
        off = bool(self.data.qpos[self._pos.stop - 1] > self._contact_height_m)
        if off != self._contact_off:
            self._contact_off = off
            opt = self.model.opt
            opt.disableflags = opt.disableflags | _CONTACT_BIT if off else opt.disableflags & ~_CONTACT_BIT

    def _update_servo_reference(self) -> None:
        d, hips = self.data, self._hips
        d.act[self._hip_act] = hips.pos_rad        # the reference angle where this period starts
        hips.advance()
        d.ctrl[self._servo_ctrl] = hips.rate_rad_s * 2

    def state(self) -> PlantState:
        """The truth (computed once per instant and command: the flight controller and the truth
        log both read it; treat its arrays as read-only)."""
        if self._state is None:
            self._state = self._compute_state()
        return self._state

    def rotor_state(self) -> RotorState:
        """The rotors' part of state(), without computing the rest (the FC reads it every tick)."""
        speed_rad_s, current_a = self.thrusters.esc_readings()
        return RotorState(rotor_speed_rad_s=speed_rad_s, esc_current_a=current_a,
                          battery_voltage_v=self.battery.voltage_v, thrust_cmd_n=list(self._esc_cmd_n))

    def _compute_state(self) -> PlantState:
        m, d = self.model, self.data
        mujoco.mj_forward(m, d)
        quat = frames.flip_quat_wxyz(d.qpos[self._quat])
        filters = d.act[self._thrust_filters]
        thrust_n = filters[:ROTOR_COUNT] + filters[ROTOR_COUNT:]
        if self._rotor_aero is not None:
            thrust_n = thrust_n * self._rotor_aero.inflow_factor
        return PlantState(
            time_s=float(d.time),
            pos_ned_m=frames.flip_vector(d.qpos[self._pos]),
            vel_ned_m_s=frames.flip_vector(d.qvel[self._vel]),
            quat_wxyz=quat,
            euler_rad=euler_from_quat_wxyz(quat),
            rates_frd_rad_s=frames.flip_vector(d.qvel[self._rates]),
            hip_rad=d.qpos[self._hip_qpos].copy(),
            hip_rate_rad_s=d.qvel[self._hip_qvel].copy(),
            thrust_cmd_n=np.array(self._esc_cmd_n),
            thrust_n=thrust_n,
            thrust_limit_n=self.thrusters.thrust_ceiling_n(self._thrust_max_n),
            thrust_rated_max_n=self._thrust_rated_max_n.copy(),
            rotor_speed_rad_s=self.thrusters.speed_rad_s,
            esc_current_a=self.thrusters.current_a,
            fault_kind=self.thrusters.kind.copy(),
            battery_voltage_v=self.battery.voltage_v,
            battery_consumed_mah=self.battery.consumed_mah,
            com_ned_m=frames.flip_vector(d.subtree_com[self._hull]),
            on_ground=bool(d.ncon > 0),
            wind_ned_m_s=self._wind_ned_m_s(),
        )

    def specific_force_frd_m_s2(self) -> np.ndarray:
        """The accelerometer at the hull centre (truth): its acceleration less gravity, in body
        FRD (m/s^2); at rest (0, 0, -g)."""
        s = self.state()               # runs mj_forward: qacc is the acceleration at this instant
        accel_ned = frames.flip_vector(self.data.qacc[self._vel])
        gravity_ned = frames.flip_vector(self.model.opt.gravity)
        return rotation_ned_from_frd(s.euler_rad).T @ (accel_ned - gravity_ned)

    def measured_rates_frd_rad_s(self) -> np.ndarray:
        """The gyro: measured_state().rates_frd_rad_s, without computing the rest of the state."""
        rates = frames.flip_vector(self.data.qvel[self._rates])
        return self._noise.measure_rates(float(self.data.time), rates) if self.options.sensor_noise else rates

    def measured_state(self) -> PlantState:
        """The truth, plus sensor noise when the options ask for it."""
        truth = self.state()
        return self._noise.measure(truth) if self.options.sensor_noise else truth


def _reach_m(af: Airframe) -> float:
    """Largest distance from the hull centre of any point that can touch the floor, any posture."""
    hull = 0.5 * float(np.linalg.norm(af.body_box_size_m))
    hips = np.linalg.norm(np.array(af.hip_frd_m), axis=1).max()
    return max(hull, float(hips) + af.leg_length_m + math.hypot(af.wheel_radius_m, af.wheel_width_m / 2))


def _evenly_spaced(addresses: np.ndarray, what: str) -> slice:
    """The addresses as a slice (reading through it is cheaper than indexing by an array)."""
    step = int(addresses[1] - addresses[0]) if len(addresses) > 1 else 1
    if step < 1 or not np.array_equal(addresses, addresses[0] + step * np.arange(len(addresses))):
        raise ValueError(f"the MJCF must keep the {what} evenly spaced, got addresses {addresses}")
    return slice(int(addresses[0]), int(addresses[-1]) + 1, step)


def _contiguous(addresses: np.ndarray, what: str) -> slice:
    if not np.array_equal(addresses, np.arange(addresses[0], addresses[0] + len(addresses))):
        raise ValueError(f"the MJCF must keep the {what} contiguous, got addresses {addresses}")
    return slice(int(addresses[0]), int(addresses[0]) + len(addresses))


def _floats(name: str, value, length: int) -> list[float]:
    """_vector(name, value, length) as Python floats; a list of them (the FC's fast loop, every
    tick) without a round trip through numpy, an array of them through its tolist()."""
    if type(value) is np.ndarray and value.shape == (length,) and value.dtype == np.float64:
        return value.tolist()
    if type(value) is list and len(value) == length:
        try:
            return [float(v) for v in value]
        except (TypeError, ValueError):
            pass                           # _vector says what is wrong
    return _vector(name, value, length).tolist()


def _vector(name: str, value, length: int) -> np.ndarray:
    try:
        v = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be {length} numbers, got {value!r}") from None
    if v.shape != (length,):
        raise ValueError(f"{name} must be {length} numbers, got shape {v.shape}")
    return v
