"""End to end: `m4-sitl serve` (a subprocess, lockstep, hover-rotor-loss) and the companion app
(in this process) over MAVLink 2 on 127.0.0.1. Rotor 4 stops at t = 1 s; the companion must
detect it, say so with STATUSTEXT CRITICAL "thrust loss rotor 4 (motor)" and keep the robot in the
air. The figures are taken from the tlog the SITL writes (both directions); `pytest -s`
prints them.
"""

from __future__ import annotations

import dataclasses
import math
import re
import subprocess
import sys
import threading
from types import SimpleNamespace

import numpy as np
import pytest

from m4.airframe import load_airframe
from companion.app import close_app, open_app
from companion.config import parse_config
from companion.feed_publisher import Feed
from m4.mavlink import COMPANION_COMPONENT_ID, FC_COMPONENT_ID, mavlink
from sitl import scenarios
from support.loopback import tlog_messages

pytestmark = pytest.mark.flight

SCENARIO = "hover-rotor-loss"
SECONDS = 4.0
RATE_HZ = 50.0


def _serve(app, *serve_args):
    """The SITL's `serve` with serve_args flown against app (run in a thread); app closed after."""
    thread = threading.Thread(target=app.run, daemon=True)
    thread.start()
    cmd = [sys.executable, "-m", "sitl.cli", "serve", *serve_args,
           "--mavlink", f"udpout:127.0.0.1:{app.fc.link.local_port}"]
    try:
        return subprocess.run(cmd, capture_output=True, text=True, timeout=120, check=False)
    finally:
        app.stop()
        thread.join(5.0)
        close_app(app)


def _fly(tmp_path):
    config = parse_config({"control": {"rate_hz": RATE_HZ}, "link": {"fc_url": "udpin:127.0.0.1:0",
                                                                      "signing": False},
                           "log": {"dir": str(tmp_path / "logs")}}, "test")
    config = dataclasses.replace(config, mission=scenarios.resolve(SCENARIO).mission)
    app = open_app(config)
    published = []
    app.feed = Feed(SimpleNamespace(put=lambda topic, payload: published.append((topic, payload)), close=list))
    tlog = tmp_path / "flight.tlog"
    done = _serve(app, "--scenario", SCENARIO, "--duration", str(SECONDS), "--tlog", str(tlog))
    assert done.returncode == 0, done.stderr
    return app, tlog, done.stderr, published


@pytest.fixture(scope="module")
def flight(tmp_path_factory):
    return _fly(tmp_path_factory.mktemp("flight"))


def test_rotor_loss_in_hover_is_announced_and_the_robot_stays_in_the_air(flight):
    app, tlog, sitl_log, _ = flight
    msgs = tlog_messages(tlog)
    fc = [m for m in msgs if m.get_srcComponent() == FC_COMPONENT_ID]
    ours = [m for m in msgs if m.get_srcComponent() == COMPANION_COMPONENT_ID]
    fault_ms = 1000

    alt = {m.time_boot_ms: -m.z for m in fc if m.get_type() == "LOCAL_POSITION_NED"}
    tilt = {m.time_boot_ms: math.degrees(max(abs(m.roll), abs(m.pitch))) for m in fc if m.get_type() == "ATTITUDE"}
    loss_m = alt[0] - min(a for t, a in alt.items() if t >= fault_ms)
    max_tilt = max(a for t, a in tilt.items() if t >= fault_ms)
    end_ms = max(alt)

    critical = [m for m in ours if m.get_type() == "STATUSTEXT" and m.severity <= mavlink.MAV_SEVERITY_CRITICAL]
    status = [m for m in ours if m.get_type() == "M4_FAULT_STATUS" and m.state == mavlink.M4_FAULT_STATE_CONFIRMED]
    setpoints = [m for m in ours if m.get_type() == "M4_SETPOINT"]
    speed = re.search(r"\(([\d.]+)x\)", sitl_log)
    detected_ms = status[0].detected_time_boot_ms if status else None
    print(f"\n{SCENARIO} at {RATE_HZ:g} Hz: altitude loss {loss_m:.2f} m, max tilt after the fault {max_tilt:.1f} deg, "
          f"detected after {None if detected_ms is None else detected_ms - fault_ms} ms, altitude at "
          f"{end_ms / 1000:g} s {alt[end_ms]:.2f} m, {len(setpoints)} setpoints, slowest solve "
          f"{app.counters.solve_ms_max:.1f} ms, lockstep {speed.group(1) if speed else '?'} simulated s per wall s")

    assert [m.text for m in critical] == ["thrust loss rotor 4 (motor)"]    # its ESC shows the speed collapse
    assert status and {m.rotor for m in status} == {4}
    assert fault_ms < detected_ms <= fault_ms + 300
    assert status[-1].thrust_max_estimate_n[3] < 0.1 * load_airframe().hover_thrust_per_rotor_n
    assert len(setpoints) >= SECONDS * RATE_HZ
    values = np.array([[*m.thrust_n, *m.hip_angle_rad, *m.hip_rate_rad_s] for m in setpoints])
    assert np.all(np.isfinite(values))
    assert loss_m < 0.6                    # from 2 m: it never comes near the ground
    assert max_tilt < 60.0
    assert abs(alt[end_ms] - 2.0) < 0.2    # back at its altitude
    assert app.counters.link_losses <= 1   # the one at the end, when the SITL stops


