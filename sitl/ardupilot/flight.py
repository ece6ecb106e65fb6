"""A flight through the real ArduCopter SITL: `m4-sitl fly-ardupilot SCENARIO [--companion]`.

The physics (sitl/ardupilot/physics.py) runs in this process; `arducopter` runs in a working
folder under the output folder with ArduPilot's SITL defaults and deploy/ardupilot/m4.parm.
Over MAVLink (tcp 127.0.0.1:5760 + 10 x instance, as a ground station: a HEARTBEAT first)
this waits for EKF3 to use GPS, switches to GUIDED, arms, takes off to the scenario's start
height, and lets the scenario run from when the robot holds its start point (the physics
starts the scenario's clock then, and its faults with it) to its duration. Then it stops
both, and writes truth.npz, statustext.txt (what ArduPilot said, on the physics' clock),
metrics.json and flight.png. The binary: ARDUPILOT_SITL, else ../shared/ardupilot/arducopter
beside the repository. The M4 applet (deploy/ardupilot/scripts/m4_fc.lua) is in the working
folder's scripts/ and idles until M4_ENABLE is set.

With the companion (`companion=True`) the companion starts first (sitl/ardupilot/companion_process.py)
and arducopter's SERIAL1 connects to it. Boot and takeoff go as above; once the robot holds
its start point, SIM_SPEEDUP goes to 1 (the companion runs on the wall clock), M4_ENABLE to 1,
and the scenario's clock starts when the applet says it flies the companion's setpoints.

With `priority` P (1..99) the companion's control loop runs in SCHED_FIFO at P once its NMPC is
built, and every thread of arducopter and of this process (the physics) from the handover on,
when the flight goes real time: a busy machine then delays them by a context switch, not a
time slice. None of the three busy-waits (the physics and arducopter block on their sockets,
the companion on its link until its next step is due), so they leave the cores to others
between steps. Before the handover, at `speedup`, they run at normal priority: there they run
flat out and would take a core.
"""

from __future__ import annotations

import contextlib
import json
import os
import random
import shutil
import socket
import subprocess
import threading
import time
import tomllib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from m4.mavlink import mavlink, mavutil
from m4.scenario import Scenario
from sitl.ardupilot.companion_process import start_companion
from sitl.ardupilot.physics import DEFAULT_PORT, PhysicsOptions, PhysicsServer
from sitl.flights.flight_run import FlightError, free_port, real_time
from sitl.plant.truth import Truth, load_truth

REPO = Path(__file__).resolve().parents[2]
DEFAULT_BINARY = REPO.parent / "shared" / "ardupilot" / "arducopter"
PARAMS = REPO / "deploy" / "ardupilot" / "m4.parm"
APPLET = REPO / "deploy" / "ardupilot" / "scripts" / "m4_fc.lua"
GCS_IDS = (255, 190)
GUIDED = 4                          # ArduCopter's custom mode number
EKF_READY_TEXT = "EKF3 IMU0 is using GPS"
APPLET_FLYING_TEXT = "m4: flying companion setpoints"
CONNECT_TIMEOUT_S = 30.0
PRIORITY_MAX = 99                # Linux's SCHED_FIFO range is 1..99
INSTANCES = 100                  # arducopter -I 0..99 keeps every port it uses below 10000
INSTANCE_PORTS = ((socket.SOCK_STREAM, 5760), (socket.SOCK_STREAM, 5762), (socket.SOCK_STREAM, 5763),
                  (socket.SOCK_DGRAM, 5501), (socket.SOCK_DGRAM, DEFAULT_PORT))
AFTER_DISARM_MS = 2000           # the flight ends this long after ArduPilot disarms (a crash)


def free_instance() -> int:
    """An arducopter instance (-I) whose ports on 127.0.0.1 are free now: its MAVLink TCP servers
    (SERIAL0..2, 5760/5762/5763 + 10 I), its RC input (UDP 5501 + 10 I) and the physics' JSON port
    (UDP 9002 + 10 I). Tried from a random one, so two flights started at once rarely meet."""
    first = random.SystemRandom().randrange(1, INSTANCES)
    for instance in (*range(first, INSTANCES), *range(1, first)):
        if all(_port_free(kind, port + 10 * instance) for kind, port in INSTANCE_PORTS):
            return instance
    raise FlightError(f"no arducopter instance 1..{INSTANCES - 1} has its ports free on 127.0.0.1")


