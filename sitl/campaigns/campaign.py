"""`m4-sitl campaign`: many faulted flights, in parallel, summarised by survival and detection.

The flights are drawn from a seeded random sample (or the full grid with `grid=True`) of:
the failing rotor (1..4), the loss of effectiveness (LOSS_LEVELS), the fault time, the
speed of forward flight at the fault (0: hover, up to MAX_SPEED_M_S, heading random), and
the plant's mismatch (mass and inertia scales) and sensor noise. Each becomes a scenario
file in <out>/scenarios/ (so any one can be flown again with `m4-sitl fly FILE`), is flown
by sitl.campaigns.parallel and leaves its folder in <out>/flights/.

Every flight has its own sensor-noise seed (`noise_seed`, drawn from the campaign's seed and
the flight's index, in campaign.csv): `m4-sitl fly <out>/scenarios/NAME.toml --seed
NOISE_SEED` flies that very flight again.

Outputs: campaign.csv (one row a flight) and summary.md (survival rate, altitude loss,
detection latency and rotor isolation per loss level, hover and forward flight apart). A
flight that did not run is a row with its error.
"""

from __future__ import annotations

import csv
import itertools
import math
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from m4.airframe import ROTOR_COUNT
from sitl.flights.flight_run import FlightOptions
from sitl.links.emulation import LinkEmulation, flights_note
from sitl.campaigns.parallel import Batch, FlightJob, fly_all

LOSS_LEVELS = (0.33, 0.66, 1.0)
MAX_SPEED_M_S = 3.0
GRID_SPEEDS_M_S = (0.0, 1.5, 3.0)
GRID_FAULT_TIMES_S = (1.0, 2.5)
FAULT_TIME_RANGE_S = (1.0, 3.0)
MASS_SCALE_RANGE = (0.95, 1.05)
INERTIA_SCALE_RANGE = (0.9, 1.1)
AFTER_FAULT_S = 5.0
ALTITUDE_M = 3.0
DEFAULT_OUT = Path("runs") / "campaign"


@dataclass(frozen=True)
class Case:
    name: str
    rotor: int
    loss: float
    at_s: float
    speed_m_s: float
    heading_deg: float = 0.0
    mass_scale: float = 1.0
    inertia_scale: float = 1.0
    sensor_noise: bool = False
    noise_seed: int = 0

    @property
    def duration_s(self) -> float:
        return self.at_s + AFTER_FAULT_S

    def scenario_toml(self) -> str:
        lines = [f'name = "{self.name}"', f"duration_s = {self.duration_s:g}", "", "[start]",
                 f"ned_m = [0.0, 0.0, {-ALTITUDE_M:g}]", "", "[mission]", 'on_fault = "hold"']
        if self.speed_m_s > 0:
            distance = self.speed_m_s * (self.duration_s + 5.0)
            h = math.radians(self.heading_deg)
            lines += ["[[mission.waypoint]]",
                      f"ned_m = [{distance * math.cos(h):.3f}, {distance * math.sin(h):.3f}, {-ALTITUDE_M:g}]",
                      f"speed_m_s = {self.speed_m_s:g}"]
        lines += ["", "[[fault]]", f"at_s = {self.at_s:g}", f"rotor = {self.rotor}", f"loss = {self.loss:g}", "",
                  "[plant]", f"mass_scale = {self.mass_scale:g}", f"inertia_scale = {self.inertia_scale:g}",
                  f"sensor_noise = {'true' if self.sensor_noise else 'false'}", ""]
        return "\n".join(lines)


def noise_seed(seed: int, index: int) -> int:
    """The sensor-noise seed of a campaign's flight: its own, from the campaign's seed and its index."""
    return int(np.random.SeedSequence((seed, index)).generate_state(1)[0])


def grid_cases(losses: tuple[float, ...] = LOSS_LEVELS, seed: int = 0) -> list[Case]:
    combos = itertools.product(range(1, ROTOR_COUNT + 1), losses, GRID_SPEEDS_M_S, GRID_FAULT_TIMES_S)
    return [Case(f"grid-{i:03d}", rotor, loss, at_s, speed, noise_seed=noise_seed(seed, i))
            for i, (rotor, loss, speed, at_s) in enumerate(combos)]


def random_cases(n: int, seed: int = 0, losses: tuple[float, ...] = LOSS_LEVELS) -> list[Case]:
    rng = np.random.default_rng(seed)
    cases = []
    for i in range(n):
        hover = rng.random() < 0.5
        cases.append(Case(
            name=f"sample-{i:03d}", rotor=int(rng.integers(1, ROTOR_COUNT + 1)), loss=float(rng.choice(losses)),
            at_s=round(float(rng.uniform(*FAULT_TIME_RANGE_S)), 2),
            speed_m_s=0.0 if hover else round(float(rng.uniform(0.5, MAX_SPEED_M_S)), 2),
            heading_deg=round(float(rng.uniform(-180.0, 180.0)), 1),
            mass_scale=round(float(rng.uniform(*MASS_SCALE_RANGE)), 3),
            inertia_scale=round(float(rng.uniform(*INERTIA_SCALE_RANGE)), 3),
            sensor_noise=bool(rng.random() < 0.5), noise_seed=noise_seed(seed, i)))
    return cases


