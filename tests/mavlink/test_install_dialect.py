"""`python -m m4.mavlink.install_dialect`: pymavlink's own mavlogdump decodes our messages by name."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys

from m4.mavlink import FC_SYSTEM_ID, COMPANION_COMPONENT_ID, mavlink, new_mav
from m4.mavlink.install_dialect import PYMAVLINK_DIR, install, main
from m4.mavlink.tlog import TlogWriter


class _Packets:
    def __init__(self):
        self.packets = []

    def write(self, packet):
        self.packets.append(bytes(packet))


def _tlog(path):
    out = _Packets()
    mav = new_mav(out, FC_SYSTEM_ID, COMPANION_COMPONENT_ID)
    mav.send(mavlink.MAVLink_m4_setpoint_message(1, 1, 1240, 20, [14.7] * 4, [0.78] * 4, [0.0] * 4, 0))
    mav.send(mavlink.MAVLink_m4_fault_status_message(1240, 4, [30.0, 30.0, 30.0, 0.4], 1040, 2))
    with TlogWriter(path) as tlog:
        for packet in out.packets:
            tlog.record(packet)


def _pymavlink_copy(tmp_path):
    """The installed pymavlink as a tree of links: installing into it leaves the real one alone."""
    root = tmp_path / "site"
    shutil.copytree(PYMAVLINK_DIR, root / "pymavlink", copy_function=os.symlink)
    return root


def _mavlogdump(site, tlog):
    env = {**os.environ, "PYTHONPATH": str(site)}
    return subprocess.run([sys.executable, "-m", "pymavlink.tools.mavlogdump", "--dialect", "m4", str(tlog)],
                          capture_output=True, text=True, env=env, cwd=site, timeout=120)


def test_mavlogdump_prints_our_messages_by_name_once_the_dialect_is_installed(tmp_path):
    tlog = tmp_path / "flight.tlog"
    _tlog(tlog)
    site = _pymavlink_copy(tmp_path)
    written = install(site / "pymavlink")
    assert {p.name for p in written} == {"m4.py", "m4.xml"}
    dump = _mavlogdump(site, tlog)
    assert dump.returncode == 0, dump.stderr[-2000:]
    lines = dump.stdout.splitlines()
    assert any("M4_SETPOINT {" in ln and "time_boot_ms : 1240" in ln for ln in lines), dump.stdout
    assert any("M4_FAULT_STATUS {" in ln and "rotor : 4" in ln for ln in lines), dump.stdout
    assert "UNKNOWN" not in dump.stdout


def test_a_folder_that_is_not_pymavlink_is_named(tmp_path, capsys):
    assert main(["--pymavlink", str(tmp_path)]) == 1
    assert f"{tmp_path} is not a pymavlink package" in capsys.readouterr().err
