"""The reduced-order model against hand physics, not against itself."""

import math

import numpy as np
import pytest

from m4.airframe import load_airframe
from companion.core import rom

AF = load_airframe()
F = rom.dynamics(AF)
NO_DIST = np.zeros(rom.ND)


def xdot(x, u, d=NO_DIST):
    return np.asarray(F(x, u, d)).ravel()


def test_hover_at_the_nominal_posture_is_an_equilibrium():
    x, u = rom.hover_state(AF), rom.hover_input(AF)
    assert xdot(x, u) == pytest.approx(np.zeros(rom.NX), abs=1e-9)


def test_free_fall_accelerates_at_g_whatever_the_attitude():
    x = rom.hover_state(AF)
    x[rom.EULER] = [0.4, -0.3, 2.0]
    a = xdot(x, np.zeros(rom.NU))[rom.V]
    assert a == pytest.approx([0.0, 0.0, AF.gravity_m_s2], abs=1e-9)


def test_pure_reaction_moment_gives_the_expected_yaw_acceleration():
    # Rotors 1 and 2 (ccw) up by dT, rotors 3 and 4 (cw) down by dT: same total thrust, no
    # roll or pitch moment at the symmetric posture, a yaw moment of 4 k_m dT.
    d_t = 2.0
    u = rom.hover_input(AF)
    u[rom.THRUST] += np.array([1, 1, -1, -1]) * d_t
    x = rom.hover_state(AF)
    _, inertia = (np.asarray(m) for m in rom.mass_properties(AF, x[rom.HIP]))
    acc = xdot(x, u)
    expected = 4 * AF.moment_coefficient_m * d_t / inertia[2, 2]
    assert acc[rom.RATES] == pytest.approx([0.0, 0.0, expected], abs=1e-9)
    assert acc[rom.V] == pytest.approx(np.zeros(3), abs=1e-9)


def test_inertia_grows_when_the_legs_spread_out():
    folded = np.asarray(rom.mass_properties(AF, np.zeros(4))[1])
    spread = np.asarray(rom.mass_properties(AF, np.full(4, math.pi / 2))[1])
    assert spread[0, 0] > folded[0, 0]          # legs out sideways: more roll inertia
    assert spread[1, 1] < folded[1, 1]          # legs no longer along x: less pitch inertia
    # Hand computation for the folded posture's roll inertia about the centre (com at 0): the
    # legs lie along x, so every lump of leg i sits at the hip's y.
    y = np.array(AF.hip_frd_m)[:, 1]
    ixx = AF.body_inertia_diag_kg_m2[0] + AF.leg_mass_kg * np.sum(y ** 2)
    assert folded[0, 0] == pytest.approx(ixx)
    # And its yaw inertia: each lump at hip + f L along x.
    hips = np.array(AF.hip_frd_m)
    izz = AF.body_inertia_diag_kg_m2[2] + sum(
        m * np.sum((hips[:, 0] + np.sign(hips[:, 0]) * f * AF.leg_length_m) ** 2 + y ** 2) for m, f in AF.leg_lumps)
    assert folded[2, 2] == pytest.approx(izz)


def test_centre_of_mass_follows_the_legs():
    q = np.radians([90, 0, 72, 0])
    com = np.asarray(rom.mass_properties(AF, q)[0]).ravel()
    assert com == pytest.approx(AF.com_offset_frd_m(q))
    # One leg swung out alone moves the centre of mass towards that side: the link (its centre
    # at mid-leg) and the wheel swing with it, the hip block stays.
    q1 = np.zeros(4)
    q1[0] = math.pi / 2
    shift = np.asarray(rom.mass_properties(AF, q1)[0]).ravel() - np.asarray(rom.mass_properties(AF, np.zeros(4))[0]).ravel()
    L = AF.leg_length_m
    k = (AF.leg_link_mass_kg / 2 + AF.leg_wheel_mass_kg) / AF.total_mass_kg
    assert shift == pytest.approx([k * (0 - L), k * L, 0.0], abs=1e-12)


def test_thrust_offset_from_the_centre_of_mass_rolls_the_robot_the_right_way():
    # More thrust on the right rotors (1 front-right, 4 rear-right) lifts the right side:
    # negative roll acceleration in FRD.
    u = rom.hover_input(AF)
    u[rom.THRUST] += np.array([1.0, -1.0, -1.0, 1.0])
    acc = xdot(rom.hover_state(AF), u)
    assert acc[rom.RATES][0] < 0
    assert abs(acc[rom.RATES][1]) < 1e-9


def test_tilted_thrust_accelerates_horizontally_towards_the_tilt():
    x = rom.hover_state(AF)
    x[rom.EULER] = [0.0, -0.2, 0.0]       # nose down in FRD/NED: negative pitch
    acc = xdot(x, rom.hover_input(AF))[rom.V]
    assert acc[0] == pytest.approx(AF.total_mass_kg * AF.gravity_m_s2 * math.sin(0.2) / AF.total_mass_kg, rel=1e-9)


def test_angular_momentum_is_conserved_when_no_force_acts():
    # Drag off, no thrust, no gravity effect on rotation: a tumbling body keeps I w.
    import dataclasses
    af = dataclasses.replace(AF, drag_rotational_linear_n_m_s=0.0, drag_yaw_quadratic_n_m_s2=0.0,
                             drag_linear_n_s_m=0.0, drag_quadratic_n_s2_m2=0.0)
    step = rom.build_rom(af, 0.001, substeps=1).step
    x = rom.hover_state(af, hip_rad=np.radians([80, 10, 60, 30]))
    x[rom.RATES] = [1.5, -0.7, 2.0]
    x[rom.V] = [1.0, -2.0, 0.5]
    u = np.zeros(rom.NU)
    _, inertia = (np.asarray(m) for m in rom.mass_properties(af, x[rom.HIP]))

    def world_momentum(state):
        r = rom.rotation_ned_from_frd(state[rom.EULER])
        return r @ inertia @ state[rom.RATES]

    h0, e0 = world_momentum(x), x[rom.RATES] @ inertia @ x[rom.RATES]
    for _ in range(300):
        x = np.asarray(step(x, u, NO_DIST)).ravel()
    assert world_momentum(x) == pytest.approx(h0, rel=1e-5)
    assert x[rom.RATES] @ inertia @ x[rom.RATES] == pytest.approx(e0, rel=1e-5)
    assert x[rom.V][:2] == pytest.approx([1.0, -2.0], abs=1e-12)     # horizontal momentum kept


def test_disturbance_force_and_torque_enter_as_forces():
    d = np.array([0.6, 0.0, 0.0, 0.0, 0.0, 0.05])
    acc = xdot(rom.hover_state(AF), rom.hover_input(AF), d)
    assert acc[rom.V][0] == pytest.approx(0.6 / AF.total_mass_kg)
    inertia = np.asarray(rom.mass_properties(AF, np.full(4, AF.nominal_hip_rad))[1])
    assert acc[rom.RATES][2] == pytest.approx(0.05 / inertia[2, 2])


def test_rk4_step_matches_the_closed_form_of_constant_acceleration():
    step = rom.build_rom(AF, 0.1).step
    x = rom.hover_state(AF)
    x_next = np.asarray(step(x, np.zeros(rom.NU), NO_DIST)).ravel()
    # Free fall from rest with drag: the drag is tiny over 0.1 s; position within 1 mm of g t^2/2.
    assert x_next[2] - x[2] == pytest.approx(0.5 * AF.gravity_m_s2 * 0.01, abs=1e-3)
