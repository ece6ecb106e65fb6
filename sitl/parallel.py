"""Many flights side by side: on the local cores (concurrent.futures processes), or on a Dask
cluster (`engine="dask"`, the optional `cluster` extra).

Each flight is one `sitl.fly.fly()` in a worker process, which itself starts the SITL and the
companion; every flight takes its own free loopback ports of the machine it runs on. A flight
that cannot start gives an `{"error": ...}` row instead of stopping the others. A progress
bar (tqdm) counts flights. With Dask, the output folders must be on a file system every
worker shares; without a scheduler address a local cluster (127.0.0.1, no dashboard) is used.
"""

from __future__ import annotations

import os
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field
from pathlib import Path

from tqdm import tqdm

from m4.toml_fields import ConfigError
from sitl.flight_run import FlightError, FlightOptions

ENGINES = ("local", "dask")


@dataclass(frozen=True)
class FlightJob:
    scenario: str                  # built-in name or scenario file
    out_dir: Path
    options: FlightOptions = field(default_factory=FlightOptions)
    figures: bool = False


def default_workers() -> int:
    """Each flight keeps about two processes busy (plant and companion)."""
    return max(1, (os.cpu_count() or 1) // 2)


def _fly(job: FlightJob) -> dict:
    from sitl.fly import fly

    try:
        return fly(job.scenario, job.out_dir, job.options, figures=job.figures, progress=False)
    except (FlightError, ConfigError) as e:
        return {"error": str(e)}


def fly_all(jobs: list[FlightJob], workers: int | None = None, desc: str = "flights", engine: str = "local",
            scheduler: str | None = None) -> list[dict]:
    """The metrics of every job, in the order of `jobs`."""
    if engine not in ENGINES:
        raise FlightError(f"unknown engine {engine!r}; choose from {', '.join(ENGINES)}")
    if engine == "dask":
        return _fly_all_dask(jobs, workers, desc, scheduler)
    results: list[dict | None] = [None] * len(jobs)
    with ProcessPoolExecutor(max_workers=workers or default_workers()) as pool:
        futures = {pool.submit(_fly, job): i for i, job in enumerate(jobs)}
        for future in tqdm(as_completed(futures), total=len(jobs), desc=desc, unit="flight"):
            results[futures[future]] = future.result()
    return results  # type: ignore[return-value]


def _fly_all_dask(jobs: list[FlightJob], workers: int | None, desc: str, scheduler: str | None) -> list[dict]:
    try:
        from dask.distributed import Client, LocalCluster
        from dask.distributed import as_completed as dask_completed
    except ImportError:
        raise FlightError("engine 'dask' needs the cluster extra: pip install 'm4-fault-recovery[cluster]'") from None
    results: list[dict | None] = [None] * len(jobs)
    cluster = None if scheduler else LocalCluster(n_workers=workers or default_workers(), threads_per_worker=1,
                                                  host="127.0.0.1", dashboard_address=None)
    try:
        with Client(scheduler or cluster) as client:
            futures = client.map(_fly, jobs, pure=False)
            index = {f.key: i for i, f in enumerate(futures)}
            for future in tqdm(dask_completed(futures), total=len(jobs), desc=desc, unit="flight"):
                results[index[future.key]] = future.result()
    finally:
        if cluster is not None:
            cluster.close()
    return results  # type: ignore[return-value]
