"""`m4-sitl campaign --kind ... --esc ... --speed ...`: fault detection measured the way the
literature does, on the MuJoCo plant with the companion in the loop.

For every turbulence level x sensor profile x detector setting x failure kind x speed x ESC
telemetry (on/off) x rotor one flight: the fault at FAULT_AT_S (hover, or flying straight
north at the speed), sensor noise, the plant's mass and inertia off by up to MISMATCH (seeded,
per flight). Weather (`Weather`): a mean wind of the campaign's speed blowing from a bearing
drawn per flight, the Dryden level, and on fault-free flights a 1-cosine gust every
GUST_EVERY_S of random bearing, peak and length; the FC's sensor profile (m4.scenario's
[sensors]). A sweep gives one of the companion's [fault_detector] settings each of several
values (e.g. chi2_min, its threshold of significance): the latency / false-alarm trade-off
(sitl.campaigns.tradeoff). Kinds and their loss: motor and
propeller total, degraded LOSS_BY_KIND (ceiling (1 - loss) x hover thrust), damage
LOSS_BY_KIND (thrust (1 - loss) at the same speed: ceiling (1 - loss) x the rotor's limit).
Fault-free endurance flights (`false_alarm_minutes`) fly an agile loop at 3 m/s with turns
and climbs on a sagging battery, with noise and mismatch, half of them without ESC telemetry.

Per flight: the detection as the flight's metrics have it (sitl.flights.metrics: the first confirmed
M4_FAULT_STATUS after the fault whose estimate reflects the fault's kind and loss; latency,
rotor), and from the companion's M4_FAULT_STATUS in the tlog the ceiling estimate of that
rotor SIZING_AFTER_S later against the truth (truth.npz: what the rotor settles at on the
largest command then, fault and pack voltage applied; as % of hover thrust), survival
(sitl.flights.metrics) and, for turbulence, held aloft (HELD_CHECKS), a false alarm (any confirmation before the fault or naming another
rotor), and the confirmations before the fault with the time flown before it (false alarms per
hour of flight). Outputs: detection.csv and detection.md in the folder, and with several
values of a sweep tradeoff.png. The SITL waits LOCKSTEP_TIMEOUT_S of wall clock for each
setpoint; a flight whose wait still ran out (its FC flew the failsafe: the machine, not the
software, decided it) is "stalled" in detection.csv, named in detection.md and counted in
no figure.
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
from sitl.flights.flight_run import FlightFiles, FlightOptions, stalled
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
GUST_EVERY_S = 10.0
GUST_PEAK_M_S = (2.0, 5.0)            # horizontal, drawn uniformly
GUST_LENGTH_S = (1.0, 3.0)
TARGETS_S = {("motor", True): 0.05, ("propeller", True): 0.10, ("motor", False): 0.15, ("propeller", False): 0.15}
TURBULENT_TARGETS_S = {("motor", True): 0.08, ("propeller", True): 0.12, ("motor", False): 0.20,
                       ("propeller", False): 0.20}
# Survival but the still-air "tilt back within 10 deg": in moderate turbulence a healthy robot
# holding against 11 m/s of air tilts beyond it (27 deg in the fault-free flights).
HELD_CHECKS = ("completed", "no_ground_contact_before_landing", "altitude_loss_within_0.5_m")
FREE_MINUTES_TARGET = {"none": 5.0, "light": 30.0, "moderate": 30.0, "severe": 30.0}
SIZING_TARGET_PCT = 10.0
DEFAULT_OUT = Path("runs") / "detection"
LOCKSTEP_TIMEOUT_S = 60.0             # the SITL's wall-clock wait for a setpoint: a loaded machine only slows a flight


@dataclass(frozen=True)
class Weather:
    """The air a flight meets and the sensors its FC estimates from."""
    wind_m_s: float = 0.0                 # mean wind speed, horizontal
    wind_from_deg: float = 0.0            # the bearing it blows from
    turbulence: str = "none"              # m4.scenario.TURBULENCE_LEVELS
    gusts: tuple[tuple[float, float, float, float], ...] = ()   # (at_s, peak north, peak east m/s, duration_s)
    profile: str = "ideal"                # m4.scenario.SENSOR_PROFILES

    @property
    def still_air(self) -> bool:
        return self.wind_m_s == 0 and self.turbulence == "none" and not self.gusts

    def toml_lines(self) -> list[str]:
        lines = []
        if not self.still_air:
            bearing = math.radians(self.wind_from_deg)        # the air moves towards the opposite bearing
            north, east = (-self.wind_m_s * f(bearing) for f in (math.cos, math.sin))
            lines += ["", "[wind]", f"mean_ned_m_s = [{north:.3f}, {east:.3f}, 0.0]", f'turbulence = "{self.turbulence}"']
            for at_s, g_north, g_east, duration_s in self.gusts:
                lines += ["[[wind.gust]]", f"at_s = {at_s:g}", f"peak_ned_m_s = [{g_north:.3f}, {g_east:.3f}, 0.0]",
                          f"duration_s = {duration_s:.3f}"]
        if self.profile != "ideal":
            lines += ["", "[sensors]", f'profile = "{self.profile}"']
        return lines


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
    weather: Weather = Weather()
    detector_setting: tuple[str, float] | None = None     # one [fault_detector] setting (name, value); None: defaults

    @property
    def loss(self) -> float:
        return LOSS_BY_KIND.get(self.kind, 0.0)

    @property
    def fault_at_s(self) -> float:
        return FAULT_AT_S if self.kind else self.duration_s


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
        lines += self.weather.toml_lines()
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


@dataclass(frozen=True)
class WeatherGrid:
    """The weather dimensions of a campaign: every turbulence level x sensor profile."""
    wind_m_s: float = 0.0
    turbulence: tuple[str, ...] = ("none",)
    profiles: tuple[str, ...] = ("ideal",)


def _weather(rng: np.random.Generator, wind_m_s: float, turbulence: str, profile: str, gusty_s: float) -> Weather:
    """A flight's weather; gusts every GUST_EVERY_S over gusty_s seconds (0: none) when the air moves."""
    if wind_m_s == 0 and turbulence == "none":
        return Weather(profile=profile)
    gusts = []
    for k in range(int(gusty_s / GUST_EVERY_S)):
        peak, bearing = rng.uniform(*GUST_PEAK_M_S), rng.uniform(0.0, 2 * math.pi)
        gusts.append((round(GUST_EVERY_S * (k + 0.5), 3), peak * math.cos(bearing), peak * math.sin(bearing),
                      float(rng.uniform(*GUST_LENGTH_S))))
    return Weather(wind_m_s, round(float(rng.uniform(0.0, 360.0)), 1), turbulence, tuple(gusts), profile)


