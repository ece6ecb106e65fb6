"""`m4-sitl campaign --kind ... --esc ... --speed ...`: fault detection measured the way the
literature does, on the MuJoCo plant with the companion in the loop.

For every failure kind x speed x ESC telemetry (on/off) x rotor one flight: the fault at
FAULT_AT_S (hover, or flying straight at the speed), sensor noise, the plant's mass and
inertia off by up to MISMATCH (seeded, per flight). Kinds and their loss: motor and
propeller total, degraded LOSS_BY_KIND (ceiling (1 - loss) x hover thrust), damage
LOSS_BY_KIND (thrust (1 - loss) at the same speed: ceiling (1 - loss) x the rotor's limit).
Fault-free endurance flights (`false_alarm_minutes`) fly an agile loop at 3 m/s with turns
and climbs on a sagging battery, with noise and mismatch, half of them without ESC telemetry.

Per flight: the detection as the flight's metrics have it (sitl.flights.metrics: the first confirmed
M4_FAULT_STATUS after the fault whose estimate reflects the fault's kind and loss; latency,
rotor), and from the companion's M4_FAULT_STATUS in the tlog the ceiling estimate of that
rotor SIZING_AFTER_S later against the truth (truth.npz: what the rotor settles at on the
largest command then, fault and pack voltage applied; as % of hover thrust), survival
(sitl.flights.metrics), a false alarm (any confirmation before the fault or naming another rotor). Outputs: detection.csv and
detection.md in the folder.
"""

from __future__ import annotations

import csv
import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from analysis.detection import CONFIRMED
from m4.airframe import ROTOR_COUNT, load_airframe
from sitl.campaigns.campaign import Campaign
from sitl.flights.flight_run import FlightOptions
from sitl.links.emulation import LinkEmulation, flights_note
from sitl.campaigns.parallel import FlightJob, fly_all
from sitl.flights.records import FaultStatusLog, read_fault_status

if TYPE_CHECKING:                       # sitl.plant.truth loads the plant (MuJoCo): not for the CLI's parser
    from sitl.plant.truth import Truth

KINDS = ("motor", "propeller", "damage", "degraded")
LOSS_BY_KIND = {"motor": 1.0, "propeller": 1.0, "damage": 0.5, "degraded": 0.5}
FAULT_AT_S = 2.0
AFTER_FAULT_S = 4.0
SIZING_AFTER_S = 1.0
MISMATCH = 0.1
ALTITUDE_M = 3.0
ENDURANCE_FLIGHT_S = 60.0
TARGETS_S = {("motor", True): 0.05, ("propeller", True): 0.10, ("motor", False): 0.15, ("propeller", False): 0.15}
SIZING_TARGET_PCT = 10.0
DEFAULT_OUT = Path("runs") / "detection"


@dataclass(frozen=True)
class DetectionCase:
    name: str
    kind: str                 # "" for a fault-free endurance flight
    rotor: int                # 0: none
    speed_m_s: float
    esc: bool
    mass_scale: float
    inertia_scale: float
    duration_s: float

    @property
    def loss(self) -> float:
        return LOSS_BY_KIND.get(self.kind, 0.0)

    def scenario_toml(self) -> str:
        lines = [f'name = "{self.name}"', f"duration_s = {self.duration_s:g}", "", "[start]",
                 f"ned_m = [0.0, 0.0, {-ALTITUDE_M:g}]", "", "[mission]", 'on_fault = "hold"']
        if self.kind:
            if self.speed_m_s > 0:
                lines += ["[[mission.waypoint]]", f"ned_m = [{self.speed_m_s * (self.duration_s + 5):.3f}, 0.0, "
                          f"{-ALTITUDE_M:g}]", f"speed_m_s = {self.speed_m_s:g}"]
            lines += ["", "[[fault]]", f"at_s = {FAULT_AT_S:g}", f"rotor = {self.rotor}", f'kind = "{self.kind}"',
                      f"loss = {self.loss:g}"]
        else:
            lines += _agile_loop(self.duration_s)
        lines += ["", "[plant]", f"mass_scale = {self.mass_scale:g}", f"inertia_scale = {self.inertia_scale:g}",
                  "sensor_noise = true", f"esc_telemetry = {str(self.esc).lower()}"]
        if not self.kind:
            lines += ["battery = true", "battery_charge = 0.5"]
        return "\n".join(lines) + "\n"


