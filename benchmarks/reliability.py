"""The companion's fail-safe probes (issue 20), in real time, judged from the plant's truth.

    python -m benchmarks.reliability stale [--scenario NAME] [--altitude-m A] [--at-s T] [--seconds S] [--out DIR]
    python -m benchmarks.reliability restart [--scenario NAME] [--altitude-m A] [--kill-at-s T]... [--seconds S]
                                             [--out DIR]

Each flies the scenario (default hover-rotor-loss: rotor 4 stops at 1 s) paced by the wall
clock: the companion (`m4-companion run`) and the SITL (`m4-sitl serve --realtime`, with a
second link on which a ground station may speak) as two processes on loopback; with
--altitude-m, from that height instead of the scenario's start (a restarted companion takes a
few seconds to start on a busy machine, while the FC's failsafe lands at 0.5 m/s).

- stale: at T (default 3 s) a ground station on its own link, with the flight's signing key
  and the companion's ids (all it takes; unsigned, anyone could), stops ATTITUDE and
  ATTITUDE_QUATERNION with two MAV_CMD_SET_MESSAGE_INTERVAL (interval -1). Figures from T on: the largest horizontal
  drift and drop of the centre of mass, the largest tilt, the first ground contact; what the
  companion said about it (its log lines and STATUSTEXT with "stale"); what the station still
  heard of the two streams on its own link after the FC acknowledged the stop.
- restart: at each T (default 3 and 6 s) the companion is killed (SIGKILL) and started again
  at once. Figures per restart: how long after the new companion was ready it took control
  (its first setpoint), the first fault status it sent (healthy overwrites the fault the FC
  kept), the thrust it commanded the dead rotor over the first 0.3 s, the largest thrust step
  between two 10 ms truth samples around the takeover, the altitude at the takeover and 1 s
  later; at the end whether the robot stands on the ground (the FC's landing, not cancelled).

Both ends sign with a key new for the flight, as `m4-sitl fly` does. Every figure comes from
truth.npz (the plant) and the SITL's tlog (what crossed the links), both kept in --out
(default: a temporary folder), with the two processes' logs.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from analysis.measures import tilt_deg
from m4.mavlink import COMPANION_COMPONENT_ID, FC_SYSTEM_ID, mavlink, mavutil
from m4.mavlink.link import UdpLink, wait_readable
from sitl import scenarios
from m4.arguments import positive_number
from m4.mavlink.signing import load_key, write_new_key
from m4.toml_fields import ConfigError
from sitl.flights.flight_run import (COMPANION, SIGNING_KEY, SITL, FlightError, FlightOptions, _await_ready, _start,
                                     companion_config_text, free_port, make_output_dir, start_process)
from sitl.plant.truth import Truth, load_truth

m = mavlink
STEP_WINDOW_S = 0.15            # thrust steps are looked for from the instant the first setpoint answers to
                                # this later (it acts a link delay and a control step after)
DEAD_ROTOR_WINDOW_S = 0.3
STATION_WATCH_S = 1.0           # stale: how long the station listens (FC time) after it stopped its streams


def at_altitude(scenario: str, altitude_m: float | None, out: Path) -> Path:
    """The scenario's file, or a copy in `out` that starts altitude_m above the ground."""
    path = scenarios.scenario_path(scenario)
    if altitude_m is None:
        return path
    start = re.compile(r"(\[start\][^\[]*?ned_m\s*=\s*\[[^,\]]*,[^,\]]*,)[^\]]*(\])")
    text, found = start.subn(rf"\g<1> {-altitude_m!r}\2", path.read_text(), count=1)
    if not found:
        raise ConfigError(f"{path.name}: no [start] ned_m to move to {altitude_m:g} m")
    copy = out / "scenario.toml"
    copy.write_text(text)
    return copy