def _suffix(weather: Weather, setting: tuple[str, float] | None) -> str:
    parts = [weather.turbulence] * (weather.turbulence != "none") + [weather.profile] * (weather.profile != "ideal")
    if setting is not None:
        parts.append(f"{setting[0]}{setting[1]:g}")
    return "".join(f"-{p}" for p in parts)


def detection_cases(kinds, speeds, escs, seed: int = 0, false_alarm_minutes: float = 0.0,
                    grid: WeatherGrid = WeatherGrid(), sweep: tuple[tuple[str, float], ...] = ()) -> list[DetectionCase]:
    """The flights: the draws of mass, inertia and the weather are seeded; still air draws no
    weather, so its flights are those of the campaign before the weather existed."""
    rng, weather_rng = np.random.default_rng(seed), np.random.default_rng([seed, 1])

    def scales():
        return tuple(round(float(v), 3) for v in rng.uniform(1 - MISMATCH, 1 + MISMATCH, 2))
    cases = []
    for turbulence in grid.turbulence:
        for profile in grid.profiles:
            for setting in sweep or (None,):
                for kind in kinds:
                    for speed in speeds:
                        for esc in escs:
                            for rotor in range(1, ROTOR_COUNT + 1):
                                mass, inertia = scales()
                                weather = _weather(weather_rng, grid.wind_m_s, turbulence, profile, 0.0)
                                cases.append(DetectionCase(
                                    f"{kind}-{speed:g}ms-esc{'on' if esc else 'off'}-r{rotor}{_suffix(weather, setting)}",
                                    kind, rotor, speed, esc, mass, inertia, FAULT_AT_S + AFTER_FAULT_S, weather, setting))
                for k in range(math.ceil(false_alarm_minutes * 60.0 / ENDURANCE_FLIGHT_S)):
                    mass, inertia = scales()
                    weather = _weather(weather_rng, grid.wind_m_s, turbulence, profile, ENDURANCE_FLIGHT_S)
                    cases.append(DetectionCase(f"fault-free-{k}{_suffix(weather, setting)}", "", 0, 3.0, k % 2 == 0,
                                               mass, inertia, ENDURANCE_FLIGHT_S, weather, setting))
    return cases


