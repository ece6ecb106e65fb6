"""Fault detection end to end (`m4-sitl fly`, SITL and companion over loopback MAVLink, 50 Hz):
a lost propeller read from the ESC telemetry, and a stopped motor on a flight controller that
has none. The robot survives, the right rotor is named within issue 9's targets."""

from __future__ import annotations

import pytest

from sitl.flight_run import FlightFiles
from sitl.fly import fly
from sitl.fly_bench import loop_costs
from sitl.records import read_feed

pytestmark = pytest.mark.flight


def _confirmed_messages(out):
    return [p["message"] for p in read_feed(out / "feed.jsonl").get("fault", []) if p.get("message")]


@pytest.mark.parametrize("scenario, latency_max_s, message", [
    ("propeller-loss", 0.10, "thrust loss rotor 2 (propeller)"),
    ("no-esc-motor-loss", 0.15, "thrust loss rotor 3"),
])
def test_the_rotor_is_found_within_the_target_and_the_robot_survives(tmp_path, scenario, latency_max_s, message):
    m = fly(scenario, tmp_path, progress=False)
    assert m["survived"], m["checks"]
    (fault,) = m["faults"]
    assert fault["detected_rotor"] == fault["rotor"]
    assert 0.0 < fault["detected_at_s"] - fault["at_s"] <= latency_max_s
    assert _confirmed_messages(tmp_path)[-1] == message       # the kind as the evidence settles it
    costs = loop_costs(FlightFiles(tmp_path))                 # what python -m sitl.fly_bench reads
    assert costs is not None and costs.sitl_cpu_s > 0.0 and 0.0 < costs.answer_ms and 0.0 < costs.companion_cpu_ms
