"""`m4-sitl physics --autopilot ardupilot`: the MuJoCo plant answering ArduPilot SITL's servo
packets (sitl/ardupilot/json_protocol.py) on UDP, in lockstep.

Every servo packet advances the plant by the packet's frame interval (1 / frame rate, in
whole physics steps of 1 ms, at least one: at SIM_RATE_HZ = 1000, which deploy/ardupilot/m4.parm
sets, exactly the interval; at other rates SITL follows the timestamps it is given) and is
answered with one sensor line at the new instant. SITL's clock runs on those timestamps, so
the pair is deterministic up to when MAVLink commands reach SITL; `arducopter --speedup N`
paces it, the physics answers as fast as packets come. A packet that repeats the last frame
count (SITL resends after a silence) is answered again without stepping; a datagram that is
not a servo packet is counted and ignored.

The robot starts on the floor below the scenario's start point, disarmed, hips at the
nominal posture. The scenario's clock (its faults' at_s) starts when the robot first holds
the scenario's start point in the air (within START_RADIUS_M, slower than START_SPEED_M_S,
for START_HOLD_S): the autopilot's boot, EKF alignment, arming and takeoff take tens of
seconds that the scenario knows nothing of. With `start_on_hold` off the hold is only noted
(`start_held_ms`) and the clock starts when `start_scenario()` is called (a flight with the
companion starts it when the companion takes control). The truth log (truth.npz) runs on the
physics' clock from boot.
"""

from __future__ import annotations

import socket
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from m4.airframe import ROTOR_COUNT, Airframe, load_airframe
from m4.scenario import Scenario
from sitl.ardupilot.json_protocol import (
    BadPacket,
    ServoPacket,
    hip_goals_rad,
    motor_throttles,
    parse_servo_packet,
    sensor_line,
)
from sitl.plant.faults import FaultSchedule, describe
from sitl.plant.mujoco_plant import Plant
from sitl.plant.truth import TruthRecorder

DEFAULT_PORT = 9002
START_RADIUS_M = 0.5
START_SPEED_M_S = 0.5
START_HOLD_S = 2.0
POLL_S = 0.2                   # how often a silent server looks at its stop flag
BAD_PACKETS_LOGGED = 3         # the first few bad datagrams are named in the log, the rest only counted


@dataclass(frozen=True)
class PhysicsOptions:
    scenario: Scenario
    port: int = DEFAULT_PORT
    seed: int = 0
    duration_s: float | None = None            # None: until stopped
    truth_log_path: Path | None = None
    start_on_hold: bool = True                 # False: the scenario's clock waits for start_scenario()


@dataclass
class PhysicsCounters:
    answered: int = 0          # packets that stepped the plant
    repeated: int = 0          # resent frames answered again without stepping
    missed: int = 0            # frame counts skipped (packets lost on the way, or SITL restarted)
    bad: int = 0               # datagrams that were not servo packets

    def summary(self) -> str:
        return (f"servo packets answered {self.answered}, repeated {self.repeated}, frames missed {self.missed}, "
                f"bad datagrams {self.bad}")


