"""The JSON physics (sitl/ardupilot/) against a fake ArduPilot SITL: servo packets on loopback
UDP, sensor lines back."""

from __future__ import annotations

import json
import socket
import threading
from contextlib import contextmanager

import numpy as np
import pytest

from m4.airframe import load_airframe
from m4.scenario import Scenario, parse_scenario
from sitl.ardupilot.json_protocol import (
    MAGIC_16,
    BadPacket,
    hip_goals_rad,
    parse_servo_packet,
    servo_packet,
)
from sitl.ardupilot.physics import JsonPhysics, PhysicsOptions, PhysicsServer
from sitl.cli import main as sitl_main
from sitl.plant.thrusters import HEALTHY, Thrusters
from sitl.plant.truth import TruthRecorder, load_truth

AF = load_airframe()
RATE_HZ = 1000
MOTORS_OFF = (1000,) * 4


def _pwm(motors_us, hips_us=(0,) * 4, channels=16):
    return [*motors_us, 0, 0, 0, 0, *hips_us, *(0,) * (channels - 12)]


def _hover_pwm_us() -> float:
    """The PWM at which every nominal rotor settles at the hover thrust (bisection on the throttle)."""
    rotors = Thrusters(AF, AF.hover_thrust_per_rotor_n, AF.battery_nominal_voltage_v)
    lo, hi = 0.0, 1.0
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        rotors.command_duty([mid] * 4)
        lo, hi = (mid, hi) if rotors.duty_thrust_n(AF.battery_nominal_voltage_v)[0] < AF.hover_thrust_per_rotor_n \
            else (lo, mid)
    return 1000.0 + 1000.0 * lo


class FakeSitl:
    """ArduPilot SITL's side: sends servo packets, reads one JSON line per packet."""

    def __init__(self, port: int):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.settimeout(5.0)
        self.address = ("127.0.0.1", port)
        self.count = 0

    def send(self, pwm, count: int | None = None, rate_hz: int = RATE_HZ) -> dict:
        self.count = self.count + 1 if count is None else count
        self.sock.sendto(servo_packet(rate_hz, self.count, [round(x) for x in pwm]), self.address)
        return self.read()

    def read(self) -> dict:
        data = self.sock.recv(4096)
        assert data.endswith(b"\n") and data.count(b"\n") == 1
        return json.loads(data)

    def run(self, seconds: float, pwm) -> dict:
        for _ in range(round(seconds * RATE_HZ)):
            line = self.send(pwm)
        return line


@contextmanager
def physics(tmp_path=None, scenario: Scenario | None = None):
    options = PhysicsOptions(scenario=scenario or Scenario(name="hover", duration_s=60.0), port=0,
                             truth_log_path=None if tmp_path is None else tmp_path / "truth.npz")
    logged: list[str] = []
    server = PhysicsServer(options, AF, log=logged.append)
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    sitl = FakeSitl(server.port)
    try:
        yield server, sitl, logged
    finally:
        server.stop()
        thread.join(5.0)
        server.close()
        sitl.sock.close()
    assert not thread.is_alive()


def test_at_rest_on_the_floor_the_accelerometer_reads_gravity_up_and_time_follows_the_frames():
    with physics() as (server, sitl, _):
        first = sitl.send(_pwm(MOTORS_OFF))
        line = sitl.run(0.5, _pwm(MOTORS_OFF))
    assert first["timestamp"] == pytest.approx(1.0 / RATE_HZ)
    assert line["timestamp"] == pytest.approx(0.501)
    np.testing.assert_allclose(line["imu"]["accel_body"], [0.0, 0.0, -AF.gravity_m_s2], atol=1e-3)
    np.testing.assert_allclose(line["imu"]["gyro"], 0.0, atol=1e-6)
    np.testing.assert_allclose(line["velocity"], 0.0, atol=1e-6)
    np.testing.assert_allclose(line["quaternion"], [1.0, 0.0, 0.0, 0.0], atol=1e-6)
    assert -0.1 < line["position"][2] < 0.0            # the belly on the floor, NED down
    assert server.physics.counters.answered == 501


