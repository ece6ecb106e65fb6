"""sitl.campaigns.parallel: results come back in the order of the jobs, a flight that cannot start is an
error row, on local processes and on a local Dask cluster alike (no flight is flown here)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from sitl.flights.flight_run import FlightError
from sitl.campaigns.parallel import Batch, FlightJob, fly_all


def _jobs(tmp_path):
    return [FlightJob(f"missing-{i}.toml", tmp_path / str(i)) for i in range(3)]


@pytest.mark.parametrize("engine", ["local", "dask"])
def test_results_keep_the_order_of_the_jobs_and_failures_are_rows(tmp_path, engine):
    if engine == "dask":
        pytest.importorskip("distributed")
    results = fly_all(_jobs(tmp_path), workers=2, engine=engine).results
    assert [f"missing-{i}.toml" in r["error"] for i, r in enumerate(results)] == [True] * 3


@pytest.mark.parametrize("engine", ["local", "dask"])
def test_the_throughput_counts_the_cores_the_workers_could_use_not_the_machines(tmp_path, engine):
    """`--jobs 1` flies one flight at a time: one core, however many the machine has."""
    if engine == "dask":
        pytest.importorskip("distributed")
    assert fly_all(_jobs(tmp_path), workers=1, engine=engine).cores == 1
    cores = len(os.sched_getaffinity(0))
    assert fly_all(_jobs(tmp_path), workers=cores + 1, engine="local").cores == cores


def test_an_unknown_engine_is_refused(tmp_path):
    with pytest.raises(FlightError, match="unknown engine 'ray'"):
        fly_all(_jobs(tmp_path), engine="ray")


def test_relative_paths_reach_the_workers_absolute(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "bad.toml").write_text('name = "bad"\nduration_s = [\n')
    job = FlightJob("bad.toml", Path("out"))
    assert job.absolute() == FlightJob(str(tmp_path / "bad.toml"), tmp_path / "out")
    assert FlightJob("hover-rotor-loss", Path("out")).absolute().scenario == "hover-rotor-loss"   # a built-in name
    batch = fly_all([job], workers=1)
    assert str(tmp_path / "bad.toml") in batch.results[0]["error"]


def test_a_batch_names_the_flights_that_did_not_run_and_its_throughput():
    batch = Batch([{"survived": True}, {"error": "port in use"}, {"error": "no companion"}], ["a", "b", "c"],
                  wall_s=30.0, cores=2)
    assert batch.failed == [1, 2]
    assert batch.not_run() == "2 of 3 flights did not run; b: port in use"
    assert batch.flights_per_core_minute == pytest.approx(3.0)
    assert batch.throughput() == "3 flights in 30 s on 2 cores: 3.00 flights per core-minute"
    assert Batch([{"survived": False}], ["a"], 1.0, 1).not_run() is None
