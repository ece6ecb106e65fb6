"""The FC's estimate on raw sensors ([sensors] profile "mocap" / "gps"): close to the truth,
reproducible, and what the FC reports, biases and all, never the truth itself."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from m4.airframe import load_airframe
from m4.attitude import euler_from_quat_wxyz, quat_wxyz_from_euler
from m4.fault_kind import FaultKind
from m4.mavlink import mavlink
from m4.scenario import Scenario, Sensors
from m4.sensor_profiles import GNSS, PROFILES
from sitl.fc.estimator import Estimator
from sitl.plant.mujoco_plant import Plant
from sitl.plant.sensor_suite import SensorSuite
from sitl.plant.state import FixSample, ImuSample
from sitl.vehicle import Vehicle

AF = load_airframe()
HOVER_RAD_S = 578.0
HEALTHY = np.full(4, -1)


def _hover(profile: str, seed: int = 0, until_ms: int = 3000, every_ms: int = 100) -> tuple[Vehicle, list]:
    """The vehicle on its failsafe HOLD (no companion), the FC's state and the truth every every_ms."""
    vehicle = Vehicle(Scenario(name="hover", duration_s=10.0, sensors=Sensors(profile)), AF, seed=seed)
    vehicle.start(lambda msgs: None)
    pairs = []
    for t_ms in range(every_ms, until_ms + 1, every_ms):
        vehicle.advance_to(t_ms, lambda msgs: None)
        pairs.append((vehicle.fc.measured_state(t_ms), vehicle.plant.state()))
    return vehicle, pairs


def _angle_deg(q_a, q_b) -> float:
    return math.degrees(2 * math.acos(min(1.0, abs(float(np.dot(q_a, q_b))))))


@pytest.mark.parametrize("profile, pos_m, vel_m_s", [("gps", 0.3, 0.15), ("mocap", 0.01, 0.05)])
def test_in_flight_the_estimate_stays_within_its_sensors_noise_of_the_truth(profile, pos_m, vel_m_s):
    _, pairs = _hover(profile)
    for est, truth in pairs:
        assert _angle_deg(est.quat_wxyz, truth.quat_wxyz) < 1.5
        assert np.linalg.norm(est.pos_ned_m - truth.pos_ned_m) < pos_m
        assert np.linalg.norm(est.vel_ned_m_s - truth.vel_ned_m_s) < vel_m_s
        assert np.abs(est.rates_frd_rad_s - truth.rates_frd_rad_s).max() < 0.05
    assert not all(np.array_equal(est.pos_ned_m, truth.pos_ned_m) for est, truth in pairs)


def test_the_fc_reports_its_estimate_not_the_truth():
    vehicle, _ = _hover("gps", until_ms=500)
    snap = vehicle.fc.snapshot(500)
    build, est, truth = vehicle.fc.telemetry_builder.build, vehicle.fc.estimator, vehicle.plant.state()
    att = build(mavlink.MAVLINK_MSG_ID_ATTITUDE_QUATERNION, snap)
    pos = build(mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED, snap)
    assert [att.q1, att.q2, att.q3, att.q4] == pytest.approx(est.quat_wxyz.tolist(), abs=1e-6)
    assert [att.rollspeed, att.pitchspeed, att.yawspeed] == pytest.approx(est.rates_frd_rad_s.tolist(), abs=1e-6)
    assert [pos.x, pos.y, pos.z] == pytest.approx(est.pos_ned_m.tolist(), abs=1e-5)
    assert [pos.x, pos.y, pos.z] != pytest.approx(truth.pos_ned_m.tolist(), abs=1e-5)
    assert [att.rollspeed, att.pitchspeed] != pytest.approx(truth.rates_frd_rad_s[:2].tolist(), abs=1e-6)


def _static_run(profile_name: str, seconds: float, gyro_bias_rad_s=None):
    """A robot held still, tilted and turned, in front of the profile's sensors and the FC's
    estimator: (the suite, the estimator) after `seconds`, and the reported roll rate then and at 0.1 s."""
    profile = PROFILES[profile_name]
    euler = np.radians([3.0, -2.0, 10.0])
    quat = quat_wxyz_from_euler(euler)
    suite = SensorSuite(profile, seed=3, mass_kg=AF.total_mass_kg, gravity_m_s2=AF.gravity_m_s2,
                        turn_sense_frd_z=-np.array(AF.spin_sign), start_vel_ned_m_s=np.zeros(3))
    if gyro_bias_rad_s is not None:
        suite.gyro_bias_rad_s = np.array(gyro_bias_rad_s)
    est = Estimator(profile, AF.gravity_m_s2, (0.0, 0.0, -2.0), euler[2])
    est.quat_wxyz = quat.copy()
    early = None
    for t_ms in range(2, round(seconds * 1000) + 1, 2):
        suite.sample(t_ms, np.array([0.0, 0.0, -2.0]), np.zeros(3), quat, np.zeros(3), np.full(4, HOVER_RAD_S),
                     HEALTHY, np.zeros(4))
        est.feed(suite.take(t_ms))
        if t_ms == 100:
            early = est.rates_frd_rad_s.copy()
    return suite, est, early, euler