def test_hover_pwm_keeps_the_robot_in_place_and_more_lifts_it(tmp_path):
    hover = _hover_pwm_us()
    assert 1500 < hover < 1800                         # the throttle of a 6 kg robot on 30 N rotors
    with physics(tmp_path) as (_, sitl, _):
        at_hover = sitl.run(2.0, _pwm((hover,) * 4, (1500,) * 4))
        climbing = sitl.run(1.0, _pwm((hover + 60,) * 4, (1500,) * 4))
    assert abs(at_hover["position"][2] - (-0.5 * AF.body_box_size_m[2])) < 0.05
    np.testing.assert_allclose(at_hover["imu"]["accel_body"], [0.0, 0.0, -AF.gravity_m_s2], atol=0.05)
    assert climbing["velocity"][2] < -0.3 and climbing["position"][2] < -0.2       # going up: NED down falls
    truth = load_truth(tmp_path / "truth.npz")
    assert truth.time_s[-1] == pytest.approx(3.0, abs=0.011)
    np.testing.assert_allclose(truth.hip_rad[-1], AF.nominal_hip_rad, atol=0.02)   # 1500 us: mid-range
    np.testing.assert_allclose(truth.euler_rad[:, :2], 0.0, atol=1e-3)            # level throughout


def test_a_motor_channel_drives_its_own_rotor_and_a_hip_channel_its_own_hip(tmp_path):
    with physics(tmp_path) as (server, sitl, _):
        sitl.run(0.5, _pwm((1000, 1000, 1000, 1400), (1500, 1500, 1500, 2000)))
        state = server.physics.plant.state()
    assert state.thrust_n[:3] == pytest.approx([0.0] * 3, abs=1e-6) and state.thrust_n[3] > 2.0
    np.testing.assert_allclose(state.hip_rad[:3], AF.nominal_hip_rad, atol=0.02)
    assert state.hip_rad[3] > AF.nominal_hip_rad + 0.5


def test_a_resent_frame_is_answered_again_without_stepping_and_gaps_are_counted():
    with physics() as (server, sitl, _):
        sitl.run(0.1, _pwm(MOTORS_OFF))
        again = sitl.send(_pwm(MOTORS_OFF), count=sitl.count)
        after_gap = sitl.send(_pwm(MOTORS_OFF), count=sitl.count + 5)
    c = server.physics.counters
    assert again["timestamp"] == pytest.approx(0.1)
    assert after_gap["timestamp"] == pytest.approx(0.101)
    assert (c.answered, c.repeated, c.missed) == (101, 1, 4)


def test_bad_datagrams_are_counted_and_named_not_fatal_and_32_channels_work():
    with physics() as (server, sitl, logged):
        for junk in ((12345).to_bytes(2, "little") + servo_packet(RATE_HZ, 1, [1000] * 16)[2:],
                     b"", b"hello", servo_packet(RATE_HZ, 1, [1000] * 16)[:-2]):
            sitl.sock.sendto(junk, sitl.address)
        line = sitl.send(_pwm(MOTORS_OFF, channels=32))
    assert line["timestamp"] == pytest.approx(0.001)
    assert server.physics.counters.bad == 4
    assert any("magic 12345" in text for text in logged)
    assert len(logged) == 2 + 3                        # start and stop, and only the first bad ones named


@pytest.mark.parametrize("data, reason", [
    (b"\x1a\x48", "shorter than its 8-byte header"),
    (servo_packet(RATE_HZ, 1, [1000] * 16) + b"\0\0", "expected 40"),
    (servo_packet(0, 1, [1000] * 16), "frame rate 0"),
])
def test_a_malformed_packet_is_refused_naming_what_is_wrong(data, reason):
    with pytest.raises(BadPacket, match=reason):
        parse_servo_packet(data)


def test_hip_pwm_spans_the_joint_range_and_an_unset_channel_commands_nothing():
    packet = parse_servo_packet(servo_packet(RATE_HZ, 1, _pwm(MOTORS_OFF, (1000, 2000, 1500, 0))))
    goals = hip_goals_rad(packet, AF)
    assert goals[:3] == pytest.approx([AF.hip_min_rad, AF.hip_max_rad, AF.nominal_hip_rad])
    assert np.isnan(goals[3])
    assert MAGIC_16 == 18458