def case_columns(case: DetectionCase) -> dict:
    """The case as flat CSV columns."""
    row = {k: v for k, v in asdict(case).items() if k not in ("weather", "detector_setting")}
    w = case.weather
    setting, value = case.detector_setting or ("", None)
    return {**row, "loss": case.loss, "wind_m_s": w.wind_m_s, "wind_from_deg": w.wind_from_deg,
            "turbulence": w.turbulence, "gusts": len(w.gusts), "profile": w.profile, "setting": setting,
            "setting_value": value}


def confirmations_before(status: FaultStatusLog, at_s: float) -> int:
    """How many times the detector went to confirmed before at_s (each a new alarm)."""
    confirmed = (status.state == CONFIRMED) & (status.time_s < at_s)
    return int(np.count_nonzero(confirmed & ~np.r_[False, confirmed[:-1]]))


def result_row(case: DetectionCase, metrics: dict, status: FaultStatusLog, truth: Truth | None, hover_n: float,
               was_stalled: bool = False) -> dict:
    """The flight's row; one whose lockstep stalled (the FC flew its failsafe while the companion
    was late on the wall clock) says so ("stalled") and counts in no figure."""
    row = {**case_columns(case), "stalled": was_stalled}
    if "error" in metrics:
        return {**row, "survived": False, "error": metrics["error"]}
    confirmed = status.state == CONFIRMED
    at_s = FAULT_AT_S if case.kind else math.inf
    wrong = confirmed & ((status.time_s < at_s) | (status.rotor != case.rotor))
    detection = metrics["faults"][0] if case.kind else {"detected_at_s": None}
    detected_s = detection["detected_at_s"]
    checks = metrics.get("checks", {})
    row.update(survived=bool(metrics["survived"]), false_alarm=bool(np.any(wrong)),
               held=all(bool(checks.get(k)) for k in HELD_CHECKS),
               alarms_before_fault=confirmations_before(status, at_s), flown_before_fault_s=case.fault_at_s,
               detected=detected_s is not None, latency_s=None, rotor_isolated=False, estimate_error_pct=None, error="")
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


def _groups(rows: list[dict], keys: tuple[str, ...]) -> list[tuple[tuple, list[dict]]]:
    """The rows by the values of keys, in the order they first appear."""
    out: dict[tuple, list[dict]] = {}
    for r in rows:
        out.setdefault(tuple(r[k] for k in keys), []).append(r)
    return list(out.items())


def _setting(r: dict) -> str:
    return f"{r['setting']} {r['setting_value']:g}" if r.get("setting") else "default"


def alarms_per_hour(rows: list[dict]) -> float:
    """Confirmations before the fault per hour flown before it."""
    flown_s = sum(r.get("flown_before_fault_s", 0.0) for r in rows if not r.get("error"))
    return 3600.0 * sum(r.get("alarms_before_fault", 0) for r in rows) / flown_s if flown_s else math.nan


