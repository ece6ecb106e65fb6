"""The plant against hand physics: hover, reaction moment, drag balance, centre of mass, faults."""

import math

import numpy as np
import pytest

from m4.airframe import ROTOR_COUNT, load_airframe
from m4.fault_kind import FaultKind
from companion.core.rom import rotation_ned_from_frd
from sitl.plant.mujoco_plant import Plant, PlantOptions

AF = load_airframe()
NOMINAL = np.full(ROTOR_COUNT, AF.nominal_hip_rad)
HOVER_N = AF.total_mass_kg * AF.gravity_m_s2 / ROTOR_COUNT
HULL_HALF_HEIGHT_M = AF.body_box_size_m[2] / 2


# Hand values from the lumps: hip block (cube) at the hip, link (rod) at mid-leg, wheel (disk,
# axis vertical) at the leg end.
def lumps_frd(q):
    """(mass, position (4, 3)) of each of the three lumps of every leg."""
    hips = np.array(AF.hip_frd_m)
    ends = AF.thruster_positions_frd_m(q)
    return [(AF.leg_hip_block_mass_kg, hips), (AF.leg_link_mass_kg, (hips + ends) / 2),
            (AF.leg_wheel_mass_kg, ends)]


def com_offset_from_lumps_frd(q):
    return sum(m * r.sum(axis=0) for m, r in lumps_frd(q)) / AF.total_mass_kg


def yaw_inertia_from_lumps(q):
    own = ROTOR_COUNT * (AF.leg_hip_block_mass_kg * AF.hip_block_size_m**2 / 6
                         + AF.leg_link_mass_kg * (3 * AF.link_radius_m**2 + AF.leg_length_m**2) / 12
                         + AF.leg_wheel_mass_kg * AF.wheel_radius_m**2 / 2)
    offsets = sum(m * np.sum(r[:, :2] ** 2) for m, r in lumps_frd(q))
    return AF.body_inertia_diag_kg_m2[2] + own + offsets


def yaw_drag_n_m(r):
    return AF.drag_rotational_linear_n_m_s * r + AF.drag_yaw_quadratic_n_m_s2 * abs(r) * r


def settled_yaw_rate(moment_n_m):
    a, b = AF.drag_yaw_quadratic_n_m_s2, AF.drag_rotational_linear_n_m_s
    return (-b + math.sqrt(b * b + 4 * a * moment_n_m)) / (2 * a)


def yaw_split(d_t):
    """Hover thrusts with ccw rotors up by d_t and cw rotors down: pure yaw moment 4 k_m d_t."""
    return HOVER_N + d_t * np.array(AF.spin_sign, dtype=float)


def on_the_floor(**kw):
    plant = Plant(AF, start_ned_m=(0.0, 0.0, -0.3), **kw)
    plant.command(np.zeros(ROTOR_COUNT), NOMINAL)
    plant.step(1.0)
    return plant


def test_starts_hovering_at_rest_with_the_hover_thrust_and_nominal_posture():
    s = Plant(AF, start_ned_m=(1.0, -2.0, -3.0), start_yaw_rad=0.7).state()
    assert s.time_s == 0.0
    assert s.pos_ned_m == pytest.approx([1.0, -2.0, -3.0])
    assert s.euler_rad == pytest.approx([0.0, 0.0, 0.7])
    assert s.quat_wxyz == pytest.approx([math.cos(0.35), 0.0, 0.0, math.sin(0.35)])
    assert s.thrust_n == pytest.approx(np.full(ROTOR_COUNT, HOVER_N))
    assert HOVER_N == pytest.approx(6.0 * 9.81 / 4)
    assert s.hip_rad == pytest.approx(NOMINAL)
    assert s.com_ned_m == pytest.approx(s.pos_ned_m, abs=1e-12)
    assert not s.on_ground


def test_hover_thrust_holds_altitude_and_attitude_for_a_second():
    plant = Plant(AF)
    plant.step(1.0)
    s = plant.state()
    assert s.time_s == pytest.approx(1.0)
    assert np.linalg.norm(s.pos_ned_m - [0.0, 0.0, -2.0]) < 1e-3
    assert np.abs(s.euler_rad).max() < 1e-6
    assert s.thrust_n == pytest.approx(np.full(ROTOR_COUNT, HOVER_N))


