"""benchmarks.link: its table row and its bad arguments (the flights themselves are the
emulation's and the flights' tests)."""

from __future__ import annotations

from benchmarks import link as link_bench


def test_a_row_names_the_link_the_verdict_and_the_detection(tmp_path):
    metrics = {"survived": False, "altitude_loss_m": 0.723, "max_tilt_deg_after_fault": 50.2,
               "faults": [{"at_s": 1.0, "rotor": 4, "detected_at_s": 1.04, "detected_rotor": 4}],
               "link": {"delay_ms": 50.0, "loss": 0.2, "mode": "lockstep", "setpoint_lead_ms": 100.0}}
    assert link_bench.row("hover-rotor-loss", 50.0, 0.2, metrics, tmp_path) == (
        "| hover-rotor-loss | 50 ms | 0.2 | **no** | 0.72 m | 50 deg | rotor 4 after 40 ms | 100 ms |")


def test_bad_arguments_give_one_line_and_exit_2(capsys):
    assert link_bench.main(["--delay-ms", "-5"]) == 2
    assert link_bench.main(["--scenario", "no-such-scenario", "--delay-ms", "0"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and "link delay" in err[0] and "no-such-scenario" in err[1]