def _port_free(kind: int, port: int) -> bool:
    with socket.socket(socket.AF_INET, kind) as s:
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


def sitl_binary() -> Path:
    """ArduCopter SITL: ARDUPILOT_SITL, else ../shared/ardupilot/arducopter beside the repository."""
    return Path(os.environ.get("ARDUPILOT_SITL", DEFAULT_BINARY))


@dataclass(frozen=True)
class ArduFlightOptions:
    scenario: Scenario
    out_dir: Path
    speedup: float = 10.0
    instance: int = 0               # arducopter -I: MAVLink on 5760 + 10 I, physics on 9002 + 10 I
    timeout_s: float = 600.0        # wall clock for the whole flight
    companion: bool = False         # the companion flies through the M4 applet
    scenario_file: Path | None = None   # the scenario's file: the companion's mission (with companion)
    priority: int = 0               # SCHED_FIFO priority from the handover on, 1..99 (0: normal; with companion)
    shortfall_cover: bool = True    # the companion asks the applet for the shortfall cover (with companion)
    before_arming: Callable[[], None] | None = None   # called once EKF3 uses GPS: a ground station of the
    #                                   caller's may select GUIDED and arm there (the flight then finds it so)


def fly_ardupilot(options: ArduFlightOptions, log=print) -> dict:
    if not 0 <= options.priority <= PRIORITY_MAX:
        raise FlightError(f"priority {options.priority}: a SCHED_FIFO priority is 1..{PRIORITY_MAX} (0: normal)")
    if options.priority and not options.companion:
        raise FlightError("a real-time priority is for a flight with the companion (it starts at the handover)")
    binary = sitl_binary()
    if not binary.is_file():
        raise FlightError(f"no ArduCopter SITL at {binary} (set ARDUPILOT_SITL)")
    out = options.out_dir
    work = out / "arducopter"
    (work / "scripts").mkdir(parents=True, exist_ok=True)
    shutil.copy(APPLET, work / "scripts")
    texts: list[tuple[float, str]] = []
    with contextlib.ExitStack() as stack:
        command = [str(binary), "--model", "JSON:127.0.0.1", "--speedup", f"{options.speedup:g}",
                   "--defaults", f"{binary.parent / 'copter.parm'},{PARAMS}", f"-I{options.instance}", "-w"]
        if options.companion:
            if options.scenario_file is None:
                raise FlightError("a flight with the companion needs the scenario's file (its mission)")
            text = options.scenario_file.read_text()
            (out / "scenario.toml").write_text(text)
            port = free_port(socket.SOCK_STREAM)
            start_companion(stack, out, port, out / "scenario.toml", "mission" in tomllib.loads(text),
                            options.priority, options.shortfall_cover)
            command += ["--serial1", f"tcpclient:127.0.0.1:{port}"]
        server = PhysicsServer(PhysicsOptions(scenario=options.scenario, port=DEFAULT_PORT + 10 * options.instance,
                                              truth_log_path=out / "truth.npz", start_on_hold=not options.companion),
                               log=log)
        thread = threading.Thread(target=server.run, daemon=True)
        thread.start()
        with open(work / "arducopter.log", "w") as sitl_log:
            sitl = subprocess.Popen(command, cwd=work, stdout=sitl_log, stderr=subprocess.STDOUT)
        try:
            _fly(options, server, sitl, texts, log)
        finally:
            if options.priority:
                real_time(os.getpid(), 0)       # the figures and files after the flight at normal priority
            sitl.kill()
            sitl.wait()
            server.stop()
            thread.join(10.0)
            server.close()
            (out / "statustext.txt").write_text("".join(f"{t:9.3f} {text}\n" for t, text in texts))
    t0_ms = server.physics.scenario_t0_ms
    metrics = flight_metrics(load_truth(out / "truth.npz"), options.scenario, t0_ms / 1000.0, texts)
    (out / "metrics.json").write_text(json.dumps(metrics, indent=2) + "\n")
    who = "the companion through the M4 applet" if options.companion else "ArduCopter 4.6.3's own controller"
    flight_figure(load_truth(out / "truth.npz"), options.scenario, t0_ms / 1000.0, out / "flight.png", who)
    return metrics


