"""`m4-companion bench`: the interface of docs/interfaces.md, on a short sequence."""

import json

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