class Rig:
    """The companion and the SITL of one probe flight, started in `out`."""

    def __init__(self, scenario: Path, seconds: float, out: Path, stack: contextlib.ExitStack):
        self.out, self.stack = out, stack
        self.scenario = scenario
        self.port, self.gcs_port = free_port(), free_port()
        key = out / SIGNING_KEY
        key.unlink(missing_ok=True)
        write_new_key(key)
        self.config = out / "companion.toml"
        self.config.write_text(companion_config_text(FlightOptions(realtime=True), self.port, None))
        self.companion: subprocess.Popen | None = None
        self.ready_unix_s: list[float] = []
        self.starts = 0
        self.start_companion()
        self.sitl = _start(stack, start_process(SITL, [
            "serve", "--realtime", "--scenario", str(self.scenario), "--duration", f"{seconds:g}",
            "--tlog", str(out / "flight.tlog"), "--truth-log", str(out / "truth.npz"), "--signing-key", str(key),
            "--mavlink", f"udpout:127.0.0.1:{self.port}", "--mavlink", f"udpin:127.0.0.1:{self.gcs_port}"],
            out / "sitl.log"))
        # the ground station's link, as the paired companion's ids (the FC answers only those
        # there), signed with the key on a signing link of its own
        self.gcs = UdpLink(f"udpout:127.0.0.1:{self.gcs_port}", FC_SYSTEM_ID, COMPANION_COMPONENT_ID,
                           key=load_key(key), link_id=1)
        stack.callback(self.gcs.close)
        self.sim_s = 0.0
        self.station: list[tuple[float, mavlink.MAVLink_message]] = []   # what it heard, at the FC time then reached

    def start_companion(self) -> None:
        self.starts += 1
        args = ["run", "--config", str(self.config)]
        if "mission" in tomllib.loads(self.scenario.read_text()):
            args += ["--mission", str(self.scenario)]
        log = self.out / f"companion-{self.starts}.log"
        ready_r, ready_w = os.pipe()
        try:
            self.companion = _start(self.stack, start_process(COMPANION, args, log, ("--ready-fd", ready_w)))
        finally:
            os.close(ready_w)
        try:
            _await_ready(self.companion, ready_r, log)
        finally:
            os.close(ready_r)
        self.ready_unix_s.append(time.time())

    def kill_companion(self) -> None:
        self.companion.send_signal(signal.SIGKILL)
        self.companion.wait()

    def wait_until(self, t_s: float) -> None:
        """Until the FC's clock, as its telemetry on the ground station's link says, reaches t_s."""
        beat_s = 0.0
        while self.sim_s < t_s:
            if self.sitl.poll() is not None:
                raise RuntimeError(f"the SITL stopped before t = {t_s:g} s: see {self.out / 'sitl.log'}")
            if time.monotonic() >= beat_s:         # how the FC learns where the ground station is
                self.gcs.send(m.MAVLink_heartbeat_message(m.MAV_TYPE_GCS, m.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3))
                beat_s = time.monotonic() + 0.5
            wait_readable([self.gcs], 0.01)
            for msg in self.gcs.receive():
                if (stamp_ms := getattr(msg, "time_boot_ms", None)) is not None:
                    self.sim_s = max(self.sim_s, stamp_ms / 1000.0)
                self.station.append((self.sim_s, msg))

    def wait_for_end(self) -> None:
        self.sitl.wait()

    def companion_said(self, word: str) -> int:
        return sum(word in line for log in self.out.glob("companion-*.log") for line in log.read_text().splitlines())


def _tlog(path: Path) -> list:
    conn = mavutil.mavlink_connection(str(path), dialect="m4")
    out = []
    while (msg := conn.recv_match()) is not None:
        out.append(msg)
    return out


def _ours(msgs: list) -> list:
    """The companion's messages, each once (the SITL's tlog has what it routes to the ground
    station's link a second time, the same packet)."""
    out, seen = [], set()
    for msg in msgs:
        key = bytes(msg.get_msgbuf())
        if msg.get_srcComponent() == COMPANION_COMPONENT_ID and key not in seen:
            seen.add(key)
            out.append(msg)
    return out


def _at(truth: Truth, t_s: float) -> int:
    return min(int(np.searchsorted(truth.time_s, t_s)), len(truth.time_s) - 1)


@dataclass(frozen=True)
class Motion:
    drift_m: float              # largest horizontal distance of the centre of mass from where it was
    drop_m: float               # largest drop of the centre of mass below where it was
    tilt_deg: float
    contact_s: float | None     # first ground contact

    def __str__(self) -> str:
        contact = "none" if self.contact_s is None else f"at {self.contact_s:.2f} s"
        return (f"drift {self.drift_m:.2f} m, drop {self.drop_m:.2f} m, tilt {self.tilt_deg:.1f} deg, "
                f"ground contact {contact}")


def motion_from(truth: Truth, t_s: float) -> Motion:
    k = _at(truth, t_s)
    com = truth.com_ned_m[k:]
    contact = np.flatnonzero(truth.on_ground[k:])
    return Motion(drift_m=float(np.max(np.linalg.norm(com[:, :2] - com[0, :2], axis=1))),
                  drop_m=float(max(np.max(com[:, 2] - com[0, 2]), 0.0)),
                  tilt_deg=float(np.max(tilt_deg(truth.euler_rad[k:]))),
                  contact_s=None if contact.size == 0 else float(truth.time_s[k + contact[0]]))