def test_thrust_differences_turn_the_robot_the_frd_way():
    right_up = Plant(AF)
    right_up.command(HOVER_N + np.array([1.0, -1.0, -1.0, 1.0]), NOMINAL)    # 1 and 4 are on the right
    front_up = Plant(AF)
    front_up.command(HOVER_N + np.array([1.0, -1.0, 1.0, -1.0]), NOMINAL)    # 1 and 3 are in front
    climb = Plant(AF)
    climb.command(np.full(ROTOR_COUNT, HOVER_N + 2.0), NOMINAL)
    for p in (right_up, front_up, climb):
        p.step(0.2)
    assert right_up.state().rates_frd_rad_s[0] < -0.1          # right side up: negative roll
    assert front_up.state().rates_frd_rad_s[1] > 0.1           # nose up: positive pitch
    assert climb.state().vel_ned_m_s[2] < -0.1                 # up is -z in NED


def test_pure_reaction_moment_gives_the_expected_yaw_acceleration():
    plant = Plant(AF)
    plant.command(yaw_split(2.0), NOMINAL)
    plant.step(0.3)                             # ten motor time constants: thrusts delivered
    s0 = plant.state()
    plant.step(0.01)
    s1 = plant.state()
    moment = AF.moment_coefficient_m * np.dot(AF.spin_sign, s0.thrust_n)
    assert moment == pytest.approx(4 * AF.moment_coefficient_m * 2.0, rel=1e-4)
    r_mid = (s0.rates_frd_rad_s[2] + s1.rates_frd_rad_s[2]) / 2
    expected = (moment - yaw_drag_n_m(r_mid)) / yaw_inertia_from_lumps(s0.hip_rad)
    accel = (s1.rates_frd_rad_s - s0.rates_frd_rad_s) / 0.01
    assert accel[2] == pytest.approx(expected, rel=0.02)
    assert np.abs(accel[:2]).max() < 1e-6 * abs(expected)


def test_constant_yaw_moment_settles_at_the_rate_where_drag_balances_it():
    plant = Plant(AF, start_ned_m=(0.0, 0.0, -500.0))
    plant.command(yaw_split(2.0), NOMINAL)
    plant.step(35.0)
    r35 = plant.state().rates_frd_rad_s[2]
    plant.step(5.0)
    r40 = plant.state().rates_frd_rad_s[2]
    hand = settled_yaw_rate(4 * AF.moment_coefficient_m * 2.0)
    print(f"settled yaw rate {r40:.3f} rad/s, hand value {hand:.3f} rad/s")
    assert abs(r40 - r35) < 0.01 * hand                 # settled
    assert r40 == pytest.approx(hand, rel=0.01)


def test_falling_with_the_motors_off_reaches_the_speed_where_drag_balances_weight():
    plant = Plant(AF, start_ned_m=(0.0, 0.0, -1000.0))
    plant.command(np.zeros(ROTOR_COUNT), NOMINAL)
    plant.step(15.0)
    s = plant.state()
    weight = AF.total_mass_kg * AF.gravity_m_s2
    a, b = AF.drag_quadratic_n_s2_m2, AF.drag_linear_n_s_m
    terminal = (-b + math.sqrt(b * b + 4 * a * weight)) / (2 * a)
    assert s.vel_ned_m_s == pytest.approx([0.0, 0.0, terminal], rel=1e-3, abs=1e-6)
    assert np.abs(s.euler_rad).max() < 1e-6                     # drag acts at the hull centre


