"""`m4-companion bench`: the interface of docs/interfaces.md, on a short sequence."""

import json

import numpy as np
import pytest

from companion.cli import main

KEYS = {"horizon", "dt_s", "solves", "solve_ms_median", "solve_ms_p99", "solve_ms_max", "ipopt_ms_median",
        "speedup_vs_ipopt", "cost_gap_rel_median"}


def test_bench_json_is_one_line_with_the_documented_keys(capsys):
    assert main(["bench", "--json", "--solves", "12", "--horizon", "5", "--dt", "0.1"]) == 0
    out = capsys.readouterr().out.strip()
    assert "\n" not in out
    report = json.loads(out)
    assert KEYS <= report.keys()
    assert report["horizon"] == 5 and report["dt_s"] == 0.1 and report["solves"] == 12
    assert 0 < report["solve_ms_median"] <= report["solve_ms_p99"] <= report["solve_ms_max"]
    assert report["fallbacks"] == 0
    assert abs(report["cost_gap_rel_median"]) <= 1e-3
    assert 0 < report["control_step_ms_median"] <= report["control_step_ms_p99"]
    assert report["max_rate_hz"] == pytest.approx(500.0 / report["control_step_ms_p99"])


@pytest.mark.parametrize("args", [["bench", "--horizon", "0"], ["bench", "--dt", "-1"], ["bench", "--solves", "x"],
                                  ["nonsense"]])
def test_bad_arguments_exit_with_a_usage_error(args, capsys):
    with pytest.raises(SystemExit) as e:
        main(args)
    assert e.value.code == 2
    assert "usage: m4-companion" in capsys.readouterr().err


def test_bench_table_names_both_routes_and_the_control_period(capsys):
    assert main(["bench", "--solves", "6", "--period", "0.05"]) == 0
    out = capsys.readouterr().out
    assert "re-solved every 0.05 s" in out
    assert "GN-SQP + DAQP" in out and "IPOPT" in out and "relative cost gap" in out
    assert "headroom in control periods" in out and "50 Hz (20.0 ms)" in out and "this computer holds up to" in out


def test_headroom_is_the_period_left_beyond_the_p99_step_and_a_rate_is_held_within_half_its_period():
    from companion.headroom import headroom_lines

    lines = headroom_lines(np.full(100, 4.0))             # every step 4 ms
    assert lines[0].endswith("median 4.00 ms, p99 4.00 ms, max 4.00 ms")
    assert "   50 Hz (20.0 ms): p99 step 0.20 period, headroom 0.80 period  held" in lines
    assert "  100 Hz (10.0 ms): p99 step 0.40 period, headroom 0.60 period  held" in lines
    assert "  200 Hz ( 5.0 ms): p99 step 0.80 period, headroom 0.20 period  NOT held" in lines
    assert lines[-1] == "this computer holds up to 125 Hz"


def test_the_whole_control_step_is_timed_along_the_states_it_is_given():
    from companion.config import CompanionConfig
    from companion.core import rom
    from companion.headroom import control_step_ms

    config = CompanionConfig()
    hover = rom.hover_state(config.airframe)
    took_ms = control_step_ms(config, np.tile(hover, (6, 1)), np.full((6, 4), config.airframe.thrust_max_n))
    assert took_ms.shape == (5,) and np.all(took_ms > 0)
