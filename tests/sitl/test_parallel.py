"""sitl.parallel: results come back in the order of the jobs, a flight that cannot start is an
error row, on local processes and on a local Dask cluster alike (no flight is flown here)."""

from __future__ import annotations

import pytest

from sitl.flight_run import FlightError
from sitl.parallel import FlightJob, fly_all


def _jobs(tmp_path):
    return [FlightJob(f"missing-{i}.toml", tmp_path / str(i)) for i in range(3)]


@pytest.mark.parametrize("engine", ["local", "dask"])
def test_results_keep_the_order_of_the_jobs_and_failures_are_rows(tmp_path, engine):
    if engine == "dask":
        pytest.importorskip("distributed")
    results = fly_all(_jobs(tmp_path), workers=2, engine=engine)
    assert [f"missing-{i}.toml" in r["error"] for i, r in enumerate(results)] == [True] * 3


def test_an_unknown_engine_is_refused(tmp_path):
    with pytest.raises(FlightError, match="unknown engine 'ray'"):
        fly_all(_jobs(tmp_path), engine="ray")