def test_one_leg_moved_moves_the_centre_of_mass_as_the_lumps_say():
    plant = on_the_floor()
    before = plant.state()
    target = NOMINAL.copy()
    target[0] = AF.hip_max_rad                       # rotor 1 straight out sideways
    plant.command(np.zeros(ROTOR_COUNT), target)
    plant.step(1.0)
    s = plant.state()
    assert s.hip_rad == pytest.approx(target, abs=2e-3)
    rot = rotation_ned_from_frd(s.euler_rad)
    com_frd = rot.T @ (s.com_ned_m - s.pos_ned_m)
    assert com_frd == pytest.approx(com_offset_from_lumps_frd(s.hip_rad), abs=1e-5)
    # The airframe's formula (used by the ROM and the companion) says the same.
    assert com_frd == pytest.approx(AF.com_offset_frd_m(s.hip_rad), abs=1e-5)
    shift_af = AF.com_offset_frd_m(s.hip_rad) - AF.com_offset_frd_m(before.hip_rad)
    assert np.linalg.norm(shift_af) > 0.005


def test_rests_on_the_floor_with_zero_thrust():
    plant = on_the_floor()
    plant.step(1.0)
    s = plant.state()
    assert s.on_ground
    assert s.pos_ned_m[2] == pytest.approx(-HULL_HALF_HEIGHT_M, abs=2e-3)
    assert np.linalg.norm(s.vel_ned_m_s) < 1e-3
    assert np.abs(s.euler_rad[:2]).max() < 1e-3
    assert s.thrust_n == pytest.approx(np.zeros(ROTOR_COUNT), abs=1e-9)


def test_rotor_speed_lags_the_command_by_the_airframe_time_constant_and_thrust_is_k_t_w_squared():
    plant = Plant(AF)
    w0, w1 = math.sqrt(HOVER_N / AF.thrust_coefficient_n_s2), math.sqrt((HOVER_N + 5.0) / AF.thrust_coefficient_n_s2)
    plant.command(np.full(ROTOR_COUNT, HOVER_N + 5.0), NOMINAL)
    plant.step(AF.motor_time_constant_s)
    s = plant.state()
    w = w0 + (w1 - w0) * (1 - math.exp(-1))
    assert s.thrust_cmd_n == pytest.approx(np.full(ROTOR_COUNT, HOVER_N + 5.0))
    assert s.rotor_speed_rad_s == pytest.approx(np.full(ROTOR_COUNT, w), rel=1e-9)
    assert s.thrust_n == pytest.approx(np.full(ROTOR_COUNT, AF.thrust_coefficient_n_s2 * w * w), rel=1e-9)


def test_rotor_loss_caps_delivered_thrust_relative_to_hover_and_can_be_restored():
    plant = Plant(AF)
    full = np.full(ROTOR_COUNT, AF.thrust_max_n)
    plant.set_rotor_loss(4, 0.5)
    plant.command(full, NOMINAL)
    plant.step(0.5)
    s = plant.state()
    cap = 0.5 * AF.hover_thrust_per_rotor_n
    assert s.thrust_limit_n == pytest.approx([AF.thrust_max_n] * 3 + [cap])
    assert s.thrust_cmd_n == pytest.approx(full)                 # the ESC command does not know the fault
    assert s.thrust_rated_max_n == pytest.approx(full)
    assert s.thrust_n == pytest.approx([AF.thrust_max_n] * 3 + [cap], rel=1e-6)
    plant.set_rotor_loss(4, 1.0)
    plant.step(0.5)
    assert plant.state().thrust_n[3] < 1e-5
    plant.set_rotor_loss(4, 0.0)                    # the request (full thrust) comes back
    plant.step(0.5)
    assert plant.state().thrust_n == pytest.approx(full, rel=1e-6)


def test_thrust_max_option_caps_every_rotor():
    plant = Plant(AF, PlantOptions(thrust_max_n=AF.thrust_max_tight_n))
    plant.command(np.full(ROTOR_COUNT, 100.0), NOMINAL)
    s = plant.state()
    assert s.thrust_cmd_n == pytest.approx(np.full(ROTOR_COUNT, AF.thrust_max_tight_n))
    assert s.thrust_limit_n == pytest.approx(np.full(ROTOR_COUNT, AF.thrust_max_tight_n))
    assert s.thrust_rated_max_n == pytest.approx(np.full(ROTOR_COUNT, AF.thrust_max_tight_n))