def _agile_loop(duration_s: float) -> list[str]:
    """Laps of a 10 x 8 m box at 3 m/s with a 2 m climb and descent on every lap."""
    corners = [(10.0, 0.0, -3.0), (10.0, 8.0, -5.0), (0.0, 8.0, -5.0), (0.0, 0.0, -3.0)]
    lap_s = 2 * (10.0 + 8.0) / 3.0 + 2.0
    lines = []
    for _ in range(max(1, int(duration_s / lap_s))):
        for n, e, d in corners:
            lines += ["[[mission.waypoint]]", f"ned_m = [{n:g}, {e:g}, {d:g}]", "speed_m_s = 3.0"]
    return lines


def detection_cases(kinds, speeds, escs, seed: int = 0, false_alarm_minutes: float = 0.0) -> list[DetectionCase]:
    rng = np.random.default_rng(seed)

    def scales():
        return tuple(round(float(v), 3) for v in rng.uniform(1 - MISMATCH, 1 + MISMATCH, 2))
    cases = []
    for kind in kinds:
        for speed in speeds:
            for esc in escs:
                for rotor in range(1, ROTOR_COUNT + 1):
                    mass, inertia = scales()
                    cases.append(DetectionCase(f"{kind}-{speed:g}ms-esc{'on' if esc else 'off'}-r{rotor}", kind, rotor,
                                               speed, esc, mass, inertia, FAULT_AT_S + AFTER_FAULT_S))
    for k in range(math.ceil(false_alarm_minutes * 60.0 / ENDURANCE_FLIGHT_S)):
        mass, inertia = scales()
        cases.append(DetectionCase(f"fault-free-{k}", "", 0, 3.0, k % 2 == 0, mass, inertia, ENDURANCE_FLIGHT_S))
    return cases


def result_row(case: DetectionCase, metrics: dict, status: FaultStatusLog, truth: Truth | None, hover_n: float) -> dict:
    row = {**asdict(case), "loss": case.loss}
    if "error" in metrics:
        return {**row, "survived": False, "error": metrics["error"]}
    confirmed = status.state == CONFIRMED
    at_s = FAULT_AT_S if case.kind else math.inf
    wrong = confirmed & ((status.time_s < at_s) | (status.rotor != case.rotor))
    detection = metrics["faults"][0] if case.kind else {"detected_at_s": None}
    detected_s = detection["detected_at_s"]
    row.update(survived=bool(metrics["survived"]), false_alarm=bool(np.any(wrong)), detected=detected_s is not None,
               latency_s=None, rotor_isolated=False, estimate_error_pct=None, error="")
    if detected_s is not None:
        rotor = detection["detected_rotor"]
        row["latency_s"] = round(detected_s - at_s, 3)
        row["rotor_isolated"] = rotor == case.rotor
        later = np.flatnonzero(status.time_s >= detected_s + SIZING_AFTER_S)
        j = later[0] if later.size else len(status.time_s) - 1
        if row["rotor_isolated"] and status.rotor[j] == rotor and truth is not None:
            estimate = status.thrust_max_estimate_n[j, rotor - 1]
            k_truth = min(int(np.searchsorted(truth.time_s, status.time_s[j])), len(truth.time_s) - 1)
            true_n = truth.thrust_limit_n[k_truth, rotor - 1]
            row["estimate_error_pct"] = round(100.0 * (estimate - true_n) / hover_n, 1)
    return row


def _stat(values, f, fmt) -> str:
    values = [v for v in values if v is not None]
    return format(f(values), fmt) if values else "-"


def summary_markdown(rows: list[dict]) -> str:
    head = ("| kind | speed (m/s) | ESC telemetry | flights | detected | latency median / max (s) | rotor isolated | "
            "ceiling error median / worst (% hover) | survived | false alarms |\n|---|---|---|---|---|---|---|---|---|---|\n")
    lines = []
    faulted = [r for r in rows if r["kind"]]
    for kind in dict.fromkeys(r["kind"] for r in faulted):
        for speed in sorted({r["speed_m_s"] for r in faulted}):
            for esc in (True, False):
                g = [r for r in faulted if r["kind"] == kind and r["speed_m_s"] == speed and r["esc"] == esc]
                if not g:
                    continue
                lat = [r.get("latency_s") for r in g]
                err = [r.get("estimate_error_pct") for r in g]
                lines.append(
                    f"| {kind} | {speed:g} | {'on' if esc else 'off'} | {len(g)} | {sum(r.get('detected', False) for r in g)} | "
                    f"{_stat(lat, np.median, '.2f')} / {_stat(lat, np.max, '.2f')} | "
                    f"{sum(r.get('rotor_isolated', False) for r in g)}/{len(g)} | "
                    f"{_stat(err, lambda v: np.median(np.abs(v)), '.1f')} / {_stat(err, lambda v: np.max(np.abs(v)), '.1f')} | "
                    f"{sum(r['survived'] for r in g)}/{len(g)} | {sum(r.get('false_alarm', False) for r in g)} |")
    free = [r for r in rows if not r["kind"]]
    if free:
        minutes = sum(r["duration_s"] for r in free) / 60.0
        lines.append(f"| none (agile loop, sagging battery) | 3 | on/off | {len(free)} ({minutes:.0f} min) | - | - | - | - | "
                     f"{sum(r['survived'] for r in free)}/{len(free)} | {sum(r.get('false_alarm', False) for r in free)} |")
    return head + "\n".join(lines) + "\n\n" + "\n".join(_verdicts(rows)) + "\n"


