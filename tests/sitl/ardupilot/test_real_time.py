"""The real-time priority of a flight through ArduCopter (`--priority P`): every thread of a
process in SCHED_FIFO and back, the companion's configuration, and bad priorities."""

from __future__ import annotations

import os
import subprocess
import sys
import tomllib

import pytest

from sitl import scenarios
from sitl.ardupilot.companion_process import companion_config_text
from sitl.ardupilot.flight import (
    ArduFlightOptions,
    FlightError,
    fly_ardupilot,
    real_time,
)

THREADS = "import threading, time; [threading.Thread(target=time.sleep, args=(30,)).start() for _ in range(3)]; " \
          "print('up', flush=True); time.sleep(30)"


def policies(pid: int) -> set[int]:
    return {os.sched_getscheduler(int(tid)) for tid in os.listdir(f"/proc/{pid}/task")}


@pytest.mark.skipif(os.geteuid() != 0, reason="SCHED_FIFO needs root or CAP_SYS_NICE")
def test_every_thread_of_a_running_process_goes_to_sched_fifo_and_back():
    proc = subprocess.Popen([sys.executable, "-c", THREADS], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "up"
        assert len(os.listdir(f"/proc/{proc.pid}/task")) == 4
        real_time(proc.pid, 7)
        assert policies(proc.pid) == {os.SCHED_FIFO}
        assert {os.sched_getparam(int(t)).sched_priority for t in os.listdir(f"/proc/{proc.pid}/task")} == {7}
        real_time(proc.pid, 0)
        assert policies(proc.pid) == {os.SCHED_OTHER}
    finally:
        proc.kill()
        proc.wait()


def test_the_companions_control_loop_gets_the_priority():
    assert tomllib.loads(companion_config_text(5760, 50))["control"]["realtime_priority"] == 50
    assert "realtime_priority" not in tomllib.loads(companion_config_text(5760))["control"]


@pytest.mark.parametrize("priority, companion, said", [
    (100, True, "priority 100: a SCHED_FIFO priority is 1..99 (0: normal)"),
    (-1, True, "priority -1: a SCHED_FIFO priority is 1..99 (0: normal)"),
    (50, False, "a real-time priority is for a flight with the companion (it starts at the handover)"),
])
def test_a_bad_priority_is_named_before_anything_starts(tmp_path, priority, companion, said):
    options = ArduFlightOptions(scenario=scenarios.resolve("hover-rotor-loss"), out_dir=tmp_path / "out",
                                companion=companion, priority=priority)
    with pytest.raises(FlightError) as raised:
        fly_ardupilot(options, log=lambda _: None)
    assert str(raised.value) == said
    assert not (tmp_path / "out").exists()
