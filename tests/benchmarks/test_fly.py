"""python -m benchmarks.fly: the loop's figures from a real flight, in lockstep and paced by the wall clock."""

from __future__ import annotations

import os
import re

import pytest

from benchmarks.fly import bench_line, main

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
    assert "on CPU" not in line
    assert ("budget for 10x" in line) != realtime               # paced by the wall clock there is no budget to meet
    sitl_ms, companion_ms = (float(v) for v in re.search(r"SITL ([0-9.]+) ms.*companion ([0-9.]+) ms", line).groups())
    median_ms, p99_ms = (float(v) for v in re.search(r"median ([0-9.]+) ms, p99 ([0-9.]+) ms\)", line).groups())
    assert sitl_ms > 0.0 and companion_ms > 0.0 and 0.0 < median_ms <= p99_ms


def test_each_process_may_be_pinned_to_its_cpus_and_the_line_says_where(tmp_path):
    scenario = tmp_path / "short-hover.toml"
    scenario.write_text(HOVER)
    first, last = min(os.sched_getaffinity(0)), max(os.sched_getaffinity(0))
    line = bench_line(str(scenario), 50.0, tmp_path / "flight", realtime=True, companion_cpus=frozenset({last}),
                      sitl_cpus=frozenset({first}))
    assert f"companion on CPU {last}, SITL on CPU {first})" in line and "survived: True" in line


def test_behind_a_link_delay_the_companion_answers_for_the_instant_its_setpoint_acts(tmp_path):
    scenario = tmp_path / "short-hover.toml"
    scenario.write_text(HOVER)
    line = bench_line(str(scenario), 50.0, tmp_path / "flight", link_delay_ms=50.0)
    assert "link delay 50 ms each way): " in line and "survived: True" in line
    lead_ms = float(re.search(r"setpoint lead ([0-9.]+) ms", (tmp_path / "flight" / "companion.log").read_text())[1])
    assert lead_ms >= 100.0                                       # both ways: what the prediction spans


@pytest.mark.parametrize("option, text, said", [
    ("--companion-cpus", "1,x", "--companion-cpus 1,x: not a comma-separated list of CPU numbers"),
    ("--sitl-cpus", "BEYOND", "--sitl-cpus BEYOND: CPU BEYOND is not one this machine lets it use"),
])
def test_cpus_this_machine_does_not_have_are_refused_by_name_before_any_flight(capsys, option, text, said):
    beyond = str(max(os.sched_getaffinity(0)) + 1)
    with pytest.raises(SystemExit) as exit_:
        main([option, text.replace("BEYOND", beyond)])
    assert exit_.value.code == 2
    assert said.replace("BEYOND", beyond) in capsys.readouterr().err


def test_a_link_delay_beyond_the_emulations_is_refused_before_any_flight(capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["--link-delay-ms", "2500"])
    assert exit_.value.code == 2
    assert "argument --link-delay-ms: must be within 0..2000 ms, got 2500" in capsys.readouterr().err