def test_a_biased_gyro_shows_in_the_reported_rates_until_the_filter_has_learnt_the_bias():
    suite, est, early, euler = _static_run("mocap", 60.0, gyro_bias_rad_s=[0.03, 0.0, 0.0])
    assert early[0] == pytest.approx(0.03, abs=0.01)          # held still: the rate reported is the bias
    assert abs(est.rates_frd_rad_s[0]) < 0.01                 # learnt
    assert est.gyro_bias_rad_s[0] == pytest.approx(suite.gyro_bias_rad_s[0], abs=0.01)
    assert euler_from_quat_wxyz(est.quat_wxyz)[:2] == pytest.approx(euler[:2], abs=math.radians(1.0))


def test_the_same_seed_gives_the_same_samples_and_another_seed_others():
    def samples(seed):
        plant = Plant(AF, seed=seed, sensors=PROFILES["gps"])
        plant.step(0.5)
        return plant.take_sensor_samples()
    a, b, c = samples(7), samples(7), samples(8)
    assert len(a) == len(b) > 250
    assert all(np.array_equal(x.gyro_frd_rad_s, y.gyro_frd_rad_s) for x, y in zip(a, b) if isinstance(x, ImuSample))
    imu_a = [s for s in a if isinstance(s, ImuSample)]
    imu_c = [s for s in c if isinstance(s, ImuSample)]
    assert not np.array_equal(imu_a[-1].accel_frd_m_s2, imu_c[-1].accel_frd_m_s2)


def test_the_same_seed_flies_the_same_estimate_whatever_the_lengths_the_plant_is_stepped_by():
    def run(steps_ms):
        vehicle = Vehicle(Scenario(name="hover", duration_s=10.0, sensors=Sensors("gps")), AF, seed=2)
        vehicle.start(lambda msgs: None)
        for t_ms in steps_ms:
            vehicle.advance_to(t_ms, lambda msgs: None)
        return vehicle.fc.measured_state(steps_ms[-1])
    once, often = run([600]), run(list(range(7, 600, 7)) + [600])
    assert np.array_equal(once.pos_ned_m, often.pos_ned_m) and np.array_equal(once.quat_wxyz, often.quat_wxyz)


def test_a_gnss_fix_is_heard_its_delay_after_it_was_measured():
    plant = Plant(AF, seed=1, sensors=PROFILES["gps"])
    plant.step((2 * GNSS.period_ms + GNSS.delay_ms - 1) / 1000.0)        # the second fix measured, not yet heard
    fixes = [s for s in plant.take_sensor_samples() if isinstance(s, FixSample)]
    assert [round(f.time_s * 1000) for f in fixes] == [GNSS.period_ms + GNSS.delay_ms]
    plant.step(0.001)
    assert [round(s.time_s * 1000) for s in plant.take_sensor_samples() if isinstance(s, FixSample)] == [
        2 * GNSS.period_ms + GNSS.delay_ms]


def test_a_damaged_propeller_shakes_the_accelerometer_more_than_a_sound_one():
    def shake(kind, loss):
        suite = SensorSuite(PROFILES["mocap"], seed=0, mass_kg=AF.total_mass_kg, gravity_m_s2=AF.gravity_m_s2,
                            turn_sense_frd_z=-np.array(AF.spin_sign), start_vel_ned_m_s=np.zeros(3))
        kinds, losses = HEALTHY.copy(), np.zeros(4)
        kinds[1], losses[1] = kind, loss
        accel = []
        for t_ms in range(2, 1001, 2):
            suite.sample(t_ms, np.zeros(3), np.zeros(3), np.array([1.0, 0, 0, 0]), np.zeros(3),
                         np.full(4, HOVER_RAD_S), kinds, losses)
            accel += [s.accel_frd_m_s2[:2] for s in suite.take(t_ms) if isinstance(s, ImuSample)]
        return float(np.std(accel))
    sound, chipped = shake(-1, 0.0), shake(int(FaultKind.DAMAGE), 0.3)
    assert 0.1 < sound < 2.0                       # healthy vibration: the guides' "good" level
    assert chipped > 5 * sound


def test_the_ideal_profile_has_no_raw_sensors_and_no_estimator():
    vehicle = Vehicle(dataclasses.replace(Scenario(name="hover", duration_s=1.0)), AF)
    assert vehicle.plant.sensors is None and vehicle.fc.estimator is None
    assert vehicle.plant.take_sensor_samples() == []
