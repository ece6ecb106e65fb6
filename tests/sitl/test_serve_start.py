"""What `m4-sitl serve` loads before it flies: a campaign starts it once a flight, so every
module it imports and never uses is paid again and again."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
UNUSED_IN_FLIGHT = {"scipy", "glfw", "pymavlink.mavutil", "zenoh", "sitl.flights.flight_run", "sitl.campaigns.parallel"}
# `m4-sitl serve` as its command line runs it: the plant built and the link open, then told
# by its start descriptor's end of file not to fly.
_PROBE = """
import json, os, sys
from sitl.cli import main
ready, told = os.pipe()
os.close(told)
main(["serve", "--duration", "1", "--mavlink", "udpout:127.0.0.1:9", "--start-fd", str(ready)])
print(json.dumps(sorted(sys.modules)))
"""

def test_serve_loads_no_module_it_does_not_fly_with():
    env = {k: v for k, v in os.environ.items() if k != "MUJOCO_GL"} | {"PYTHONPATH": str(ROOT)}
    out = subprocess.run([sys.executable, "-c", _PROBE], cwd=ROOT, env=env, capture_output=True, text=True,
                         timeout=120, check=True).stdout
    assert UNUSED_IN_FLIGHT.isdisjoint(json.loads(out.splitlines()[-1]))
