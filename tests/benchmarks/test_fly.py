"""python -m benchmarks.fly: the loop's figures from a real flight, in lockstep and paced by the wall clock."""

from __future__ import annotations

import re

import pytest

from benchmarks.fly import bench_line

pytestmark = pytest.mark.flight

HOVER = """
name = "short-hover"
duration_s = 1.0
[start]
ned_m = [0.0, 0.0, -2.0]
"""


@pytest.mark.parametrize("realtime", [False, True])
def test_the_loop_is_measured_in_lockstep_and_as_the_robot_flies(tmp_path, realtime):
    scenario = tmp_path / "short-hover.toml"
    scenario.write_text(HOVER)
    line = bench_line(str(scenario), 50.0, tmp_path / "flight", realtime=realtime)
    assert ("paced by the wall clock" in line) == realtime and ("lockstep" in line) != realtime
    assert ("budget for 10x" in line) != realtime               # paced by the wall clock there is no budget to meet
    sitl_ms, companion_ms = (float(v) for v in re.search(r"SITL ([0-9.]+) ms.*companion ([0-9.]+) ms", line).groups())
    median_ms, p99_ms = (float(v) for v in re.search(r"median ([0-9.]+) ms, p99 ([0-9.]+) ms\)", line).groups())
    assert sitl_ms > 0.0 and companion_ms > 0.0 and 0.0 < median_ms <= p99_ms