def test_mass_and_inertia_scales_apply_to_the_plant_and_it_still_starts_hovering():
    plant = Plant(AF, PlantOptions(mass_scale=1.2, inertia_scale=1.3))
    m = plant.model
    assert m.body_subtreemass[m.body("hull").id] == pytest.approx(1.2 * AF.total_mass_kg)
    assert m.body("hull").inertia == pytest.approx(1.2 * 1.3 * np.array(AF.body_inertia_diag_kg_m2))
    assert plant.state().thrust_n == pytest.approx(np.full(ROTOR_COUNT, 1.2 * HOVER_N))
    plant.step(1.0)
    assert np.linalg.norm(plant.state().pos_ned_m - [0.0, 0.0, -2.0]) < 1e-3


def test_non_finite_command_entries_keep_the_previous_values():
    plant = Plant(AF)
    plant.command([10.0, 11.0, 12.0, 13.0], NOMINAL)
    plant.command([math.nan, 20.0, math.inf, 21.0], [math.nan, 0.5, 0.5, 0.5], [math.nan, 0.0, 0.0, 0.0])
    plant.step(1.0)
    s = plant.state()
    assert s.thrust_cmd_n == pytest.approx([10.0, 20.0, 12.0, 21.0])
    assert s.hip_rad[0] == pytest.approx(AF.nominal_hip_rad, abs=0.02)
    assert s.hip_rad[1:] == pytest.approx([0.5, 0.5, 0.5], abs=0.02)


@pytest.mark.parametrize("call, message", [
    (lambda p: p.command([1.0, 2.0, 3.0], NOMINAL), "thrust_n must be 4 numbers"),
    (lambda p: p.command(np.ones(4), "up"), "hip_rad must be 4 numbers"),
    (lambda p: p.set_rotor_loss(5, 1.0), "rotor must be an integer 1..4"),
    (lambda p: p.set_rotor_loss(1, 1.5), "loss must be a number in \\[0, 1\\]"),
    (lambda p: p.set_rotor_loss(1, 1.0, FaultKind.UNKNOWN), "kind must be one of degraded, motor"),
    (lambda p: p.step(0.0015), "multiple of 0.001"),
    (lambda p: p.step(-0.001), "non-negative"),
])
def test_bad_inputs_raise_errors_that_name_them(call, message):
    with pytest.raises(ValueError, match=message):
        call(Plant(AF))


def test_hip_servo_respects_the_rate_and_acceleration_limits():
    plant = on_the_floor()
    target = np.array([AF.hip_max_rad, AF.hip_min_rad, AF.nominal_hip_rad, 0.3])
    plant.command(np.zeros(ROTOR_COUNT), target)
    rates = []
    for _ in range(160):
        plant.step(0.005)
        rates.append(plant.state().hip_rate_rad_s)
    rates = np.array(rates)
    accel = np.diff(rates, axis=0) / 0.005
    assert plant.state().hip_rad == pytest.approx(target, abs=2e-3)
    # The reference keeps both limits exactly (tests/sitl/plant/test_hip_servos.py); the joint follows it
    # through the servo, critically damped with rate feed-forward, (kv s + kp) / (I s^2 + kv s
    # + kp), whose impulse response integrates in absolute value to 1 + 2 / e^2: the most it
    # can amplify the reference's rate or acceleration.
    overshoot = 1 + 2 * math.exp(-2)
    assert np.abs(rates).max() <= overshoot * AF.hip_rate_max_rad_s
    assert np.abs(rates).max() > 0.9 * AF.hip_rate_max_rad_s      # the big move does reach it
    assert np.abs(accel).max() <= overshoot * AF.hip_accel_max_rad_s2


def test_sensor_noise_only_when_asked_seeded_and_only_on_measured_quantities():
    assert Plant(AF).measured_state().pos_ned_m == pytest.approx(Plant(AF).state().pos_ned_m)
    noisy_a = Plant(AF, PlantOptions(sensor_noise=True), seed=3)
    noisy_b = Plant(AF, PlantOptions(sensor_noise=True), seed=3)
    a, b, truth = noisy_a.measured_state(), noisy_b.measured_state(), noisy_a.state()
    assert a.pos_ned_m == pytest.approx(b.pos_ned_m)
    assert 0 < np.abs(a.pos_ned_m - truth.pos_ned_m).max() < 6 * AF.position_noise_m
    assert 0 < np.abs(a.rates_frd_rad_s - truth.rates_frd_rad_s).max() < 6 * AF.rate_noise_rad_s
    assert a.quat_wxyz == pytest.approx(
        np.array([math.cos(a.euler_rad[2] / 2), 0, 0, math.sin(a.euler_rad[2] / 2)]), abs=0.01)
    assert a.thrust_n == pytest.approx(truth.thrust_n)


