"""benchmarks.lockstep: m4-sitl serve in lockstep against the stand-in companion, with the SITL's own CPU."""

from __future__ import annotations

import re

from benchmarks.lockstep import main


def test_the_sitl_s_cpu_per_step_comes_from_its_stop_line(capsys):
    assert main(["--seconds", "1"]) == 0
    out = capsys.readouterr().out
    assert "(51 setpoints at 50 Hz" in out
    cpu_ms = float(re.search(r"the SITL's CPU per step ([0-9.]+) ms$", out.strip()).group(1))
    assert 0.0 < cpu_ms < 20.0                  # a 20 ms step takes a fraction of its period
