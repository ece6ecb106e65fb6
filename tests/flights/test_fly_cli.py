"""`m4-sitl fly` on bad input: one line on stderr naming what is wrong, exit code 2, nothing flown."""

from __future__ import annotations

import socket

import pytest

from sitl.cli import EXIT_BAD_INPUT, main


def _fails_with(capsys, args, *needles):
    assert main(args) == EXIT_BAD_INPUT
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("m4-sitl: error:")
    for needle in needles:
        assert needle in err


def test_an_unknown_scenario_is_named(capsys, tmp_path):
    _fails_with(capsys, ["fly", "no-such-scenario", "--out", str(tmp_path)], "unknown scenario 'no-such-scenario'")


def test_a_malformed_scenario_file_names_the_bad_key(capsys, tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text('name = "bad"\nduration_s = 5.0\n[start]\nned_m = [0.0, 0.0, -2.0]\naltitude = 3\n')
    _fails_with(capsys, ["fly", str(bad), "--out", str(tmp_path / "out")], "altitude")
    bad.write_text('name = "bad"\nduration_s = [\n')
    _fails_with(capsys, ["fly", str(bad), "--out", str(tmp_path / "out")], "bad.toml")


def test_a_port_in_use_is_refused_before_anything_starts(capsys, tmp_path):
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as busy:
        busy.bind(("127.0.0.1", 0))
        port = busy.getsockname()[1]
        _fails_with(capsys, ["fly", "hover-rotor-loss", "--port", str(port), "--out", str(tmp_path / "out")],
                    f"UDP port {port}", "not free")
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("port", ["0", "70000", "-3"])
def test_a_port_out_of_range_is_named(capsys, tmp_path, port):
    _fails_with(capsys, ["fly", "hover-rotor-loss", "--port", port, "--out", str(tmp_path / "out")],
                f"UDP port must be 1..65535, got {port}")
    assert not (tmp_path / "out").exists()


def test_an_unknown_controller_is_refused(capsys, tmp_path):
    _fails_with(capsys, ["fly", "hover-rotor-loss", "--controller", "pid", "--out", str(tmp_path)], "pid")


@pytest.mark.parametrize("command", ["compare", "campaign"])
def test_compare_and_campaign_refuse_unknown_options(capsys, command):
    _fails_with(capsys, [command, "--bogus"], "--bogus")


def test_a_campaign_whose_flights_do_not_run_says_why_and_exits_non_zero(capsys, tmp_path):
    out = tmp_path / "campaign"
    assert main(["campaign", "--samples", "2", "--jobs", "1", "--rate-hz", "1000", "--out", str(out)]) == 1
    captured = capsys.readouterr()
    last = captured.err.strip().splitlines()[-1]
    assert last.startswith("m4-sitl: error: 2 of 2 flights did not run; sample-000: the companion did not start: "
                           "companion.toml [control] rate_hz must be <= 100 (") and last.endswith("), got 1000")
    assert "flights per core-minute" in captured.out
    assert (out / "campaign.csv").read_text().count("rate_hz must be <= 100") == 2