def third_party_stops_attitude(gcs: UdpLink) -> None:
    """Two MAV_CMD_SET_MESSAGE_INTERVAL (-1) from the ground station's link, as system 1
    component 191: ATTITUDE and ATTITUDE_QUATERNION stop."""
    for msg_id in (m.MAVLINK_MSG_ID_ATTITUDE, m.MAVLINK_MSG_ID_ATTITUDE_QUATERNION):
        gcs.send(m.MAVLink_command_long_message(FC_SYSTEM_ID, 1, m.MAV_CMD_SET_MESSAGE_INTERVAL, 0,
                                                float(msg_id), -1.0, 0, 0, 0, 0, 0))


def attitude_after_the_stop(station: list[tuple[float, mavlink.MAVLink_message]]) -> int | None:
    """ATTITUDE and ATTITUDE_QUATERNION the station heard stamped after the FC time it had
    reached when the second COMMAND_ACK came (the FC had stopped them by then); None: no acks."""
    acked = [t_s for t_s, msg in station
             if msg.get_type() == "COMMAND_ACK" and msg.command == m.MAV_CMD_SET_MESSAGE_INTERVAL]
    if len(acked) < 2:
        return None
    return sum(msg.get_type() in ("ATTITUDE", "ATTITUDE_QUATERNION") and msg.time_boot_ms / 1000.0 > acked[1]
               for _, msg in station)


@dataclass(frozen=True)
class StaleFigures:
    at_s: float
    motion: Motion              # from at_s on
    log_lines: int              # the companion's log lines on stale streams
    statustext: list[str]       # its STATUSTEXT on stale and fresh streams
    station_attitude: int | None    # what the station heard of the two streams after they were stopped (None: no acks)

    def __str__(self) -> str:
        station = "not acknowledged" if self.station_attitude is None else f"{self.station_attitude} after the acks"
        return (f"ATTITUDE and ATTITUDE_QUATERNION stopped at {self.at_s:g} s: {self.motion}; the companion's log: "
                f"{self.log_lines} lines on stale streams; its STATUSTEXT: {self.statustext}; the station's "
                f"own ATTITUDE and ATTITUDE_QUATERNION: {station}")


def stale(scenario: str, at_s: float, seconds: float, out: Path, altitude_m: float | None = None) -> StaleFigures:
    with contextlib.ExitStack() as stack:
        rig = Rig(at_altitude(scenario, altitude_m, out), seconds, out, stack)
        rig.wait_until(at_s)
        third_party_stops_attitude(rig.gcs)
        rig.wait_until(min(at_s + STATION_WATCH_S, seconds - STATION_WATCH_S / 2))
        rig.wait_for_end()
    texts = [msg.text for msg in _ours(_tlog(out / "flight.tlog")) if msg.get_type() == "STATUSTEXT"]
    return StaleFigures(at_s, motion_from(load_truth(out / "truth.npz"), at_s), rig.companion_said("stale"),
                        [t for t in texts if "stale" in t or "fresh" in t], attitude_after_the_stop(rig.station))


@dataclass(frozen=True)
class Takeover:
    ready_to_control_s: float   # from the restarted companion's ready line to its first setpoint (wall)
    first_fault_state: int      # M4_FAULT_STATE of its first M4_FAULT_STATUS
    confirmed_after_s: float | None   # from its first setpoint to its first confirmed fault status (FC clock)
    dead_rotor_max_n: float     # the largest thrust commanded the dead rotor in the first 0.3 s
    thrust_step_n: float        # the largest change between two truth samples around the takeover
    altitude_m: float           # of the centre of mass at the takeover
    altitude_1s_m: float        # 1 s later

    def __str__(self) -> str:
        state = {0: "healthy", 1: "suspect", 2: "confirmed"}.get(self.first_fault_state, "?")
        confirmed = "never" if self.confirmed_after_s is None else f"{1000 * self.confirmed_after_s:.0f} ms later"
        return (f"control {self.ready_to_control_s:.2f} s after ready; first fault status {state}, confirmed "
                f"{confirmed}; dead rotor "
                f"up to {self.dead_rotor_max_n:.1f} N; thrust step {self.thrust_step_n:.1f} N; altitude "
                f"{self.altitude_m:.2f} m, 1 s later {self.altitude_1s_m:.2f} m")


