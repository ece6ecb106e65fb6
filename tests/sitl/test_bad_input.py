"""Issue 10's bad input: each gives one clear line and exit code 2, never a traceback, before
anything flies."""

from __future__ import annotations

import logging

import pytest

from companion.cli import main as companion_main
from sitl import scenarios
from sitl.cli import main as sitl_main
from sitl.plant.truth import TruthRecorder


@pytest.fixture(autouse=True)
def _root_logging_restored():
    """`m4-companion run` sets up logging on the stderr of the moment: undo it afterwards."""
    handlers = list(logging.getLogger().handlers)
    yield
    for handler in logging.getLogger().handlers[:]:
        if handler not in handlers:
            logging.getLogger().removeHandler(handler)


def _one_line(capsys, main, args, prog) -> str:
    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"{prog}: error: "), err
    return err[0]


def _not_utf8(tmp_path):
    path = tmp_path / "latin1.toml"
    path.write_bytes('name = "caf\xe9"\nduration_s = 5.0\n'.encode("latin-1"))
    return path


def test_fly_into_a_folder_that_cannot_be_made(capsys):
    line = _one_line(capsys, sitl_main, ["fly", "hover-rotor-loss", "--out", "/proc/x"], "m4-sitl")
    assert line.endswith("--out /proc/x: cannot create the folder (No such file or directory)")


def test_fly_into_an_existing_file(capsys, tmp_path):
    existing = tmp_path / "notes.txt"
    existing.write_text("keep me")
    line = _one_line(capsys, sitl_main, ["fly", "hover-rotor-loss", "--out", str(existing)], "m4-sitl")
    assert line.endswith(f"--out {existing}: exists and is not a folder")
    assert existing.read_text() == "keep me"


@pytest.mark.parametrize("command", [["fly"], ["serve", "--scenario"]])
def test_a_scenario_that_is_not_utf8(capsys, tmp_path, command):
    path = _not_utf8(tmp_path)
    line = _one_line(capsys, sitl_main, [*command, str(path)], "m4-sitl")
    assert line.endswith(f"{path}: not UTF-8 text (byte 0xe9 at offset 11); TOML files must be UTF-8")


def test_a_companion_config_that_is_not_utf8(capsys, tmp_path):
    path = _not_utf8(tmp_path)
    line = _one_line(capsys, companion_main, ["run", "--config", str(path)], "m4-companion")
    assert "not UTF-8 text" in line


def test_a_horizon_the_loop_cannot_use_is_refused_with_the_limit(capsys, tmp_path):
    path = tmp_path / "companion.toml"
    path.write_text("[nmpc]\nhorizon = 100000\n")
    line = _one_line(capsys, companion_main, ["run", "--config", str(path)], "m4-companion")
    assert line.endswith("[nmpc] horizon must be <= 40 (the NMPC must solve within a control period), got 100000")


def test_a_control_rate_the_loop_cannot_use_is_refused_with_the_limit(capsys, tmp_path):
    path = tmp_path / "companion.toml"
    path.write_text("[control]\nrate_hz = 5000\n")
    assert "rate_hz must be <= 100" in _one_line(capsys, companion_main, ["run", "--config", str(path)], "m4-companion")


def test_a_misspelt_key_is_named_as_unknown_not_the_right_one_as_missing(capsys, tmp_path):
    text = scenarios.scenario_path("hover-rotor-loss").read_text().replace("\nduration_s", "\ndurration_s")
    path = tmp_path / "misspelt.toml"
    path.write_text(text)
    line = _one_line(capsys, sitl_main, ["fly", str(path), "--out", str(tmp_path / "run")], "m4-sitl")
    assert line.endswith("misspelt.toml: unknown key durration_s (did you mean duration_s?)")


class _Plant:
    def state(self):
        return _State()


class _State:
    def __getattr__(self, name):
        return 0.0


def test_the_truth_log_keeps_a_bounded_window():
    recorder = TruthRecorder(period_ms=10, max_samples=100)
    for t_ms in range(0, 5000, 10):
        recorder.observe(t_ms, _Plant())
    truth = recorder.truth()
    assert len(truth.time_s) == 100 and recorder.dropped == 400
    assert truth.time_s[0] == pytest.approx(4.0) and truth.time_s[-1] == pytest.approx(4.99)


@pytest.mark.parametrize("args, error", [
    (["campaign", "--samples", "0"], "argument --samples: must be >= 1, got 0"),
    (["campaign", "--samples", "-1"], "argument --samples: must be >= 1, got -1"),
    (["campaign", "--jobs", "0"], "argument --jobs: must be >= 1, got 0"),
    (["compare", "--jobs", "0"], "argument --jobs: must be >= 1, got 0")])
def test_a_campaign_of_no_flights_or_no_workers_is_refused_before_anything_flies(capsys, tmp_path, args, error):
    line = _one_line(capsys, sitl_main, [*args, "--out", str(tmp_path / "out")], "m4-sitl")
    assert line.endswith(error) and not (tmp_path / "out").exists()