class JsonPhysics:
    """The plant behind the JSON interface, without sockets: `answer(packet)` steps and replies."""

    def __init__(self, scenario: Scenario, airframe: Airframe, seed: int = 0, log=print, start_on_hold: bool = True):
        self.scenario, self.airframe, self._log, self._seed = scenario, airframe, log, seed
        self.start_on_hold = start_on_hold
        north, east, _ = scenario.start.ned_m
        rest_down_m = -0.5 * airframe.body_box_size_m[2]        # the hull's belly on the floor
        self.plant = Plant(airframe, scenario.plant, start_ned_m=(north, east, rest_down_m),
                           start_yaw_rad=scenario.start.yaw_rad, seed=seed)
        self.plant.command_throttle([0.0] * ROTOR_COUNT)
        self.now_ms = 0
        self.scenario_t0_ms: int | None = None     # when the scenario's clock started (physics time)
        self.start_held_ms: int | None = None      # when the robot first held the start point
        self._start_asked = False
        self._held_since_ms: int | None = None
        self._faults = FaultSchedule(scenario.faults)
        self._hip_goals = [float("nan")] * ROTOR_COUNT
        self._last_count: int | None = None
        self._last_line = b""
        self.counters = PhysicsCounters()
        self.observers = []                        # called with (now_ms, plant) at every instant

    def answer(self, packet: ServoPacket) -> bytes:
        c = self.counters
        if packet.frame_count == self._last_count:
            c.repeated += 1
            return self._last_line
        if self._last_count is not None and packet.frame_count != self._last_count + 1:
            c.missed += abs(packet.frame_count - self._last_count - 1)
        self._last_count = packet.frame_count
        self._command(packet)
        steps = max(1, round(1.0 / (packet.frame_rate_hz * self.plant.physics_dt_s)))
        for _ in range(steps):
            self.plant.step(self.plant.physics_dt_s)
            self.now_ms += round(self.plant.physics_dt_s * 1000)
            self._at_instant()
        c.answered += 1
        self._last_line = self._sensor_line()
        return self._last_line

    def _command(self, packet: ServoPacket) -> None:
        self.plant.command_throttle(motor_throttles(packet))
        goals = hip_goals_rad(packet, self.airframe)
        if not np.allclose(goals, self._hip_goals, equal_nan=True):
            self._hip_goals = goals
            self.plant.command_hips(goals)

    def start_scenario(self) -> None:
        """Start the scenario's clock at the next instant (from another thread too)."""
        self._start_asked = True

    def _at_instant(self) -> None:
        if self.scenario_t0_ms is None and self._start_asked:
            self._start_clock("started on request")
        if self.scenario_t0_ms is None:
            if self.start_held_ms is None:
                self._watch_start()
        else:
            for fault, ends in self._faults.due(self.now_ms - self.scenario_t0_ms):
                self.plant.set_rotor_loss(fault.rotor, 0.0 if ends else fault.loss, fault.kind)
                self._log(f"t={self.now_ms / 1000:.3f} s (scenario t={(self.now_ms - self.scenario_t0_ms) / 1000:.3f} s): "
                          f"{describe(fault, ends)}")
        for observe in self.observers:
            observe(self.now_ms, self.plant)

    def _watch_start(self) -> None:
        s = self.plant.state()
        at_start = (not s.on_ground and np.linalg.norm(s.pos_ned_m - self.scenario.start.ned_m) < START_RADIUS_M
                    and np.linalg.norm(s.vel_ned_m_s) < START_SPEED_M_S)
        if not at_start:
            self._held_since_ms = None
        elif self._held_since_ms is None:
            self._held_since_ms = self.now_ms
        elif self.now_ms - self._held_since_ms >= round(START_HOLD_S * 1000):
            self.start_held_ms = self.now_ms
            self._log(f"t={self.now_ms / 1000:.3f} s: the robot holds the scenario's start point")
            if self.start_on_hold:
                self._start_clock("started on the hold")

    def _start_clock(self, why: str) -> None:
        self.scenario_t0_ms = self.now_ms
        if self.scenario.wind is not None:                 # the scenario's air, its gusts on its clock
            self.plant.blow(self.scenario.wind, height_m=-float(self.scenario.start.ned_m[2]), seed=self._seed)
        self._log(f"t={self.now_ms / 1000:.3f} s: scenario {self.scenario.name!r} t=0 ({why})")

    def _sensor_line(self) -> bytes:
        p = self.plant
        s = p.state()
        return sensor_line(self.now_ms / 1000.0, s.rates_frd_rad_s, p.specific_force_frd_m_s2(), s.pos_ned_m,
                           s.vel_ned_m_s, s.quat_wxyz, s.battery_voltage_v, float(np.sum(s.esc_current_a)))


class PhysicsServer:
    """JsonPhysics on a UDP socket at 127.0.0.1:port: answers whoever sent the packet."""

    def __init__(self, options: PhysicsOptions, airframe: Airframe | None = None, log=print):
        self.options, self._log = options, log
        self.physics = JsonPhysics(options.scenario, airframe or load_airframe(), options.seed, log,
                                   options.start_on_hold)
        self.truth = TruthRecorder() if options.truth_log_path else None
        if self.truth is not None:
            self.physics.observers.append(self.truth.observe)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self.sock.bind(("127.0.0.1", options.port))
        except OSError as e:
            self.sock.close()
            raise OSError(f"cannot listen on udp 127.0.0.1:{options.port}: {e.strerror}") from None
        self.sock.settimeout(POLL_S)
        self.port = self.sock.getsockname()[1]
        self._stop = False

    def stop(self) -> None:
        """Ask the loop to end (from another thread or a signal handler)."""
        self._stop = True

    def run(self) -> None:
        end_ms = None if self.options.duration_s is None else round(self.options.duration_s * 1000)
        ph, c = self.physics, self.physics.counters
        self._log(f"physics for ArduPilot SITL (JSON) on udp 127.0.0.1:{self.port}, scenario "
                  f"{self.options.scenario.name!r}")
        wall0 = time.monotonic()
        try:
            while not self._stop and (end_ms is None or ph.now_ms < end_ms):
                try:
                    data, sender = self.sock.recvfrom(512)
                except TimeoutError:
                    continue
                try:
                    packet = parse_servo_packet(data)
                except BadPacket as e:
                    c.bad += 1
                    if c.bad <= BAD_PACKETS_LOGGED:
                        self._log(f"ignored a datagram from {sender[0]}:{sender[1]}: {e}")
                    continue
                self.sock.sendto(ph.answer(packet), sender)
        finally:
            wall = time.monotonic() - wall0
            self._log(f"stopped at t={ph.now_ms / 1000:.3f} s after {wall:.1f} s wall "
                      f"({ph.now_ms / 1000 / max(wall, 1e-9):.1f}x); {c.summary()}")

    def close(self) -> None:
        self.sock.close()
        if self.truth is not None:
            self.truth.save(self.options.truth_log_path)
            self.truth = None