@pytest.mark.parametrize("noise", [False, True])
def test_the_gyro_alone_reads_what_the_whole_measured_state_reads(noise):
    plant = Plant(AF, PlantOptions(sensor_noise=noise), seed=3)
    plant.command(np.full(ROTOR_COUNT, plant.hover_thrust_n) + [0.5, -0.5, 0.3, -0.3], np.full(ROTOR_COUNT, 0.7))
    for _ in range(5):
        plant.step(0.004)
        gyro = plant.measured_rates_frd_rad_s()
        assert np.array_equal(gyro, plant.measured_state().rates_frd_rad_s) and np.any(gyro != 0.0)


def test_sensor_noise_depends_on_the_instant_and_seed_not_on_how_often_it_was_drawn():
    once, often = (Plant(AF, PlantOptions(sensor_noise=True), seed=3) for _ in range(2))
    first = often.measured_state()
    for _ in range(5):
        assert often.measured_state().pos_ned_m == pytest.approx(first.pos_ned_m)
    once.step(0.01)
    often.step(0.01)
    assert once.measured_state().euler_rad == pytest.approx(often.measured_state().euler_rad)
    assert once.measured_state().pos_ned_m != pytest.approx(first.pos_ned_m)
    other_seed = Plant(AF, PlantOptions(sensor_noise=True), seed=4)
    other_seed.step(0.01)
    assert other_seed.measured_state().pos_ned_m != pytest.approx(once.measured_state().pos_ned_m)


@pytest.mark.parametrize("battery", [False, True], ids=["steady pack", "sagging pack"])
def test_the_same_flight_whatever_lengths_the_caller_steps_by(battery):
    """The FC steps the plant from event to event, and when a command lands depends on the wall
    clock: stepping 1 + 3 + 6 ms must give the very numbers stepping 10 ms does."""
    plants = [Plant(AF, PlantOptions(battery=battery), start_ned_m=(0.0, 0.0, -2.0)) for _ in range(2)]
    for plant in plants:
        plant.command(np.array([16.0, 14.0, 15.0, 13.0]), np.full(ROTOR_COUNT, AF.nominal_hip_rad + 0.2))
    for _ in range(20):
        plants[0].step(0.010)
        for dt in (0.001, 0.003, 0.006):
            plants[1].step(dt)
    a, b = (p.state() for p in plants)
    for name in ("pos_ned_m", "vel_ned_m_s", "euler_rad", "hip_rad", "thrust_n"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    assert np.array_equal(plants[0].thrusters.speed_rad_s, plants[1].thrusters.speed_rad_s)   # the ESCs' rpm


def test_random_commands_through_the_api_never_raise_a_mujoco_warning():
    plant = Plant(AF, start_ned_m=(0.0, 0.0, -3.0))
    rng = np.random.default_rng(11)
    for k in range(150):
        thrust = rng.uniform(-5.0, 40.0, ROTOR_COUNT)
        thrust[rng.random(ROTOR_COUNT) < 0.1] = math.nan
        plant.command(thrust, rng.uniform(-0.5, 2.0, ROTOR_COUNT), rng.uniform(-10.0, 10.0, ROTOR_COUNT))
        if k % 50 == 25:
            plant.set_rotor_loss(int(rng.integers(1, 5)), float(rng.uniform()))
        plant.step(0.02)
    s = plant.state()
    assert all(w.number == 0 for w in plant.data.warning), [w.number for w in plant.data.warning]
    assert np.all(np.isfinite(s.pos_ned_m)) and np.all(np.isfinite(s.quat_wxyz))
    assert np.all((s.hip_rad > AF.hip_min_rad - 0.05) & (s.hip_rad < AF.hip_max_rad + 0.05))
