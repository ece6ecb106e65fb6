"""Many flights side by side on the local cores (concurrent.futures processes).

Each flight is one `sitl.fly.fly()` in a worker process, which itself starts the SITL and the
companion; every flight takes its own free loopback ports. A flight that cannot start gives
an `{"error": ...}` row instead of stopping the others. A progress bar (tqdm) counts flights.
"""

from __future__ import annotations

import os
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path

from tqdm import tqdm

from companion.toml_fields import ConfigError
from sitl.flight_run import FlightError, FlightOptions


@dataclass(frozen=True)
class FlightJob:
    scenario: str                  # built-in name or scenario file
    out_dir: Path
    options: FlightOptions = FlightOptions()
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


def fly_all(jobs: list[FlightJob], workers: int | None = None, desc: str = "flights") -> list[dict]:
    """The metrics of every job, in the order of `jobs`."""
    results: list[dict | None] = [None] * len(jobs)
    with ProcessPoolExecutor(max_workers=workers or default_workers()) as pool:
        futures = {pool.submit(_fly, job): i for i, job in enumerate(jobs)}
        for future in tqdm(as_completed(futures), total=len(jobs), desc=desc, unit="flight"):
            results[futures[future]] = future.result()
    return results  # type: ignore[return-value]
