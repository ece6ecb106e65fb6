"""benchmarks.hog's figures from a flight's metrics and feed (no flight here: the bench flies)."""

from __future__ import annotations

from benchmarks.hog import HEADER, flight_row, main


def _nmpc(t_s, rate_hz, overruns, lead_ms):
    return {"t_s": t_s, "rate_hz": rate_hz, "overruns": overruns, "lead_ms": lead_ms}


def test_a_row_counts_losses_in_flight_only_and_the_worst_whole_second():
    metrics = {"duration_s": 2.0, "survived": False, "altitude_loss_m": 1.234, "max_tilt_deg_after_fault": 73.4,
               "nmpc": {"solve_ms_median": 1.25, "solve_ms_p99": 97.5}}
    feed = {"nmpc": [_nmpc(0.5, 2.0, 0, 10.0), _nmpc(1.0, 30.0, 3, 20.0), _nmpc(1.5, 25.0, 5, 300.0),
                     _nmpc(1.9, 40.0, 7, 30.0)],
            "link": [{"t_s": 0.5, "connected": True}, {"t_s": 1.0, "connected": False},
                     {"t_s": 1.2, "connected": True}, {"t_s": 2.0, "connected": False}]}   # the SITL's end
    cells = [c.strip() for c in flight_row(8, 100.0, "normal priority", metrics, feed).strip("|").split("|")]
    assert cells == ["8", "100 Hz", "normal priority", "**no**", "1.23 m", "73.4 deg", "2 Hz (25)", "7", "1",
                     "1.2 / 97.5 ms", "25 / 300 ms"]
    assert len(cells) == HEADER.splitlines()[0].count("|") - 1


def test_bad_arguments_are_one_line_and_exit_2(capsys):
    for argv in (["--priority", "95"], ["--hogs", "-1"], ["--rate-hz", "500"], ["--scenario", "no-such-scenario"]):
        assert main(argv) == 2
        captured = capsys.readouterr()
        assert len(captured.err.strip().splitlines()) == 1 and "error" in captured.err
