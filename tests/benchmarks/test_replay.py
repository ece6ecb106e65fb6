"""benchmarks.replay: the SITL's vehicle on a recorded flight's setpoints, its truth against the flight's."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from benchmarks.builtins import main as builtins
from benchmarks.replay import main

SCENARIO = "propeller-loss"


@pytest.fixture(scope="module")
def flight(tmp_path_factory):
    out = tmp_path_factory.mktemp("replay")
    assert builtins(["fly", str(out), "--scenario", SCENARIO]) == 0
    return out / SCENARIO


def test_a_flight_replayed_gives_its_truth_bit_for_bit(flight, capsys):
    assert main([str(flight), "--repeat", "1"]) == 0
    out = capsys.readouterr().out
    assert "ms of CPU per control step (201 steps, least of 1)" in out
    assert out.rstrip().endswith("truth against the flight's: identical")


def test_a_truth_that_differs_is_named_with_by_how_much(flight, tmp_path, capsys):
    moved = tmp_path / SCENARIO
    shutil.copytree(flight, moved)
    with np.load(moved / "truth.npz") as truth:
        arrays = dict(truth)
    arrays["pos_ned_m"] = arrays["pos_ned_m"] + 1e-9
    np.savez(moved / "truth.npz", **arrays)
    assert main([str(moved), "--repeat", "1"]) == 0
    assert capsys.readouterr().out.rstrip().endswith("DIFFERENT: pos_ned_m (by up to 1.0e-09)")


@pytest.mark.parametrize("argv, said", [(["no-such-folder"], "is not a flight folder of m4-sitl fly: no flight.tlog"),
                                         (["{flight}", "--repeat", "0"], "--repeat must be at least 1")])
def test_bad_arguments_are_one_line(argv, said, flight, capsys):
    with pytest.raises(SystemExit) as e:
        main([a.format(flight=flight) for a in argv])
    assert e.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert said in err[-1] and len(err) == 2           # argparse: the usage line, then the error


def test_a_tlog_cut_short_is_replayed_up_to_its_last_whole_packet(flight, tmp_path, capsys):
    cut = tmp_path / SCENARIO
    shutil.copytree(flight, cut)
    tlog = (cut / "flight.tlog").read_bytes()
    (cut / "flight.tlog").write_bytes(tlog[:len(tlog) // 2 + 7])     # a killed flight's log: mid-packet
    assert main([str(cut), "--repeat", "1"]) == 0
    assert "ms of CPU per control step" in capsys.readouterr().out


def test_a_broken_scenario_is_one_line(flight, tmp_path, capsys):
    broken = tmp_path / SCENARIO
    shutil.copytree(flight, broken)
    (broken / "scenario.toml").write_text("duration_s = 'long'\n")
    with pytest.raises(SystemExit) as e:
        main([str(broken), "--repeat", "1"])
    assert e.value.code == 2 and "scenario.toml" in capsys.readouterr().err.strip().splitlines()[-1]
