"""benchmarks.reliability's bad arguments (the probes themselves fly in tests/flights/test_reliability_flights.py)."""

from __future__ import annotations

import pytest

from benchmarks.reliability import main


@pytest.mark.parametrize("argv", [["stale", "--scenario", "no-such-scenario"], ["stale", "--at-s", "9"],
                                  ["restart", "--kill-at-s", "6", "--kill-at-s", "3"]])
def test_bad_arguments_are_one_line_and_exit_2(argv, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("python -m benchmarks.reliability: error:")


def test_a_number_that_is_not_one_is_refused_by_the_parser(capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["restart", "--seconds", "0"])
    assert exit_.value.code == 2 and "--seconds: must be a finite number > 0" in capsys.readouterr().err
