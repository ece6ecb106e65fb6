"""The four thrusters as a real plant has them: an ESC, a DC motor and a propeller each.

Rotor speed w (rad/s) heads for the speed at which the motor settles with a first-order lag
(the airframe's motor_time_constant_s): w(t) = w_settled + (w0 - w_settled) exp(-t / tau),
exact between updates. The propeller gives thrust k_t w^2 and drag torque k_q w^2 with
k_q = k_m k_t. The motor (back-EMF and torque constant k_e, winding resistance R, no-load
current i0) on ESC output voltage u settles where its torque carries the propeller's drag:
k_e ((u - k_e w) / R - i0) = k_q w^2. Its current is (u - k_e w) / R (never below 0: an
ESC braking the rotor reports no current), the pack sees u / V of it.

The ESC command is the FC's thrust turned into the speed the nominal propeller needs for it,
and that speed into the throttle that turns the nominal propeller at it on the present pack
voltage V (the FC's thrust linearisation with battery-voltage compensation), at most full
throttle. So a healthy rotor turns at the commanded speed below its ceiling, and a sagging
pack lowers every rotor's ceiling together. An autopilot that linearises thrust itself
(ArduPilot's MOT_THST_EXPO) commands the throttle instead (`command_duty`): the ESC drives its
motor at duty x V.

Failure kinds (m4.fault_kind.FaultKind, the dialect's M4_FAULT_KIND), per rotor:
- DEGRADED: the motor cannot exceed the speed at which the healthy propeller gives
  (1 - loss) x hover thrust (its ESC output is capped there); loss 1 stops it.
- MOTOR: motor or ESC dead: no drive, no current; the rotor spins down at its time constant.
- PROPELLER: propeller lost: no thrust, no drag torque; the unloaded motor overspeeds to its
  no-load speed for the same throttle and draws only its no-load current.
- DAMAGE: a chipped propeller: k_t and k_q x (1 - loss) at the same speed (the lighter load
  lets the motor turn a little faster).
"""

from __future__ import annotations

import math

import numpy as np

from m4.airframe import ROTOR_COUNT, Airframe
from m4.fault_kind import FaultKind
from m4.units import RAD_S_TO_RPM

HEALTHY = -1                   # fault_kind of a healthy rotor (truth)


_MOTOR, _PROPELLER, _DAMAGE, _DEGRADED = (int(k) for k in (FaultKind.MOTOR, FaultKind.PROPELLER,
                                                            FaultKind.DAMAGE, FaultKind.DEGRADED))


