"""The most a damaged propeller can still give, from its ESC's speed and the thrust it delivers.

A chipped propeller keeps a share s of its thrust and drag coefficients (thrust s k_t w^2,
drag torque s k_q w^2). Its ESC reports the speed w it turns at, the model residual the thrust
it delivers, so s = delivered / (k_t w^2). Its most is s k_t w_full^2, where w_full is the
speed a full command settles at on that lighter load: the motor (back-EMF and torque constant
k_e, winding resistance R, no-load current i0, the airframe's) on the ESC's voltage u carries
the drag where k_e ((u - k_e w) / R - i0) = s k_q w^2. A lighter load turns faster: the
effectiveness measured at the hover throttle (thrust per command) times the limit falls
short of that most by about 6 % of hover thrust for half a propeller. Pure functions.
"""

from __future__ import annotations

import math

from m4.airframe import Airframe


def full_command_speed_rad_s(af: Airframe, voltage_v: float, load_share: float) -> float:
    """The speed a full command settles at on `voltage_v` with `load_share` of the nominal
    propeller's drag (1: a whole propeller; 0: none, the motor's no-load speed)."""
    k_e, r = af.motor_back_emf_v_s_rad, af.motor_resistance_ohm
    drive_v = max(voltage_v - r * af.motor_no_load_current_a, 0.0)
    quadratic = load_share * af.drag_torque_coefficient_n_m_s2 * r        # a w^2 + k_e^2 w - k_e drive = 0
    if quadratic <= 0.0:
        return drive_v / k_e
    return (math.sqrt(k_e**4 + 4.0 * quadratic * k_e * drive_v) - k_e**2) / (2.0 * quadratic)


def damaged_ceiling_n(af: Airframe, load_share: float, voltage_v: float) -> float:
    """The thrust a propeller with `load_share` of its coefficients gives at a full command on
    `voltage_v` (the nominal voltage when it is not finite)."""
    volts = voltage_v if math.isfinite(voltage_v) and voltage_v > 0 else af.battery_nominal_voltage_v
    share = min(max(load_share, 0.0), 1.0)
    return share * af.thrust_coefficient_n_s2 * full_command_speed_rad_s(af, volts, share) ** 2