def _verdicts(rows: list[dict]) -> list[str]:
    out = []
    for (kind, esc), target in TARGETS_S.items():
        lat = [r.get("latency_s") for r in rows if r["kind"] == kind and r["esc"] == esc]
        if lat:
            worst = max((v for v in lat if v is not None), default=None)
            met = None not in lat and worst is not None and worst <= target + 1e-9
            out.append(f"- {kind}, ESC telemetry {'on' if esc else 'off'}: worst latency "
                       f"{'-' if worst is None else f'{worst:.2f} s'} against {target:.2f} s: {'met' if met else 'NOT met'}")
    sized = [r.get("estimate_error_pct") for r in rows if r["kind"] in ("damage", "degraded")]
    if sized:
        worst = max((abs(v) for v in sized if v is not None), default=math.inf)
        met = None not in sized and worst <= SIZING_TARGET_PCT
        out.append(f"- partial losses sized within {SIZING_TARGET_PCT:g} % of hover thrust: worst {worst:.1f} %: "
                   f"{'met' if met else 'NOT met'}")
    total = [r for r in rows if r["kind"] in ("motor", "propeller")]
    if total:
        survived = sum(r["survived"] for r in total)
        out.append(f"- survival of total single-rotor loss: {survived}/{len(total)}: "
                   f"{'met' if survived == len(total) else 'NOT met'}")
    free = [r for r in rows if not r["kind"]]
    if free:
        alarms = sum(r.get("false_alarm", False) for r in free)
        minutes = sum(r["duration_s"] for r in free) / 60.0
        out.append(f"- false alarms over {minutes:.0f} min of fault-free agile flight: {alarms}: "
                   f"{'met' if alarms == 0 and minutes >= 5 else 'NOT met'}")
    return out


def run_detection_campaign(out_dir: Path, kinds, speeds, escs, seed: int = 0, false_alarm_minutes: float = 0.0,
                           workers: int | None = None, rate_hz: float | None = None, engine: str = "local",
                           scheduler: str | None = None, link: LinkEmulation | None = None) -> Campaign:
    from sitl.plant.truth import load_truth

    out_dir = Path(out_dir).resolve()
    cases = detection_cases(kinds, speeds, escs, seed, false_alarm_minutes)
    (out_dir / "scenarios").mkdir(parents=True, exist_ok=True)
    jobs = []
    for k, case in enumerate(cases):
        path = out_dir / "scenarios" / f"{case.name}.toml"
        path.write_text(case.scenario_toml())
        jobs.append(FlightJob(str(path), out_dir / "flights" / case.name, FlightOptions(seed=seed + k, rate_hz=rate_hz, link=link)))
    af = load_airframe()
    rows = []
    batch = fly_all(jobs, workers, "detection", engine, scheduler)
    for case, job, metrics in zip(cases, jobs, batch.results):
        tlog, truth = job.out_dir / "flight.tlog", job.out_dir / "truth.npz"
        status = read_fault_status(tlog) if tlog.exists() else FaultStatusLog.empty()
        rows.append(result_row(case, metrics, status, load_truth(truth) if truth.exists() else None,
                               af.hover_thrust_per_rotor_n))
    fields = list(dict.fromkeys(key for r in rows for key in r))
    with (out_dir / "detection.csv").open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=fields)
        writer.writeheader()
        writer.writerows(rows)
    summary = flights_note(link) + summary_markdown(rows)
    (out_dir / "detection.md").write_text(summary)
    return Campaign(summary, rows, batch)
