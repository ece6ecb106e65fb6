"""The companion as a process beside ArduCopter SITL (`m4-sitl fly-ardupilot --companion`).

It listens on tcp 127.0.0.1:PORT and arducopter connects its SERIAL1 to it (`--serial1
tcpclient:...`), so the companion starts first and has built its NMPC before SITL boots. Its
configuration (companion.toml in the flight's folder) is the one for ArduPilot with the M4
applet: signing off (the applet cannot check signatures: docs/ardupilot.md), the shortfall
cover asked for or not (the applet runs it on its gyro's measure, and the rate feedback).
"""

from __future__ import annotations

import contextlib
import os
import subprocess
from pathlib import Path

from sitl.flights.flight_run import COMPANION, COMPANION_LOG_DIR, _await_ready, _start, start_process


def companion_config_text(port: int, priority: int = 0, shortfall_cover: bool = True) -> str:
    return "\n".join([
        "# The companion's configuration for a flight through ArduCopter (written by m4-sitl fly-ardupilot).",
        "[control]",
        "# the M4 applet runs the rate feedback, and the shortfall cover on its gyro's measure",
        f"shortfall_cover = {str(shortfall_cover).lower()}", *[f"realtime_priority = {priority}"] * bool(priority),
        "",
        "[link]", f'fc_url = "tcpin:127.0.0.1:{port}"',
        "# the applet receives M4_SETPOINT through ArduPilot's bad-CRC path, where no signature is checked",
        "signing = false", "",
        "[log]", f'dir = "{COMPANION_LOG_DIR}"', ""])


def start_companion(stack: contextlib.ExitStack, out_dir: Path, port: int, scenario_path: Path,
                    has_mission: bool, priority: int = 0, shortfall_cover: bool = True) -> subprocess.Popen:
    """The companion started and ready (NMPC built, listening); stopped when `stack` closes. Its
    control loop in SCHED_FIFO at `priority` (0: normal); the applet's shortfall cover asked for or not."""
    config = out_dir / "companion.toml"
    config.write_text(companion_config_text(port, priority, shortfall_cover))
    args = ["run", "--config", str(config)]
    if has_mission:
        args += ["--mission", str(scenario_path)]
    ready_r, ready_w = os.pipe()
    stack.callback(os.close, ready_r)
    try:
        companion = _start(stack, start_process(COMPANION, args, out_dir / "companion.log", ("--ready-fd", ready_w)))
    finally:
        os.close(ready_w)
    _await_ready(companion, ready_r, out_dir / "companion.log")
    return companion