class Thrusters:
    """Per-rotor state on Python floats (lists of four): the FC commands the rotors at every
    4 ms tick, a sagging pack at every physics step, and numpy on four-element arrays costs
    more than the sums. The public arrays are built from them when asked for."""

    def __init__(self, af: Airframe, thrust_n: float, voltage_v: float):
        """Four healthy rotors settled at `thrust_n` each."""
        self._tau_s = af.motor_time_constant_s
        self._k_t, self._k_q = af.thrust_coefficient_n_s2, af.drag_torque_coefficient_n_m_s2
        self._k_e, self._r, self._i0 = af.motor_back_emf_v_s_rad, af.motor_resistance_ohm, af.motor_no_load_current_a
        self._k_e_sq, self._k_e_4 = self._k_e ** 2, self._k_e ** 4
        self._friction_v = self._r * self._i0              # the drive the no-load current takes
        self._hover_n = af.hover_thrust_per_rotor_n
        self.kind = np.full(ROTOR_COUNT, HEALTHY)
        self.loss = np.zeros(ROTOR_COUNT)
        self._scale = [1.0] * ROTOR_COUNT                  # the propellers' k_t and k_q / the nominal ones
        self._k_t_now = [self._k_t] * ROTOR_COUNT          # k_t x scale: 0 without a propeller
        self._k_q_now = [self._k_q] * ROTOR_COUNT          # k_q x scale
        self._u_max_v = [math.inf] * ROTOR_COUNT           # what each motor may be driven with
        self._driven = [True] * ROTOR_COUNT                # False: motor or ESC dead, no current
        self._speed_cmd = [float(self.speed_for_thrust(thrust_n))] * ROTOR_COUNT
        self._duty: list[float] | None = None              # set: the ESCs are driven at duty x V (command_duty)
        self._speed = list(self._speed_cmd)                # rad/s
        self.voltage_v = voltage_v
        self._ceiling: tuple[float, float, np.ndarray] | None = None   # (thrust_max_n, voltage_v, ceiling)
        self.update(voltage_v)

    # -- what the ESCs are told -------------------------------------------------------------
    def speed_for_thrust(self, thrust_n):
        """The speed at which the nominal propeller gives `thrust_n`."""
        return np.sqrt(np.maximum(thrust_n, 0.0) / self._k_t)

    def command(self, thrust_n) -> None:
        """The ESC commands: thrusts (N, four) through the nominal propeller. Call update() after."""
        k_t = self._k_t
        self._speed_cmd = [math.sqrt((0.0 if 0.0 > t else t) / k_t) for t in thrust_n]      # max(t, 0)
        self._duty = None

    def command_duty(self, duty) -> None:
        """The ESC commands as throttles (four, clamped to 0..1): each ESC drives its motor at
        duty x pack voltage, with no thrust linearisation. Call update() after."""
        self._duty = [min(max(float(x), 0.0), 1.0) for x in duty]

    def duty_thrust_n(self, voltage_v: float) -> list[float]:
        """What the nominal rotor settles at on the present duties and pack voltage `voltage_v`
        (the thrust an autopilot's throttle stands for; command_duty must have been called)."""
        speeds = self._settled_speeds([d * voltage_v for d in self._duty], [self._k_q] * ROTOR_COUNT)
        return [self._k_t * w ** 2 for w in speeds]

    def set_fault(self, index: int, loss: float, kind: FaultKind) -> None:
        """The rotor at `index` (0..3 into the arrays: rotor index + 1) fails; loss 0 restores
        it. Call update() after."""
        restored = loss == 0.0
        self.kind[index] = kind = HEALTHY if restored else int(kind)
        self.loss[index] = loss = 0.0 if restored else loss
        self._scale[index] = {_PROPELLER: 0.0, _DAMAGE: 1.0 - loss}.get(kind, 1.0)
        self._k_t_now[index] = self._k_t * self._scale[index]
        self._k_q_now[index] = self._k_q * self._scale[index]
        ceiling_v = self._drive_voltages([float(self.speed_for_thrust((1.0 - loss) * self._hover_n))])[0]
        self._u_max_v[index] = {_MOTOR: 0.0, _DEGRADED: ceiling_v}.get(kind, math.inf)
        self._driven[index] = kind != _MOTOR
        self._ceiling = None

    # -- the motor ------------------------------------------------------------------------
    # Each takes and gives lists, one entry a rotor: the FC commands the rotors at every tick
    # (`c if c > x else x` is max(x, c), `c if c < x else x` min(x, c), without the builtin's call: it costs several times the comparison, and these run at every tick).
    def _drive_voltages(self, speed_rad_s: list[float]) -> list[float]:
        """The motor voltages that settle the nominal propeller at `speed_rad_s` (0 at rest)."""
        k_e, r, k_q, i0 = self._k_e, self._r, self._k_q, self._i0
        return [k_e * w + r * (k_q * w * w / k_e + i0) if w > 0.0 else 0.0 for w in speed_rad_s]

    def _settled_speeds(self, u_v: list[float], k_q: list[float]) -> list[float]:
        """Roots of k_q R w^2 + k_e^2 w - k_e (u - R i0) = 0 (0 where u cannot beat friction)."""
        k_e, r, friction_v, k_e_sq, k_e_4 = self._k_e, self._r, self._friction_v, self._k_e_sq, self._k_e_4
        speeds = []
        for u, k in zip(u_v, k_q):
            drive = u - friction_v
            drive = k_e * (0.0 if 0.0 > drive else drive)
            speeds.append(2.0 * drive / (k_e_sq + math.sqrt(k_e_4 + 4.0 * k * r * drive)))
        return speeds

    def _settle(self, drive_v: list[float], voltage_v: float) -> tuple[list[float], list[float]]:
        """(ESC output voltage, settled speed) for the drive voltages asked for (four), at most the
        pack's, faults applied."""
        u = [voltage_v if voltage_v < r else r for r in drive_v]
        u = [u_max if u_max < u_v else u_v for u_v, u_max in zip(u, self._u_max_v)]
        return u, self._settled_speeds(u, self._k_q_now)

    def update(self, voltage_v: float) -> None:
        """Recompute what every rotor heads for, on pack voltage `voltage_v`."""
        self.voltage_v = voltage_v
        drive_v = ([d * voltage_v for d in self._duty] if self._duty is not None
                   else self._drive_voltages(self._speed_cmd))
        self._u_v, self._settled = self._settle(drive_v, voltage_v)

    def advance(self, dt_s: float) -> None:
        decay = math.exp(-dt_s / self._tau_s)
        self._speed = [w_s + (w - w_s) * decay for w_s, w in zip(self._settled, self._speed)]

    def advance_drawing(self, dt_s: float, steps: int) -> list[float]:
        """advance(dt_s) `steps` times (targets and pack voltage held); after each, what the
        ESCs draw from the pack in all (current_a summed, in its order of operations)."""
        decay = math.exp(-dt_s / self._tau_s)
        k_e, r = self._k_e, self._r
        # The four rotors written out (this runs at every physics step): advance() and
        # _pack_currents(speed, share) summed (0 + each rotor's, in order), the same operations.
        # A rotor not driven has u = 0 and share 0: it adds 0.0 to a sum that is never -0.0.
        # `0.0 if x < 0.0 else x` is max(x, 0.0) without the call.
        s0, s1, s2, s3 = self._settled
        w0, w1, w2, w3 = self._speed
        (u0, u1, u2, u3), (p0, p1, p2, p3) = self._driven_drives()
        totals = []
        for _ in range(steps):
            w0, w1, w2, w3 = s0 + (w0 - s0) * decay, s1 + (w1 - s1) * decay, s2 + (w2 - s2) * decay, s3 + (w3 - s3) * decay
            i0, i1, i2, i3 = (u0 - k_e * w0) / r, (u1 - k_e * w1) / r, (u2 - k_e * w2) / r, (u3 - k_e * w3) / r
            totals.append(0.0 + p0 * (0.0 if i0 < 0.0 else i0) + p1 * (0.0 if i1 < 0.0 else i1)
                          + p2 * (0.0 if i2 < 0.0 else i2) + p3 * (0.0 if i3 < 0.0 else i3))
        self._speed = [w0, w1, w2, w3]
        return totals

    def _driven_drives(self) -> tuple[list[float], list[float]]:
        """(ESC output voltage, share of the pack) of every rotor, both 0 for a rotor not driven."""
        driven = self._driven
        return ([u if d else 0.0 for u, d in zip(self._u_v, driven)],
                [s if d else 0.0 for s, d in zip(self._pack_share(), driven)])

    def esc_readings(self) -> tuple[list[float], list[float]]:
        """(speed rad/s, draw from the pack A) of every rotor: what its ESC measures."""
        return list(self._speed), self._pack_currents(self._speed, self._pack_share())

    def filter_inputs(self) -> tuple[list[float], list[float], list[float]]:
        """(k_t N/(rad/s)^2, settled speed rad/s, speed rad/s), one entry a rotor (read only): what
        the plant's thrust filters are set from (sitl/plant/mujoco_plant.py)."""
        return self._k_t_now, self._settled, self._speed

    # -- what the rotors do ---------------------------------------------------------------
    @property
    def time_constant_s(self) -> float:
        return self._tau_s

    @property
    def speed_rad_s(self) -> np.ndarray:
        return np.array(self._speed)

    @property
    def thrust_coefficient_n_s2(self) -> np.ndarray:
        """Each rotor's k_t now (0 without its propeller)."""
        return np.array(self._k_t_now)

    @property
    def thrust_n(self) -> np.ndarray:
        return self.thrust_coefficient_n_s2 * self.speed_rad_s ** 2

    @property
    def current_a(self) -> np.ndarray:
        """What each ESC draws from the pack."""
        return np.array(self._pack_currents(self._speed, self._pack_share()))

    def _pack_share(self) -> list[float]:
        """Each ESC's draw from the pack per ampere of its motor: its output voltage over the pack's."""
        return [u / self.voltage_v for u in self._u_v]

    def _pack_currents(self, speed_rad_s: list[float], share: list[float]) -> list[float]:
        """Each ESC's draw from the pack: its motor's current (u - k_e w) / R, at least 0 and 0 when
        not driven, times its share (_pack_share)."""
        k_e, r = self._k_e, self._r
        return [s * (0.0 if 0.0 > (i := (u - k_e * w) / r if driven else 0.0) else i)      # s max(i, 0)
                for s, u, w, driven in zip(share, self._u_v, speed_rad_s, self._driven)]

    def thrust_ceiling_n(self, thrust_max_n: float) -> np.ndarray:
        """What each rotor settles at when commanded `thrust_max_n` now (truth: the fault and the
        pack voltage applied; computed again only when one of them changed)."""
        if self._ceiling is None or self._ceiling[:2] != (thrust_max_n, self.voltage_v):
            drive_v = self._drive_voltages([float(self.speed_for_thrust(thrust_max_n))])[0]
            _, w = self._settle([drive_v] * ROTOR_COUNT, self.voltage_v)
            self._ceiling = (thrust_max_n, self.voltage_v, self.thrust_coefficient_n_s2 * np.array(w) ** 2)
        return self._ceiling[2].copy()


