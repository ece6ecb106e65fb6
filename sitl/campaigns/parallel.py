"""Many flights side by side: on the local cores (concurrent.futures processes), or on a Dask
cluster (`engine="dask"`, the optional `cluster` extra).

Each flight is one `sitl.flights.fly.fly()` in a worker process, which starts the SITL and the
companion as forks of its two fork servers (sitl/flights/forks.py: `m4-sitl serve` and
`m4-companion run` pre-loaded once a worker, the flights those of new processes bit for bit);
every flight takes its own free loopback ports of the machine it runs on. A flight
that cannot run gives an `{"error": ...}` row instead of stopping the others, and the batch
says which (`Batch.failed`): the commands exit non-zero on them. The jobs' paths are made
absolute here, before they reach a worker (a Dask worker's working folder is not ours). A
progress bar (tqdm) counts flights. With Dask, the output folders must be on a file system
every worker shares; without a scheduler address a local cluster (127.0.0.1, no dashboard)
is used. Throughput: flights per core-minute, the cores being those the flights could use:
local, one per worker up to the cores this process may use (`--jobs 1` flies on one core of
many); Dask, each worker host's cores once (a local cluster's: one per worker up to them).
"""

from __future__ import annotations

import atexit
import dataclasses
import functools
import multiprocessing
import os
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field
from pathlib import Path

from tqdm import tqdm

from m4.toml_fields import ConfigError
from sitl.flights.flight_run import FlightError, FlightOptions

ENGINES = ("local", "dask")


@dataclass(frozen=True)
class FlightJob:
    scenario: str                  # built-in name or scenario file
    out_dir: Path
    options: FlightOptions = field(default_factory=FlightOptions)
    figures: bool = False

    def absolute(self) -> FlightJob:
        """The job with its output folder, and its scenario when it is a file, as absolute paths."""
        scenario = Path(self.scenario)
        return dataclasses.replace(self, out_dir=Path(self.out_dir).resolve(),
                                   scenario=str(scenario.resolve()) if scenario.is_file() else self.scenario)


@dataclass(frozen=True)
class Batch:
    results: list[dict]            # each flight's metrics, or {"error": ...}, in the order of the jobs
    names: list[str]               # each flight's name: its folder's
    wall_s: float
    cores: int

    @property
    def failed(self) -> list[int]:
        """Indices of the flights that did not run."""
        return [i for i, r in enumerate(self.results) if "error" in r]

    @property
    def flights_per_core_minute(self) -> float:
        return len(self.results) / max(self.wall_s / 60.0 * self.cores, 1e-9)

    def not_run(self) -> str | None:
        """None when every flight ran; else one line: how many did not, and why the first did not."""
        if not self.failed:
            return None
        first = self.failed[0]
        return (f"{len(self.failed)} of {len(self.results)} flights did not run; "
                f"{self.names[first]}: {self.results[first]['error']}")

    def throughput(self) -> str:
        return (f"{len(self.results)} flights in {self.wall_s:.0f} s on {self.cores} cores: "
                f"{self.flights_per_core_minute:.2f} flights per core-minute")


def default_workers() -> int:
    """One flight per core: in lockstep a flight's two processes (plant and companion) take
    turns, so together they keep about one core busy (with 2 flights on 2 cores a campaign ran
    8.5-9 flights per core-minute, with 1 flight 4, with 4 flights 7.3; measured under load)."""
    return _local_cores()


def _local_cores() -> int:
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


@functools.cache
def _forked_start():
    """The worker's ForkedStart: its fork servers start at its first flight and serve all of its flights."""
    from sitl.flights.forks import ForkedStart

    start = ForkedStart()
    atexit.register(start.close)        # the servers waited for at the worker's end: their CPU counts as its own
    return start


def _fly(job: FlightJob) -> dict:
    from sitl.flights.fly import fly

    try:
        return fly(job.scenario, job.out_dir, job.options, figures=job.figures, progress=False,
                   start=_forked_start())
    except (FlightError, ConfigError) as e:
        return {"error": str(e)}
    except Exception as e:  # noqa: BLE001 - whatever stops one flight is its row's error; the others go on
        return {"error": f"{type(e).__name__}: {e}"}


def fly_all(jobs: list[FlightJob], workers: int | None = None, desc: str = "flights", engine: str = "local",
            scheduler: str | None = None) -> Batch:
    """Every job flown; the results in the order of `jobs`."""
    if engine not in ENGINES:
        raise FlightError(f"unknown engine {engine!r}; choose from {', '.join(ENGINES)}")
    jobs = [job.absolute() for job in jobs]
    start = time.monotonic()
    if engine == "dask":
        results, cores = _fly_all_dask(jobs, workers, desc, scheduler)
    else:
        results, cores = _fly_all_local(jobs, workers, desc), _local_cores()
    if workers is not None and scheduler is None:         # workers on this machine: one core each at most
        cores = min(cores, workers)
    return Batch(results, [job.out_dir.name for job in jobs], time.monotonic() - start, cores)


def _fly_all_local(jobs: list[FlightJob], workers: int | None, desc: str) -> list[dict]:
    results: list[dict | None] = [None] * len(jobs)
    # spawn, not fork: a forked copy of a process with threads (Zenoh's, a caller's) can
    # inherit a lock held by one of them and hang.
    with ProcessPoolExecutor(max_workers=workers or default_workers(),
                             mp_context=multiprocessing.get_context("spawn")) as pool:
        futures = {pool.submit(_fly, job): i for i, job in enumerate(jobs)}
        for future in tqdm(as_completed(futures), total=len(jobs), desc=desc, unit="flight"):
            results[futures[future]] = future.result()
    return results  # type: ignore[return-value]


def _fly_all_dask(jobs: list[FlightJob], workers: int | None, desc: str,
                  scheduler: str | None) -> tuple[list[dict], int]:
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
            cores_by_host = {address.rpartition(":")[0]: n for address, n in client.run(_local_cores).items()}
            futures = client.map(_fly, jobs, pure=False)
            index = {f.key: i for i, f in enumerate(futures)}
            for future in tqdm(dask_completed(futures), total=len(jobs), desc=desc, unit="flight"):
                results[index[future.key]] = future.result()
    finally:
        if cluster is not None:
            cluster.close()
    return results, sum(cores_by_host.values())  # type: ignore[return-value]
