"""Crash and upset recognition: upside down for a while, or on the ground outside a landing."""

from __future__ import annotations

import math


from companion.core import rom
from companion.core.upset import UpsetConfig, UpsetDetector, tilt_rad
from m4.airframe import load_airframe
from m4.mission_plan import ground_com_height_m

AF = load_airframe()
GROUND_Z = -ground_com_height_m(AF)


def state(z_ned_m=-2.0, roll_rad=0.0, v_z=0.0):
    x = rom.hover_state(AF, p_ned_m=(0.0, 0.0, z_ned_m))
    x[rom.EULER.start] = roll_rad
    x[rom.V.stop - 1] = v_z
    return x


def test_tilt_is_the_angle_of_the_body_axis_from_the_vertical():
    assert tilt_rad((0.0, 0.0, 1.0)) == 0.0
    assert math.degrees(tilt_rad((math.pi, 0.0, 0.0))) == 180.0
    assert math.degrees(tilt_rad((math.radians(30), math.radians(40), 2.0))) > 40.0


def test_a_roll_through_upside_down_is_no_crash_staying_there_is():
    det = UpsetDetector(GROUND_Z)
    for k in range(15):                                   # 0.3 s at 170 deg, then level again
        assert det.update(0.02 * k, state(roll_rad=math.radians(170)), landing=False) is None
    assert det.update(0.3, state(), landing=False) is None
    crash = [det.update(1.0 + 0.02 * k, state(roll_rad=math.pi), landing=False) for k in range(30)]
    assert crash[24] is None and crash[25] == "upside down" and det.crash_s == 1.5
    assert det.update(3.0, state(), landing=False) == "upside down"           # latched


def test_on_the_ground_after_flying_is_a_crash_outside_a_landing_only():
    for landing, expected in ((False, "on the ground"), (True, None)):
        det = UpsetDetector(GROUND_Z)
        det.update(0.0, state(z_ned_m=-2.0), landing=landing)
        got = [det.update(1.0 + 0.02 * k, state(z_ned_m=GROUND_Z), landing=landing) for k in range(30)]
        assert got[-1] == expected


def test_standing_on_the_ground_before_any_flight_is_no_crash():
    det = UpsetDetector(GROUND_Z, UpsetConfig(ground_s=0.1))
    assert all(det.update(0.02 * k, state(z_ned_m=GROUND_Z), landing=False) is None for k in range(50))
