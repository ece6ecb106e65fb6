"""The control loop's real-time class ([control] realtime_priority): applied by `m4-companion run`
where permitted; said in one line, and flown on at normal priority, where not."""

from __future__ import annotations

import logging
import os
import resource
import signal
import subprocess
import sys

import pytest

from companion import realtime
from companion.realtime import use_realtime
from m4.mavlink.signing import write_new_key

PRIORITY = 10


def _may_use_fifo(priority: int) -> bool:
    if not hasattr(os, "sched_setscheduler"):
        return False
    soft = resource.getrlimit(resource.RLIMIT_RTPRIO)[0]
    if soft == resource.RLIM_INFINITY or soft >= priority:
        return True
    try:                                    # CAP_SYS_NICE: try it on a throwaway process
        probe = subprocess.run(["chrt", "-f", str(priority), "true"], capture_output=True, timeout=10)
    except FileNotFoundError:
        return False
    return probe.returncode == 0


def _start_companion(tmp_path, prelude: str = "", control: str = f"realtime_priority = {PRIORITY}") -> subprocess.Popen:
    config = tmp_path / "companion.toml"
    write_new_key(tmp_path / "mavlink.key")
    config.write_text(f"[control]\n{control}\n[link]\nsigning_key_file = \"mavlink.key\"\n"
                      "[log]\nenabled = false\n")
    main = "from companion.cli import main; raise SystemExit(main(sys.argv[1:]))"
    return subprocess.Popen([sys.executable, "-c", f"import sys\n{prelude}\n{main}", "run", "--fc",
                             "udpin:127.0.0.1:0", "--config", str(config)], stderr=subprocess.PIPE, text=True)


def _until_ready(proc: subprocess.Popen) -> list[str]:
    lines = []
    while not lines or "ready" not in lines[-1]:
        line = proc.stderr.readline()
        assert line, f"the companion stopped before it was ready: {lines}"
        lines.append(line.strip())
    return lines


def _stop(proc: subprocess.Popen) -> tuple[int, str]:
    proc.send_signal(signal.SIGTERM)
    try:
        return proc.wait(timeout=10), proc.stderr.read()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


@pytest.mark.skipif(not _may_use_fifo(PRIORITY), reason="this process may not use SCHED_FIFO")
def test_run_puts_its_control_loop_in_sched_fifo_at_the_configured_priority(tmp_path):
    proc = _start_companion(tmp_path)
    try:
        lines = _until_ready(proc)
        policy = os.sched_getscheduler(proc.pid)            # the main thread: the run loop
        priority = os.sched_getparam(proc.pid).sched_priority
    finally:
        code, rest = _stop(proc)
    assert policy & ~os.SCHED_RESET_ON_FORK == os.SCHED_FIFO and priority == PRIORITY
    assert policy & os.SCHED_RESET_ON_FORK                   # a compiler it starts is not real-time
    assert any(f"real-time priority {PRIORITY} (SCHED_FIFO)" in ln for ln in lines), lines
    assert code == 0 and "Traceback" not in rest


def test_run_says_so_in_one_line_and_flies_on_when_not_permitted(tmp_path):
    refuse = ("import os\ndef refuse(*_):\n    raise PermissionError(1, 'Operation not permitted')\n"
              "os.sched_setscheduler = refuse")
    proc = _start_companion(tmp_path, refuse)
    try:
        lines = _until_ready(proc)
        policy = os.sched_getscheduler(proc.pid)
    finally:
        code, rest = _stop(proc)
    said = [ln for ln in lines if "real-time" in ln]
    assert len(said) == 1 and "not granted" in said[0] and "normal priority" in said[0], lines
    assert "RLIMIT_RTPRIO" in said[0]                        # and what would grant it
    assert policy == os.SCHED_OTHER
    assert code == 0 and "stopped by SIGTERM after" in rest and "Traceback" not in rest


def test_a_platform_without_sched_fifo_is_said_in_one_line(monkeypatch, caplog):
    monkeypatch.delattr(realtime.os, "sched_setscheduler", raising=False)
    with caplog.at_level(logging.INFO, logger="m4-companion"):
        assert use_realtime(PRIORITY) is False
    assert [r.getMessage() for r in caplog.records] == [
        f"real-time priority {PRIORITY} asked for, but this platform has no SCHED_FIFO: flying at normal priority"]


def test_priority_zero_leaves_the_scheduling_alone(monkeypatch, caplog):
    def must_not_be_called(*_):
        raise AssertionError("sched_setscheduler called for priority 0")

    monkeypatch.setattr(realtime.os, "sched_setscheduler", must_not_be_called, raising=False)
    with caplog.at_level(logging.INFO, logger="m4-companion"):
        assert use_realtime(0) is False
    assert caplog.records == []


def test_run_keeps_the_whole_companion_on_the_configured_cpu_and_says_so(tmp_path):
    """The run loop and the threads beside it (here the signing timestamps' saver): the loop's
    thread alone on the CPU did not shorten the p99 (docs/performance.md)."""
    cpu = max(os.sched_getaffinity(0))
    proc = _start_companion(tmp_path, control=f"cpu = {cpu}")
    try:
        lines = _until_ready(proc)
        on = [os.sched_getaffinity(int(tid)) for tid in os.listdir(f"/proc/{proc.pid}/task")]
    finally:
        code, rest = _stop(proc)
    assert len(on) >= 2 and all(cpus == {cpu} for cpus in on), on
    assert any(f"the companion on CPU {cpu}" in ln for ln in lines), lines
    assert code == 0 and "Traceback" not in rest


def test_a_cpu_this_process_may_not_run_on_is_refused_in_one_line_before_the_build(tmp_path):
    beyond = max(os.sched_getaffinity(0)) + 1
    proc = _start_companion(tmp_path, control=f"cpu = {beyond}")
    code, said = proc.wait(timeout=60), proc.stderr.read()
    assert code == 2
    assert said.strip().splitlines()[-1].startswith(f"m4-companion: error: [control] cpu {beyond}: not a CPU this "
                                                   "process may run on")
    assert "Traceback" not in said