def _fly(options: ArduFlightOptions, server: PhysicsServer, sitl: subprocess.Popen, texts: list, log) -> None:
    physics = server.physics
    deadline = time.monotonic() + options.timeout_s
    link = _connect(5760 + 10 * options.instance, sitl, options.out_dir / "arducopter" / "arducopter.log")
    heartbeat_at = 0.0
    state = {"armed": False, "mode": None, "disarmed_ms": None}

    def pump(until) -> None:
        nonlocal heartbeat_at
        while not until():
            if sitl.poll() is not None:
                raise FlightError(f"arducopter exited ({sitl.returncode}) at physics t={physics.now_ms / 1000:.1f} s")
            if time.monotonic() > deadline:
                raise FlightError(f"timed out after {options.timeout_s:g} s wall at physics t={physics.now_ms / 1000:.1f} s "
                                  f"(last words: {texts[-3:]})")
            if time.monotonic() >= heartbeat_at:
                link.mav.heartbeat_send(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
                heartbeat_at = time.monotonic() + 1.0
            msg = link.recv_match(blocking=True, timeout=0.2)
            if msg is not None and msg.get_type() == "STATUSTEXT":
                texts.append((physics.now_ms / 1000.0, msg.text))
                log(f"t={physics.now_ms / 1000:.3f} s: ArduCopter: {msg.text}")
            if msg is not None and msg.get_type() == "HEARTBEAT" and msg.get_srcComponent() == 1:
                armed = bool(msg.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
                if state["armed"] and not armed:
                    state["disarmed_ms"] = physics.now_ms
                state["armed"], state["mode"] = armed, msg.custom_mode

    try:
        pump(lambda: any(text == EKF_READY_TEXT for _, text in texts))
        if options.before_arming is not None:
            options.before_arming()
        target = link.target_system
        while not (state["armed"] and state["mode"] == GUIDED):
            link.mav.command_long_send(target, 1, mavlink.MAV_CMD_DO_SET_MODE, 0,
                                       mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, GUIDED, 0, 0, 0, 0, 0)
            link.mav.command_long_send(target, 1, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
            retry = time.monotonic() + 2.0
            pump(lambda retry=retry: (state["armed"] and state["mode"] == GUIDED) or time.monotonic() > retry)
        height_m = -options.scenario.start.ned_m[2]
        link.mav.command_long_send(target, 1, mavlink.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 0, height_m)
        log(f"t={physics.now_ms / 1000:.3f} s: armed in GUIDED, taking off to {height_m:g} m")
        if options.companion:
            pump(lambda: physics.start_held_ms is not None)
            for name, value in (("SIM_SPEEDUP", 1.0), ("M4_ENABLE", 1.0)):
                link.mav.param_set_send(target, 1, name.encode(), value, mavlink.MAV_PARAM_TYPE_REAL32)
            if options.priority:
                for pid in (sitl.pid, os.getpid()):
                    real_time(pid, options.priority)
            log(f"t={physics.now_ms / 1000:.3f} s: real time, the applet engaged (M4_ENABLE 1)"
                + f", SCHED_FIFO {options.priority}" * bool(options.priority))
            pump(lambda: any(text == APPLET_FLYING_TEXT for _, text in texts))
            physics.start_scenario()
        pump(lambda: physics.scenario_t0_ms is not None)
        end_ms = physics.scenario_t0_ms + round(options.scenario.duration_s * 1000)
        pump(lambda: physics.now_ms >= end_ms or (state["disarmed_ms"] is not None
                                                  and physics.now_ms >= state["disarmed_ms"] + AFTER_DISARM_MS))
    finally:
        link.close()


def _connect(port: int, sitl: subprocess.Popen, sitl_log: Path):
    """MAVLink to SITL's SERIAL0 once it listens (it prints so; an older SITL may hold the port)."""
    give_up = time.monotonic() + CONNECT_TIMEOUT_S
    while "Waiting for connection" not in sitl_log.read_text():
        last = (sitl_log.read_text().strip().splitlines() or ["nothing"])[-1]
        if sitl.poll() is not None:
            raise FlightError(f"arducopter exited ({sitl.returncode}): {last}")
        if time.monotonic() > give_up:
            raise FlightError(f"arducopter did not open tcp 127.0.0.1:{port} in {CONNECT_TIMEOUT_S:g} s: {last}")
        time.sleep(0.2)
    return mavutil.mavlink_connection(f"tcp:127.0.0.1:{port}", source_system=GCS_IDS[0],
                                      source_component=GCS_IDS[1], retries=3)


def flight_metrics(truth: Truth, scenario: Scenario, t0_s: float, texts: list[tuple[float, str]]) -> dict:
    """Hover before the first fault (the scenario's clock from t0_s: its start hold, 2 s, included)
    and what came after it, from the plant's truth."""
    t = truth.time_s - t0_s
    first_fault_s = min((f.at_s for f in scenario.faults), default=scenario.duration_s)
    height_m = -scenario.start.ned_m[2]
    before = (t >= -1.0) & (t < first_fault_s)
    after = t >= first_fault_s
    tilt_deg = np.degrees(np.arccos(np.clip(np.cos(truth.euler_rad[:, 0]) * np.cos(truth.euler_rad[:, 1]), -1, 1)))
    altitude_m = -truth.pos_ned_m[:, 2]
    metrics = {
        "scenario": scenario.name, "scenario_t0_physics_s": t0_s,
        "hover": {"altitude_error_max_m": float(np.max(np.abs(altitude_m[before] - height_m))),
                  "altitude_error_mean_m": float(np.mean(altitude_m[before] - height_m)),
                  "horizontal_drift_max_m": float(np.max(np.linalg.norm(
                      truth.pos_ned_m[before, :2] - np.array(scenario.start.ned_m[:2]), axis=1))),
                  "tilt_max_deg": float(np.max(tilt_deg[before]))},
    }
    if scenario.faults and np.any(after):
        touched = after & truth.on_ground
        metrics["after_fault"] = {
            "tilt_max_deg": float(np.max(tilt_deg[after])),
            "yaw_rate_max_rad_s": float(np.max(np.abs(truth.rates_frd_rad_s[after, 2]))),
            "altitude_min_m": float(np.min(altitude_m[after])),
            "hit_the_floor_after_s": float(t[touched][0] - first_fault_s) if np.any(touched) else None,
            "ardupilot_said": [text for ts, text in texts if ts - t0_s >= first_fault_s],
        }
    return metrics


def flight_figure(truth: Truth, scenario: Scenario, t0_s: float, path: Path, who: str) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = truth.time_s - t0_s
    keep = t >= -10.0
    fig, axes = plt.subplots(3, 1, figsize=(8, 7), sharex=True)
    axes[0].plot(t[keep], -truth.pos_ned_m[keep, 2], label="altitude (m)")
    axes[0].axhline(-scenario.start.ned_m[2], color="grey", ls=":", label="target")
    axes[1].plot(t[keep], np.degrees(truth.euler_rad[keep, 0]), label="roll (deg)")
    axes[1].plot(t[keep], np.degrees(truth.euler_rad[keep, 1]), label="pitch (deg)")
    axes[2].plot(t[keep], truth.rates_frd_rad_s[keep, 2], label="yaw rate (rad/s)")
    for f in scenario.faults:
        for ax in axes:
            ax.axvline(f.at_s, color="red", ls="--", lw=0.8)
    axes[0].set_title(f"{who}, {scenario.name}: faults at the dashed lines", fontsize=10)
    axes[-1].set_xlabel("scenario time (s); before 0: takeoff and the start hold")
    for ax in axes:
        ax.legend(loc="upper left", fontsize=8)
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def summary_line(metrics: dict) -> str:
    h = metrics["hover"]
    text = (f"{metrics['scenario']} through ArduCopter: hover altitude error max {h['altitude_error_max_m']:.2f} m, "
            f"tilt max {h['tilt_max_deg']:.1f} deg")
    if (a := metrics.get("after_fault")) is not None:
        floor = a["hit_the_floor_after_s"]
        text += (f"; after the fault tilt max {a['tilt_max_deg']:.0f} deg, yaw rate max {a['yaw_rate_max_rad_s']:.1f} "
                 f"rad/s, " + ("held the air" if floor is None else f"hit the floor {floor:.2f} s after it"))
    return text