def test_the_feed_says_what_the_statustext_says_and_carries_every_topic(flight):
    _, _, _, payloads = flight
    assert {topic for topic, _ in payloads} == {"state", "setpoint", "fault", "nmpc", "link"}
    confirmed = [p for topic, p in payloads if topic == "fault" and p["state"] == "confirmed"]
    assert confirmed and confirmed[0]["rotor"] == 4 and confirmed[0]["message"] == "thrust loss rotor 4 (motor)"
    assert 1.0 < confirmed[0]["detected_at_s"] <= 1.3
    nmpc = [p for topic, p in payloads if topic == "nmpc"]
    assert len(nmpc) >= 0.9 * SECONDS * RATE_HZ       # every control step (no rate cap on this feed)
    assert all(len(p["disturbance_force_ned_n"]) == 3 for p in nmpc)
    assert max(abs(v) for p in nmpc for v in p["disturbance_force_ned_n"]) > 0.1   # the lost rotor's push, at least


def test_the_companion_logs_what_the_link_carried_and_what_it_decided(flight):
    app, tlog, _, _ = flight
    [companion_log] = app.flight_log.files
    ours, sitl = tlog_messages(companion_log), tlog_messages(tlog)

    def count(msgs, kind):
        return sum(m.get_type() == kind for m in msgs)
    for kind in ("M4_SETPOINT", "M4_FAULT_STATUS", "M4_THRUSTER_STATUS", "STATUSTEXT"):
        assert abs(count(ours, kind) - count(sitl, kind)) <= 5 and count(ours, kind), kind   # the ends differ
    solve = [m for m in ours if m.get_type() == "NAMED_VALUE_FLOAT" and m.name == "nmpc_ms"]
    latency = [m.value for m in ours if m.get_type() == "NAMED_VALUE_FLOAT" and m.name == "step_ms"]
    assert len(solve) >= 0.9 * count(ours, "M4_SETPOINT") and all(m.value > 0 for m in solve)
    assert len(latency) == count(ours, "M4_SETPOINT") and 0 < np.median(latency) < 100


@pytest.mark.parametrize("same_key", [True, False], ids=["same key", "another key"])
def test_with_signing_only_the_holder_of_the_key_flies_the_robot(tmp_path, same_key):
    fc_key, our_key = tmp_path / "fc.key", tmp_path / "companion.key"
    fc_key.write_text("11" * 32)
    our_key.write_text("11" * 32 if same_key else "22" * 32)
    config = parse_config({"control": {"rate_hz": RATE_HZ},
                           "link": {"fc_url": "udpin:127.0.0.1:0", "signing_key_file": str(our_key)}}, "test")
    app = open_app(config)
    done = _serve(app, "--duration", "1", "--lockstep-timeout", "1", "--signing-key", str(fc_key))
    accepted = int(re.search(r"setpoints accepted (\d+)", done.stderr).group(1))
    rejected = int(re.search(r"packets rejected (\d+)", done.stderr).group(1))
    health = app.fc.health()
    if same_key:
        assert accepted >= RATE_HZ and rejected == 0 and health.bad_signature == 0
    else:
        # every FC packet, its heartbeat too, fails our signature check: we never lock on, never answer
        assert accepted == 0 and app.counters.answered == 0 and not health.locked
        assert health.bad_signature > 0