def fault_ceiling_n(af: Airframe, loss: float, kind: FaultKind, thrust_max_n: float | None = None) -> float:
    """The most a rotor with this fault gives, settled on the nominal pack when commanded
    `thrust_max_n` (default: the airframe's): 0 for a stopped motor or a lost propeller,
    (1 - loss) x hover thrust for a degraded motor, a little over (1 - loss) x its limit for a
    damaged propeller (on the lighter load the motor turns faster)."""
    v = af.battery_nominal_voltage_v
    rotors = Thrusters(af, af.hover_thrust_per_rotor_n, v)
    rotors.set_fault(0, loss, kind)
    rotors.update(v)
    return float(rotors.thrust_ceiling_n(af.thrust_max_n if thrust_max_n is None else thrust_max_n)[0])


def figures(af: Airframe) -> list[str]:
    """The rotor's figures on the nominal pack, settled: `python -m sitl.plant.thrusters`."""
    v = af.battery_nominal_voltage_v
    rows = [f"k_t {af.thrust_coefficient_n_s2:g} N/(rad/s)^2, k_q {af.drag_torque_coefficient_n_m_s2:.3g} N m/(rad/s)^2, "
            f"KV {af.motor_kv_rpm_per_v:g}, R {af.motor_resistance_ohm * 1e3:.1f} mOhm, i0 {af.motor_no_load_current_a:g} A, "
            f"tau {af.motor_time_constant_s * 1e3:g} ms, pack {v:g} V",
            "| rotor 4 | command | speed (rpm) | thrust (N) | ESC current (A) |", "|---|---|---|---|---|"]
    cases = [("healthy", None, 0.0, af.hover_thrust_per_rotor_n), ("healthy", None, 0.0, af.thrust_max_n)]
    cases += [(k.label, k, loss, af.hover_thrust_per_rotor_n)
              for k, loss in ((FaultKind.MOTOR, 1.0), (FaultKind.PROPELLER, 1.0), (FaultKind.DAMAGE, 0.5),
                              (FaultKind.DEGRADED, 0.5))]
    for label, kind, loss, thrust_n in cases:
        rotors = Thrusters(af, af.hover_thrust_per_rotor_n, v)
        if kind is not None:
            rotors.set_fault(3, loss, kind)
            label += f" {loss:g}" if kind in (FaultKind.DAMAGE, FaultKind.DEGRADED) else ""
        rotors.command(np.full(ROTOR_COUNT, thrust_n))
        rotors.update(v)
        rotors.advance(100.0 * af.motor_time_constant_s)
        rows.append(f"| {label} | {thrust_n:.2f} N | {rotors.speed_rad_s[3] * RAD_S_TO_RPM:,.0f} | "
                    f"{rotors.thrust_n[3]:.2f} | {rotors.current_a[3]:.2f} |")
    return rows


if __name__ == "__main__":
    from m4.airframe import load_airframe
    print("\n".join(figures(load_airframe())))
