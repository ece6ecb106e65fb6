"""The FC's own failsafe after a rotor loss (issue 10 item 3): the companion, flying on three
rotors, is killed (SIGKILL) 1 s after the fault; the FC lands on the three live rotors without
flipping, disarms, and a later companion's setpoints do not spin the motors until it re-arms.
A rotor lost while the FC flies alone is seen on its ESC speed, with the same landing."""

from __future__ import annotations

import os
import select
import signal
import subprocess
import sys

import numpy as np
import pytest

from m4.airframe import load_airframe
from m4.mavlink import mavlink
from sitl.fc.flight_controller import FcMode
from sitl.flights.flight_run import free_port
from m4.scenario import Fault, Scenario
from sitl.serve import ServeOptions, Server
from sitl.standin_companion import StandInCompanion, served
from sitl.plant.truth import load_truth

m = mavlink
pytestmark = pytest.mark.flight
FAULT_S, KILL_S = 1.0, 2.0


def _companion(tmp_path, port):
    """The real companion, returned once it has said it is ready (m4-companion run --ready-fd)."""
    config = tmp_path / "companion.toml"
    config.write_text(f'[link]\nfc_url = "udpin:127.0.0.1:{port}"\nsigning = false\n')
    log_path = tmp_path / "companion.log"
    read_end, write_end = os.pipe()
    with log_path.open("w") as log:
        proc = subprocess.Popen([sys.executable, "-m", "companion.cli", "run", "--config", str(config),
                                 "--ready-fd", str(write_end)],
                                stdout=subprocess.DEVNULL, stderr=log, stdin=subprocess.DEVNULL, pass_fds=(write_end,))
    os.close(write_end)
    with os.fdopen(read_end) as ready:
        said = ready.readline() if select.select([ready], [], [], 60.0)[0] else ""
    assert said.startswith("ready:") and proc.poll() is None, log_path.read_text()
    return proc


def test_companion_killed_after_a_rotor_loss_the_fc_lands_on_three_rotors(tmp_path):
    port = free_port()
    proc = _companion(tmp_path, port)
    scenario = Scenario(name="rotor-loss", duration_s=60.0, faults=(Fault(at_s=FAULT_S, rotor=4, loss=1.0),))
    server = Server(ServeOptions(scenario=scenario, mavlink_urls=(f"udpout:127.0.0.1:{port}",), duration_s=8.0,
                                 lockstep_timeout_s=0.3, truth_log_path=tmp_path / "truth.npz"))

    def kill(now_ms, plant):
        if now_ms >= KILL_S * 1000 and proc.poll() is None:
            os.kill(proc.pid, signal.SIGKILL)
            proc.wait()

    server.vehicle.observers.append(kill)
    try:
        server.run()
    finally:
        server.close()
        if proc.poll() is None:
            proc.kill()
    fc = server.vehicle.fc
    truth = load_truth(tmp_path / "truth.npz")
    after = truth.time_s >= KILL_S
    tilt_deg = np.degrees(np.arccos(np.cos(truth.euler_rad[:, 0]) * np.cos(truth.euler_rad[:, 1])))
    touchdown = int(np.argmax(truth.on_ground & after))
    print(f"companion killed at {KILL_S:g} s, {KILL_S - FAULT_S:g} s after rotor 4 failed: max tilt afterwards "
          f"{tilt_deg[after].max():.0f} deg, touchdown at {truth.time_s[touchdown]:.2f} s at "
          f"{truth.vel_ned_m_s[touchdown, 2]:.2f} m/s, tilt {tilt_deg[touchdown]:.1f} deg")
    assert fc.lost_rotor() == 4                        # from the companion's last M4_FAULT_STATUS
    assert truth.on_ground[touchdown] and truth.time_s[touchdown] > KILL_S
    assert tilt_deg[after].max() < 45.0 and tilt_deg[-1] < 10.0
    assert truth.vel_ned_m_s[touchdown, 2] < 1.0
    assert (fc.mode, fc.armed) == (FcMode.LANDED, False)
    assert np.all(truth.thrust_cmd_n[-1] == 0.0)


def test_after_a_thrust_cut_setpoints_move_no_motor_until_the_companion_re_arms():
    hover = load_airframe().hover_thrust_per_rotor_n
    phase = {"cut": True}
    companion = StandInCompanion(answer=lambda t_ms: ([hover] * 4, [0.78] * 4, [0.0] * 4,
                                                      m.M4_SETPOINT_FLAG_THRUST_CUT if phase["cut"] else 0))
    with served(companion, ServeOptions(scenario=Scenario(name="hover", duration_s=60.0), realtime=True)) as server:
        fc = server.vehicle.fc
        assert companion.wait_for("HEARTBEAT", lambda h: not h.base_mode & m.MAV_MODE_FLAG_SAFETY_ARMED, 5.0)
        phase["cut"] = False                            # "a restarted companion": plain setpoints again
        t_ms = companion.of_type("ATTITUDE")[-1].time_boot_ms
        still = companion.wait_for("M4_THRUSTER_STATUS", lambda s: s.time_boot_ms > t_ms + 300, 5.0)
        refused = fc.counters.dropped_by_reason["disarmed"]
        companion.send(m.MAVLink_command_long_message(1, 1, m.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0))
        ack = companion.wait_for("COMMAND_ACK", lambda a: a.command == m.MAV_CMD_COMPONENT_ARM_DISARM, 5.0)
        spinning = companion.wait_for("M4_THRUSTER_STATUS", lambda s: min(s.thrust_cmd_n) > 0.9 * hover, 5.0)
    assert list(still.thrust_cmd_n) == [0.0] * 4
    assert refused > 5
    assert ack.result == m.MAV_RESULT_ACCEPTED
    assert spinning is not None and fc.armed


def test_a_rotor_lost_while_the_fc_holds_alone_is_seen_on_its_esc_speed_and_it_lands_on_three(tmp_path):
    companion = StandInCompanion(until_ms=300)               # then gone: the FC holds on its own
    scenario = Scenario(name="rotor-loss", duration_s=60.0, faults=(Fault(at_s=FAULT_S, rotor=2, loss=1.0),))
    options = ServeOptions(scenario=scenario, duration_s=6.0, lockstep_timeout_s=0.2,
                           truth_log_path=tmp_path / "truth.npz")
    with served(companion, options) as server:
        assert companion.wait_for("M4_THRUSTER_STATUS", lambda s: s.time_boot_ms >= 6000, 60.0)
    truth = load_truth(tmp_path / "truth.npz")
    tilt_deg = np.degrees(np.arccos(np.cos(truth.euler_rad[:, 0]) * np.cos(truth.euler_rad[:, 1])))
    texts = [t.text for t in companion.of_type("STATUSTEXT")]
    touchdown = int(np.argmax(truth.on_ground))
    print(f"rotor 2 lost at {FAULT_S:g} s in the FC's own HOLD: max tilt {tilt_deg.max():.0f} deg, touchdown "
          f"at {truth.time_s[touchdown]:.2f} s at {truth.vel_ned_m_s[touchdown, 2]:.2f} m/s")
    assert "FC: rotor 2 lost (ESC speed)" in texts
    assert server.vehicle.fc.lost_rotor() == 2
    assert truth.on_ground[touchdown] and truth.vel_ned_m_s[touchdown, 2] < 1.0
    assert tilt_deg.max() < 60.0 and tilt_deg[-1] < 10.0