def summary_markdown(rows: list[dict]) -> str:
    """The tables and verdicts of the flights that did not stall, after a line naming those that did."""
    note, rows = stalled_note(rows), [r for r in rows if not r.get("stalled")]
    head = note + ("| kind | speed (m/s) | ESC telemetry | turbulence | profile | detector | flights | detected | "
            "latency median / max (s) | rotor isolated | ceiling error median / worst (% hover) | survived | "
            "held aloft | false alarms |\n|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n")
    lines = []
    faulted = [r for r in rows if r["kind"]]
    for (turbulence, profile, kind), g0 in _groups(faulted, ("turbulence", "profile", "kind")):
        for setting in dict.fromkeys(map(_setting, g0)):
            for speed in sorted({r["speed_m_s"] for r in g0}):
                for esc in (True, False):
                    g = [r for r in g0 if _setting(r) == setting and r["speed_m_s"] == speed and r["esc"] == esc]
                    if not g:
                        continue
                    lat = [r.get("latency_s") for r in g]
                    err = [r.get("estimate_error_pct") for r in g]
                    lines.append(
                        f"| {kind} | {speed:g} | {'on' if esc else 'off'} | {turbulence} | {profile} | {setting} | "
                        f"{len(g)} | {sum(r.get('detected', False) for r in g)} | "
                        f"{_stat(lat, np.median, '.2f')} / {_stat(lat, np.max, '.2f')} | "
                        f"{sum(r.get('rotor_isolated', False) for r in g)}/{len(g)} | "
                        f"{_stat(err, lambda v: np.median(np.abs(v)), '.1f')} / "
                        f"{_stat(err, lambda v: np.max(np.abs(v)), '.1f')} | "
                        f"{sum(r['survived'] for r in g)}/{len(g)} | {sum(r.get('held', False) for r in g)}/{len(g)} | "
                        f"{sum(r.get('false_alarm', False) for r in g)} |")
    free = [r for r in rows if not r["kind"]]
    if free:
        lines += ["", "| fault-free (agile loop, sagging battery, gusts in moving air) | turbulence | profile | detector | "
                      "flights | minutes | held aloft | false alarms | per hour |", "|---|---|---|---|---|---|---|---|---|"]
        for (turbulence, profile), g0 in _groups(free, ("turbulence", "profile")):
            for setting in dict.fromkeys(map(_setting, g0)):
                g = [r for r in g0 if _setting(r) == setting]
                minutes = sum(r["duration_s"] for r in g if not r.get("error")) / 60.0
                lines.append(f"| 3 m/s, ESC on/off | {turbulence} | {profile} | {setting} | {len(g)} | {minutes:.0f} | "
                             f"{sum(r.get('held', False) for r in g)}/{len(g)} | {sum(r.get('alarms_before_fault', 0) for r in g)} | "
                             f"{alarms_per_hour(g):.1f} |")
    return head + "\n".join(lines) + "\n\n" + "\n".join(_verdicts(rows)) + "\n"


def _verdicts(rows: list[dict]) -> list[str]:
    out = []
    for (turbulence, profile), level in _groups([r for r in rows if not r.get("setting")], ("turbulence", "profile")):
        where = f" ({turbulence} turbulence, {profile})" if (turbulence, profile) != ("none", "ideal") else ""
        targets = TARGETS_S if turbulence == "none" else TURBULENT_TARGETS_S
        for (kind, esc), target in targets.items():
            lat = [r.get("latency_s") for r in level if r["kind"] == kind and r["esc"] == esc]
            if lat:
                worst = max((v for v in lat if v is not None), default=None)
                met = None not in lat and worst is not None and worst <= target + 1e-9
                out.append(f"- {kind}, ESC telemetry {'on' if esc else 'off'}{where}: worst latency "
                           f"{'-' if worst is None else f'{worst:.2f} s'} against {target:.2f} s: "
                           f"{'met' if met else 'NOT met'}")
        sized = [r.get("estimate_error_pct") for r in level if r["kind"] in ("damage", "degraded")]
        if sized:
            worst = max((abs(v) for v in sized if v is not None), default=math.inf)
            met = None not in sized and worst <= SIZING_TARGET_PCT
            out.append(f"- partial losses sized within {SIZING_TARGET_PCT:g} % of hover thrust{where}: worst "
                       f"{worst:.1f} %: {'met' if met else 'NOT met'}")
        total = [r for r in level if r["kind"] in ("motor", "propeller")]
        if total:
            survived = sum(r["survived"] if turbulence == "none" else r.get("held", False) for r in total)
            how = "" if turbulence == "none" else " (held aloft: no tilt check in turbulence)"
            out.append(f"- survival of total single-rotor loss{where}{how}: {survived}/{len(total)}: "
                       f"{'met' if survived == len(total) else 'NOT met'}")
        free = [r for r in level if not r["kind"]]
        if free:
            alarms = sum(r.get("alarms_before_fault", 0) for r in free)
            minutes = sum(r["duration_s"] for r in free if not r.get("error")) / 60.0
            enough = minutes >= FREE_MINUTES_TARGET[turbulence]
            out.append(f"- false alarms over {minutes:.0f} min of fault-free agile flight{where}: {alarms}: "
                       f"{'met' if alarms == 0 and enough else 'NOT met'}"
                       f"{'' if enough else f' (needs {FREE_MINUTES_TARGET[turbulence]:g} min)'}")
    return out