def _takeovers(truth: Truth, msgs: list, ready_unix_s: list[float], dead_rotor: int) -> list[Takeover | None]:
    """One per restart: the first setpoint after each ready line (None: it never took control)."""
    ours = _ours(msgs)
    out = []
    for ready in ready_unix_s[1:]:
        after = [msg for msg in ours if msg._timestamp >= ready]
        setpoint = next((msg for msg in after if msg.get_type() == "M4_SETPOINT"), None)
        if setpoint is None:
            out.append(None)
            continue
        statuses = [msg for msg in after if msg.get_type() == "M4_FAULT_STATUS"]
        confirmed = next((msg for msg in statuses if msg.state == m.M4_FAULT_STATE_CONFIRMED), None)
        t_s = setpoint.time_boot_ms / 1000.0
        k0, k1, k_dead = _at(truth, t_s), _at(truth, t_s + STEP_WINDOW_S), _at(truth, t_s + DEAD_ROTOR_WINDOW_S)
        steps = np.abs(np.diff(truth.thrust_cmd_n[k0:k1 + 1], axis=0))
        out.append(Takeover(ready_to_control_s=setpoint._timestamp - ready, first_fault_state=int(statuses[0].state),
                            confirmed_after_s=None if confirmed is None else confirmed.time_boot_ms / 1000.0 - t_s,
                            dead_rotor_max_n=float(np.max(truth.thrust_cmd_n[_at(truth, t_s):k_dead + 1, dead_rotor - 1])),
                            thrust_step_n=float(np.max(steps, initial=0.0)),
                            altitude_m=float(-truth.com_ned_m[_at(truth, t_s), 2]),
                            altitude_1s_m=float(-truth.com_ned_m[_at(truth, t_s + 1.0), 2])))
    return out


@dataclass(frozen=True)
class RestartFigures:
    kill_at_s: list[float]
    takeovers: list[Takeover | None]   # one per restart (None: it never took control)
    end_s: float
    end_altitude_m: float
    standing: bool              # on the ground with the motors off at the end

    def __str__(self) -> str:
        lines = [f"restart {i + 1} (killed at {t:g} s): {tk or 'no control before the end of the flight'}"
                 for i, (t, tk) in enumerate(zip(self.kill_at_s, self.takeovers))]
        lines.append(f"at the end ({self.end_s:.1f} s): altitude {self.end_altitude_m:.2f} m, "
                     f"{'on the ground, motors off' if self.standing else 'in the air or motors on'}")
        return "\n".join(lines)


def restart(scenario: str, kill_at_s: list[float], seconds: float, out: Path,
            altitude_m: float | None = None) -> RestartFigures:
    with contextlib.ExitStack() as stack:
        rig = Rig(at_altitude(scenario, altitude_m, out), seconds, out, stack)
        for t_s in kill_at_s:
            rig.wait_until(t_s)
            rig.kill_companion()
            rig.start_companion()
        rig.wait_for_end()
    truth = load_truth(out / "truth.npz")
    faults = scenarios.resolve(scenario).faults
    takeovers = _takeovers(truth, _tlog(out / "flight.tlog"), rig.ready_unix_s, faults[0].rotor if faults else 4)
    return RestartFigures(kill_at_s, takeovers, float(truth.time_s[-1]), float(-truth.com_ned_m[-1, 2]),
                          bool(truth.on_ground[-1]) and float(np.max(np.abs(truth.thrust_cmd_n[-1]))) == 0.0)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.reliability", description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="probe", required=True)
    for name, seconds in (("stale", 8.0), ("restart", 10.0)):
        s = sub.add_parser(name)
        s.add_argument("--scenario", default="hover-rotor-loss", help="built-in name or file (default hover-rotor-loss)")
        s.add_argument("--seconds", type=positive_number, default=seconds, help=f"the flight (default {seconds:g})")
        s.add_argument("--altitude-m", type=positive_number, help="start this high (default: the scenario's start)")
        s.add_argument("--out", type=Path, help="keep the flight's files here (default: a temporary folder)")
    sub.choices["stale"].add_argument("--at-s", type=positive_number, default=3.0,
                                      help="when the streams are stopped (default 3)")
    sub.choices["restart"].add_argument("--kill-at-s", type=positive_number, action="append",
                                        help="when the companion is killed; repeat (default 3 and 6)")
    args = p.parse_args(argv)
    times = [args.at_s] if args.probe == "stale" else args.kill_at_s or [3.0, 6.0]
    try:
        scenarios.resolve(args.scenario)
        if max(times) >= args.seconds or times != sorted(times):
            raise ConfigError(f"the times ({', '.join(f'{t:g}' for t in times)} s) must rise and end before "
                              f"--seconds {args.seconds:g}")
        with contextlib.ExitStack() as stack:
            out = args.out or Path(stack.enter_context(tempfile.TemporaryDirectory()))
            make_output_dir(out)
            probe = stale if args.probe == "stale" else restart
            print(probe(args.scenario, times[0] if args.probe == "stale" else times, args.seconds, out, args.altitude_m))
    except (FlightError, ConfigError) as e:
        print(f"python -m benchmarks.reliability: error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