def result_row(case: Case, metrics: dict) -> dict:
    row = asdict(case)
    if "error" in metrics:
        return {**row, "survived": False, "error": metrics["error"]}
    fault = metrics["faults"][0]
    detected = fault["detected_at_s"]
    return {**row, "survived": metrics["survived"], "crashed": metrics["crashed"],
            "altitude_loss_m": metrics["altitude_loss_m"], "max_tilt_deg": metrics["max_tilt_deg_after_fault"],
            "detected": detected is not None,
            "detection_latency_s": None if detected is None else round(detected - fault["at_s"], 3),
            "rotor_isolated": fault["detected_rotor"] == case.rotor, "error": ""}


def _stats(rows: list[dict]) -> str:
    flown = [r for r in rows if not r["error"]]
    if not rows:
        return ""
    survived = sum(r["survived"] for r in rows)
    loss = [r["altitude_loss_m"] for r in flown]
    latency = [r["detection_latency_s"] for r in flown if r["detection_latency_s"] is not None]
    isolated = sum(r["rotor_isolated"] for r in flown)

    def fmt(values, f):
        return f(values) if values else float("nan")
    return (f"{len(rows)} | {survived}/{len(rows)} ({100 * survived / len(rows):.0f} %) | "
            f"{fmt(loss, np.median):.2f} / {fmt(loss, np.max):.2f} | "
            f"{len(latency)}/{len(flown)} | {fmt(latency, np.median):.2f} / {fmt(latency, np.max):.2f} | "
            f"{isolated}/{len(flown)}")


def summary_markdown(rows: list[dict]) -> str:
    head = ("| group | flights | survived | altitude loss median / max (m) | detected | "
            "detection latency median / max (s) | rotor isolated |\n|---|---|---|---|---|---|---|\n")
    lines = []
    for loss in sorted({r["loss"] for r in rows}):
        for label, moving in (("hover", False), ("forward flight", True)):
            group = [r for r in rows if r["loss"] == loss and (r["speed_m_s"] > 0) == moving]
            if group:
                lines.append(f"| loss {loss:g}, {label} | {_stats(group)} |")
    lines.append(f"| **all** | {_stats(rows)} |")
    target = [r for r in rows if r["loss"] == 1.0 and r["speed_m_s"] <= MAX_SPEED_M_S]
    survived = sum(r["survived"] for r in target)
    verdict = (f"Target, single total rotor loss in hover and forward flight up to {MAX_SPEED_M_S:g} m/s: "
               f"{survived}/{len(target)} survived." if target else "")
    return head + "\n".join(lines) + "\n\n" + verdict + "\n"


@dataclass(frozen=True)
class Campaign:
    summary: str                   # summary.md's text
    rows: list[dict]               # campaign.csv's rows
    batch: Batch                   # as flown, in the order of the rows


def run_campaign(out_dir: Path = DEFAULT_OUT, samples: int = 20, seed: int = 0, grid: bool = False,
                 workers: int | None = None, rate_hz: float | None = None,
                 losses: tuple[float, ...] = LOSS_LEVELS, engine: str = "local",
                 scheduler: str | None = None, link: LinkEmulation | None = None,
                 lockstep_timeout_s: float = FlightOptions.lockstep_timeout_s) -> Campaign:
    out_dir = Path(out_dir).resolve()
    cases = grid_cases(losses, seed) if grid else random_cases(samples, seed, losses)
    (out_dir / "scenarios").mkdir(parents=True, exist_ok=True)
    jobs = []
    for case in cases:
        path = out_dir / "scenarios" / f"{case.name}.toml"
        path.write_text(case.scenario_toml())
        jobs.append(FlightJob(str(path), out_dir / "flights" / case.name,
                              FlightOptions(seed=case.noise_seed, rate_hz=rate_hz, link=link,
                                            lockstep_timeout_s=lockstep_timeout_s)))
    batch = fly_all(jobs, workers, "campaign", engine, scheduler)
    rows = [result_row(c, m) for c, m in zip(cases, batch.results)]
    with (out_dir / "campaign.csv").open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(dict.fromkeys(k for row in rows for k in row)), restval="")
        writer.writeheader()
        writer.writerows(rows)
    summary = flights_note(link) + summary_markdown(rows)
    (out_dir / "summary.md").write_text(summary)
    return Campaign(summary, rows, batch)