@pytest.mark.parametrize("args, says", [
    (["physics", "--autopilot", "px4"], "invalid choice: 'px4'"),
    (["physics", "--autopilot", "ardupilot", "--port", "70000"], "expected a UDP port 1..65535"),
    (["physics", "--autopilot", "ardupilot", "--scenario", "no-such"], "unknown scenario 'no-such'"),
])
def test_bad_physics_arguments_give_one_line(capsys, args, says):
    assert sitl_main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("m4-sitl: error: ") and says in err[0], err


def test_a_port_in_use_is_one_line(capsys):
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as taken:
        taken.bind(("127.0.0.1", 0))
        port = taken.getsockname()[1]
        assert sitl_main(["physics", "--autopilot", "ardupilot", "--port", str(port)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1] == f"m4-sitl: error: cannot listen on udp 127.0.0.1:{port}: Address already in use", err


def test_without_start_on_hold_the_scenarios_clock_and_its_faults_wait_for_start_scenario():
    """A flight with the companion starts the scenario when the companion takes control."""
    scenario = parse_scenario({"name": "t", "duration_s": 1.0, "start": {"ned_m": [0.0, 0.0, -2.0]},
                               "fault": [{"at_s": 0.01, "rotor": 3, "loss": 1.0}]}, "test")
    ph = JsonPhysics(scenario, AF, log=lambda _: None, start_on_hold=False)
    count = iter(range(10**6))

    def step(n: int) -> None:
        for _ in range(n):
            ph.answer(parse_servo_packet(servo_packet(RATE_HZ, next(count), _pwm(MOTORS_OFF))))

    step(50)
    assert ph.scenario_t0_ms is None and ph.plant.thrusters.kind[2] == HEALTHY
    ph.start_scenario()
    step(1)
    assert ph.scenario_t0_ms == 51
    step(9)
    assert ph.plant.thrusters.kind[2] == HEALTHY
    step(1)
    assert ph.plant.thrusters.kind[2] != HEALTHY                # rotor 3 failed at scenario t = 0.01 s


def test_the_scenarios_wind_blows_from_its_clock_on_with_its_gusts_on_that_clock():
    """Still air while ArduPilot boots, aligns and takes off; the scenario's air once its clock
    starts, a gust at its at_s counted from there (not from boot)."""
    scenario = parse_scenario({"name": "t", "duration_s": 1.0, "start": {"ned_m": [0.0, 0.0, -2.0]},
                               "wind": {"mean_ned_m_s": [0.0, 3.0, 0.0],
                                        "gust": [{"at_s": 0.02, "peak_ned_m_s": [2.0, 0.0, 0.0],
                                                  "duration_s": 0.02}]}}, "test")
    ph = JsonPhysics(scenario, AF, log=lambda _: None, start_on_hold=False)
    recorder = TruthRecorder(period_ms=10)
    ph.observers.append(recorder.observe)
    count = iter(range(10**6))

    def step(n: int) -> np.ndarray | None:
        for _ in range(n):
            ph.answer(parse_servo_packet(servo_packet(RATE_HZ, next(count), _pwm(MOTORS_OFF))))
        return ph.plant.state().wind_ned_m_s

    assert step(50) is None
    ph.start_scenario()
    np.testing.assert_allclose(step(1), [0.0, 3.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(step(30), [2.0, 3.0, 0.0], atol=1e-9)       # the gust's peak, at t = 0.03 s
    truth = recorder.truth()                 # the air row by row with the time: still before the clock started
    assert truth.wind_ned_m_s.shape == (len(truth.time_s), 3)
    np.testing.assert_array_equal(truth.wind_ned_m_s[truth.time_s < 0.051], 0.0)
    np.testing.assert_allclose(truth.wind_ned_m_s[truth.time_s == 0.06], [[0.0, 3.0, 0.0]], atol=1e-12)