def stalled_note(rows: list[dict]) -> str:
    """The flights whose lockstep stalled, left out of every figure below; "" when none did."""
    names = [r["name"] for r in rows if r.get("stalled")]
    if not names:
        return ""
    return (f"{len(names)} of {len(rows)} flights stalled (the SITL's lockstep wait ran out and its FC flew its "
            f"failsafe; detection.csv column \"stalled\"), left out of the figures below: {', '.join(names)}\n\n")


def run_detection_campaign(out_dir: Path, kinds, speeds, escs, seed: int = 0, false_alarm_minutes: float = 0.0,
                           workers: int | None = None, rate_hz: float | None = None, engine: str = "local",
                           scheduler: str | None = None, link: LinkEmulation | None = None,
                           grid: WeatherGrid = WeatherGrid(), sweep: tuple[tuple[str, float], ...] = (),
                           lockstep_timeout_s: float = LOCKSTEP_TIMEOUT_S) -> Campaign:
    from sitl.plant.truth import load_truth

    out_dir = Path(out_dir).resolve()
    cases = detection_cases(kinds, speeds, escs, seed, false_alarm_minutes, grid, sweep)
    (out_dir / "scenarios").mkdir(parents=True, exist_ok=True)
    jobs = []
    for k, case in enumerate(cases):
        path = out_dir / "scenarios" / f"{case.name}.toml"
        path.write_text(case.scenario_toml())
        settings = () if case.detector_setting is None else (case.detector_setting,)
        jobs.append(FlightJob(str(path), out_dir / "flights" / case.name,
                              FlightOptions(seed=seed + k, rate_hz=rate_hz, link=link, fault_detector=settings,
                                            lockstep_timeout_s=lockstep_timeout_s)))
    af = load_airframe()
    rows = []
    batch = fly_all(jobs, workers, "detection", engine, scheduler)
    for case, job, metrics in zip(cases, jobs, batch.results):
        tlog, truth = job.out_dir / "flight.tlog", job.out_dir / "truth.npz"
        status = read_fault_status(tlog) if tlog.exists() else FaultStatusLog.empty()
        rows.append(result_row(case, metrics, status, load_truth(truth) if truth.exists() else None,
                               af.hover_thrust_per_rotor_n, stalled(FlightFiles(job.out_dir))))
    fields = list(dict.fromkeys(key for r in rows for key in r))
    with (out_dir / "detection.csv").open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=fields)
        writer.writeheader()
        writer.writerows(rows)
    summary = flights_note(link) + summary_markdown(rows)
    if len(sweep) > 1:
        from sitl.campaigns.tradeoff import draw_tradeoff, tradeoff_markdown

        summary += "\n" + tradeoff_markdown(draw_tradeoff(rows, out_dir / "tradeoff.png"))
    (out_dir / "detection.md").write_text(summary)
    return Campaign(summary, rows, batch)
