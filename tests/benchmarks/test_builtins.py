"""benchmarks.builtins: a built-in flown without figures, and flights compared with a reference."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from benchmarks.builtins import main

SCENARIO = "hover-rotor-loss"


@pytest.fixture(scope="module")
def flown(tmp_path_factory):
    out = tmp_path_factory.mktemp("builtins")
    assert main(["fly", str(out / "a"), "--scenario", SCENARIO]) == 0
    return out / "a"


def _row(capsys) -> str:
    return next(line for line in capsys.readouterr().out.splitlines() if line.startswith(f"| {SCENARIO} "))


def test_a_flight_flown_without_figures_is_its_own_reference_bit_for_bit(flown, capsys):
    assert (flown / SCENARIO / "truth.npz").exists() and not list((flown / SCENARIO).glob("*.png"))
    assert main(["table", str(flown), str(flown)]) == 0
    row = _row(capsys)
    assert row.startswith(f"| {SCENARIO} | yes / yes |") and row.endswith("| identical |")
    assert "1.04 / 1.04" in row                   # the rotor lost at 1 s, named at 1.04 s


def test_a_flight_that_moved_is_named_with_what_moved(flown, tmp_path, capsys):
    moved = tmp_path / "moved" / SCENARIO
    shutil.copytree(flown / SCENARIO, moved)
    with np.load(moved / "truth.npz") as truth:
        arrays = dict(truth)
    arrays["pos_ned_m"] = arrays["pos_ned_m"] + 1e-9
    np.savez(moved / "truth.npz", **arrays)
    metrics = json.loads((moved / "metrics.json").read_text())
    metrics["altitude_loss_m"] += 0.001
    metrics["realtime_factor"] *= 2                # the machine's figure: never a difference
    (moved / "metrics.json").write_text(json.dumps(metrics))
    assert main(["table", str(flown), str(moved.parent)]) == 0
    assert _row(capsys).endswith("| differs: pos_ned_m, metrics.altitude_loss_m |")


def test_a_flight_without_its_metrics_is_told_so_in_its_cell(flown, tmp_path, capsys):
    cut = tmp_path / "cut" / SCENARIO
    shutil.copytree(flown / SCENARIO, cut)
    (cut / "metrics.json").unlink()                 # a flight stopped before its metrics were written
    assert main(["table", str(flown), str(cut.parent)]) == 1
    assert _row(capsys).endswith("| differs: metrics.json missing |")


def test_a_scenario_missing_from_a_folder_fails_the_table(flown, tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    assert main(["table", str(flown), str(tmp_path / "empty")]) == 1
    assert _row(capsys).startswith(f"| {SCENARIO} | yes / missing |")


@pytest.mark.parametrize("argv, said", [(["fly", "out", "--scenario", "no-such"], "not a built-in scenario: no-such"),
                                         (["table", "no-such-folder"], "not a folder: no-such-folder")])
def test_bad_arguments_are_one_line(argv, said, capsys):
    with pytest.raises(SystemExit) as e:
        main(argv)
    assert e.value.code == 2 and said in capsys.readouterr().err
