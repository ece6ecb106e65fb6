import os
import shlex
import shutil
import subprocess
from pathlib import Path

import pytest

from companion.config import default_log_dir, load_config
from companion.core.codegen_cache import CACHE_ENV

UNIT = Path(__file__).resolve().parents[2] / "deploy" / "m4-companion.service"


def parse_unit(text: str) -> dict[str, dict[str, list[str]]]:
    """systemd's unit syntax: [Section] headers, Key=value lines (keys may repeat), # or ; comments."""
    sections: dict[str, dict[str, list[str]]] = {}
    current = None
    for number, raw in enumerate(text.splitlines(), 1):
        line = raw.strip()
        if not line or line[0] in "#;":
            continue
        if line.startswith("[") and line.endswith("]"):
            current = sections.setdefault(line[1:-1], {})
        elif "=" in line and current is not None and not line.endswith("\\"):
            key, value = line.split("=", 1)
            current.setdefault(key.strip(), []).append(value.strip())
        else:
            raise AssertionError(f"{UNIT.name}:{number}: not a Key=value line in a section: {raw!r}")
    return sections


@pytest.fixture(scope="module")
def unit():
    return parse_unit(UNIT.read_text())


def one(unit, section: str, key: str) -> str:
    values = unit[section].get(key)
    assert values, f"[{section}] {key}= is missing"
    return values[-1]


def test_unit_has_the_three_sections_and_starts_at_boot(unit):
    assert {"Unit", "Service", "Install"} <= set(unit)
    assert one(unit, "Install", "WantedBy") == "multi-user.target"


def test_service_runs_as_an_unprivileged_user_with_the_serial_group(unit):
    assert one(unit, "Service", "User") not in ("root", "0")
    assert one(unit, "Service", "Group") not in ("root", "0")
    assert "dialout" in one(unit, "Service", "SupplementaryGroups").split()
    assert one(unit, "Service", "NoNewPrivileges") == "yes"
    assert one(unit, "Service", "CapabilityBoundingSet") == ""
    assert "AmbientCapabilities" not in unit["Service"] or one(unit, "Service", "AmbientCapabilities") == ""


def test_service_restarts_on_failure_after_a_pause(unit):
    assert one(unit, "Service", "Restart") == "on-failure"
    assert float(one(unit, "Service", "RestartSec")) > 0


def test_exec_start_runs_the_companion_with_a_config_file(unit):
    argv = shlex.split(one(unit, "Service", "ExecStart"))
    assert Path(argv[0]).is_absolute() and Path(argv[0]).name == "m4-companion"
    assert argv[1] == "run"
    config = argv[argv.index("--config") + 1]
    assert Path(config).is_absolute() and config.endswith(".toml")


def test_system_is_read_only_but_for_the_cache_the_nmpc_code_reads(unit):
    assert one(unit, "Service", "ProtectSystem") == "strict"
    writable = {f"/var/cache/{d}" for d in one(unit, "Service", "CacheDirectory").split()}
    env = dict(e.split("=", 1) for v in unit["Service"]["Environment"] for e in shlex.split(v))
    assert env[CACHE_ENV] in writable                    # compiled NMPC functions can be stored
    assert unit["Service"].get("LogsDirectory") or unit["Service"].get("ReadWritePaths"), "no writable log dir"


def test_flight_logs_go_to_the_folder_systemd_makes_for_them(unit, monkeypatch):
    assert one(unit, "Service", "LogsDirectory") == "m4"
    monkeypatch.delenv("M4_LOG_DIR", raising=False)
    monkeypatch.setenv("LOGS_DIRECTORY", "/var/log/m4")       # what systemd sets for LogsDirectory=m4
    assert default_log_dir() == Path("/var/log/m4")


def test_the_example_config_signs_with_a_root_owned_key_and_keeps_its_timestamps_where_it_may_write(unit):
    link = load_config(UNIT.parent / "companion.toml").link
    key, timestamps = link.signing_files()
    assert key.parent == Path("/etc/m4")                    # read-only to the service (ProtectSystem=strict)
    assert timestamps.parent == Path("/var/lib") / one(unit, "Service", "StateDirectory")


def test_the_control_loop_may_take_the_real_time_priority_its_config_asks_for_and_no_more(unit):
    """The in-process route (companion/realtime.py): an RLIMIT_RTPRIO, no capability, no
    systemd-wide real-time class (the compiler at first start and the feed's threads stay normal)."""
    config = load_config(UNIT.parent / "companion.toml")
    assert 0 < config.realtime_priority == int(one(unit, "Service", "LimitRTPRIO")) < 50   # under the IRQ threads
    assert unit["Service"].get("RestrictRealtime", ["no"])[-1] == "no"       # yes would refuse SCHED_FIFO
    assert "CPUSchedulingPolicy" not in unit["Service"]
    assert -20 <= int(one(unit, "Service", "Nice")) < 0                      # the rest: ahead of ordinary work


def test_systemd_accepts_the_unit(tmp_path):
    """systemd-analyze verify, with ExecStart's program replaced by one that exists here."""
    analyze = shutil.which("systemd-analyze")
    if analyze is None:
        pytest.skip("systemd-analyze is not installed")
    text = UNIT.read_text()
    program = shlex.split(one(parse_unit(text), "Service", "ExecStart"))[0]
    stub = tmp_path / "m4-companion"
    stub.write_text("#!/bin/sh\nexit 0\n")
    stub.chmod(0o755)
    copy = tmp_path / UNIT.name
    copy.write_text(text.replace(program, str(stub)))
    result = subprocess.run([analyze, "verify", str(copy)], capture_output=True, text=True, timeout=60,
                            env={**os.environ, "SYSTEMD_LOG_COLOR": "0"})
    messages = (result.stdout + result.stderr).strip()
    assert result.returncode == 0 and messages == "", messages       # unknown keys only warn
