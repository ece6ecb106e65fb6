"""The same scenarios flown by the companion through ArduCopter and the M4 applet, and through
the project's flight controller, judged on the plant's truth alike.

    python -m benchmarks.ardupilot [--out DIR] [--scenario NAME]... [--speedup N] [--instance I] [--priority P]
                                   [--project DIR] [--no-cover] [--judge-only]

Each scenario is flown twice: `m4-sitl fly-ardupilot NAME --companion` (ArduCopter 4.6.3
SITL, the applet, the companion at 50 Hz on the wall clock from the handover on) and
`m4-sitl fly NAME` (the project's FC, lockstep). Writes DIR/ardupilot/NAME and DIR/project/NAME,
a figure DIR/NAME.png with both flights' altitude and tilt on the scenario's clock, and prints a
Markdown table, a row a flight: ground contact before the landing (when), altitude loss and
largest tilt after the first fault (the whole flight without one), the touchdown's vertical
speed, the fault the companion announced and how long after the plant's fault, and the
machine's load average when the flight through ArduCopter started, and its SCHED_FIFO priority
(load.txt). `--priority P` flies the companion, arducopter and the physics in SCHED_FIFO at P from
the handover on (sitl/ardupilot/flight.py), so a busy machine does not starve the companion on
its wall clock. `--project DIR` takes the project's FC flights from DIR/NAME (as
`/work/flights/fly_all.sh` writes them) instead of flying them. `--no-cover` flies without the
applet's shortfall cover (the companion asks for none). `--judge-only` judges the flights
already in DIR without flying.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import tomllib
from pathlib import Path

import numpy as np

from sitl import scenarios
from sitl.ardupilot.flight import ArduFlightOptions, fly_ardupilot, free_instance
from sitl.flights.fly import fly
from sitl.plant.truth import Truth, load_truth

DEFAULT_SCENARIOS = ("hover-rotor-loss", "forward-flight-fault", "propeller-loss", "fault-free")


def judged(truth: Truth, scenario, t0_s: float) -> dict:
    """What the plant's truth says of one flight, on the scenario's clock (t0_s: its t = 0)."""
    t = truth.time_s - t0_s
    flown = (t >= 0.0) & (t <= scenario.duration_s)
    land_s = scenario.mission.land.at_s if scenario.mission is not None and scenario.mission.land is not None else None
    fault_s = min((f.at_s for f in scenario.faults), default=0.0)
    after = flown & (t >= fault_s) & ((t < land_s) if land_s is not None else True)
    tilt_deg = np.degrees(np.arccos(np.clip(np.cos(truth.euler_rad[:, 0]) * np.cos(truth.euler_rad[:, 1]), -1, 1)))
    altitude_m = -truth.pos_ned_m[:, 2]
    contact = flown & truth.on_ground
    first_contact_s = float(t[contact][0]) if contact.any() else None
    crashed = first_contact_s is not None and (land_s is None or first_contact_s < land_s)
    touchdown = None
    if first_contact_s is not None and not crashed:
        i = int(np.flatnonzero(contact)[0])
        touchdown = float(truth.vel_ned_m_s[max(i - 1, 0), 2])
    at_fault = int(np.flatnonzero(after)[0])
    return {"crashed_at_s": first_contact_s if crashed else None,
            "altitude_loss_m": float(altitude_m[at_fault] - altitude_m[after].min()),
            "tilt_max_deg": float(tilt_deg[after].max()), "touchdown_m_s": touchdown}


def row(system: str, name: str, j: dict, announced: str, load: str) -> str:
    crash = "no" if j["crashed_at_s"] is None else f"at {j['crashed_at_s']:.2f} s"
    touchdown = "" if j["touchdown_m_s"] is None else f"{j['touchdown_m_s']:.2f}"
    return (f"| {name} | {system} | {crash} | {j['altitude_loss_m']:.2f} | {j['tilt_max_deg']:.0f} | {touchdown} | "
            f"{announced} | {load} |")


def figure(path: Path, name: str, flights: list[tuple[str, Truth, float]], fault_s: list[float]) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 1, figsize=(8, 5.5), sharex=True)
    for label, truth, t0_s in flights:
        t = truth.time_s - t0_s
        keep = t >= -1.0
        tilt = np.degrees(np.arccos(np.clip(np.cos(truth.euler_rad[:, 0]) * np.cos(truth.euler_rad[:, 1]), -1, 1)))
        axes[0].plot(t[keep], -truth.pos_ned_m[keep, 2], label=label)
        axes[1].plot(t[keep], tilt[keep], label=label)
    for ax in axes:
        for f in fault_s:
            ax.axvline(f, color="red", ls="--", lw=0.8)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="upper right")
    axes[0].set_ylabel("altitude (m)")
    axes[1].set_ylabel("tilt (deg)")
    axes[1].set_xlabel("scenario time (s); the fault at the dashed line")
    axes[0].set_title(f"{name}: the companion through ArduCopter + the M4 applet, and through the project's FC",
                      fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def announced(companion_log: Path, t0_physics_s: float, fault_s: float | None) -> str:
    """The companion's first fault announcement and its time after the plant's fault (its log
    runs on ArduPilot's clock, which is the physics'); with no fault (fault_s None), a false one
    and when on the scenario's clock."""
    found = re.search(r"t=([\d.]+) s: (thrust loss rotor \d)", companion_log.read_text())
    if found is None:
        return ""
    t_s = float(found.group(1)) - t0_physics_s
    return f"{found.group(2)} after {t_s - fault_s:.2f} s" if fault_s is not None else \
        f"false: {found.group(2)} at {t_s:.1f} s"


def fly_ardupilot_one(name: str, out: Path, speedup: float, instance: int, priority: int, cover: bool) -> None:
    scenario = scenarios.resolve(name)
    (out / "ardupilot" / name).mkdir(parents=True, exist_ok=True)
    fifo = f", SCHED_FIFO {priority}" if priority else ""
    (out / "ardupilot" / name / "load.txt").write_text(f"{os.getloadavg()[0]:.1f}{fifo}\n")
    fly_ardupilot(ArduFlightOptions(scenario=scenario, out_dir=out / "ardupilot" / name, speedup=speedup,
                                    instance=instance, companion=True, scenario_file=scenarios.scenario_path(name),
                                    priority=priority, shortfall_cover=cover),
                  log=lambda _: None)


def judge(name: str, out: Path, project_root: Path) -> list[str]:
    """The two rows of one scenario (the project FC's flight from project_root/NAME), and its figure."""
    scenario = scenarios.resolve(name)
    ardu_dir, project_dir = out / "ardupilot" / name, project_root / name
    ardu, project = (json.loads((d / "metrics.json").read_text()) for d in (ardu_dir, project_dir))
    t0_s = ardu["scenario_t0_physics_s"]
    ardu_truth, project_truth = load_truth(ardu_dir / "truth.npz"), load_truth(project_dir / "truth.npz")
    fault = next(iter(project["faults"]), None)
    project_said = "" if fault is None or fault["detected_at_s"] is None else \
        f"thrust loss rotor {fault['detected_rotor']} after {fault['latency_s']:.2f} s"
    ardu_said = announced(ardu_dir / "companion.log", t0_s, scenario.faults[0].at_s if scenario.faults else None)
    figure(out / f"{name}.png", name, [("ArduCopter + M4 applet", ardu_truth, t0_s), ("project FC", project_truth, 0.0)],
           [f.at_s for f in scenario.faults])
    cover = tomllib.loads((ardu_dir / "companion.toml").read_text())["control"].get("shortfall_cover", True)
    return [row(f"ArduCopter + applet ({'rate feedback, cover' if cover else 'rate feedback, no cover'})", name, judged(ardu_truth, scenario, t0_s), ardu_said,
                (ardu_dir / "load.txt").read_text().strip()),
            row("project FC (lockstep)", name, judged(project_truth, scenario, 0.0), project_said, "-")]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, default=Path("out/ardupilot-table"))
    p.add_argument("--scenario", action="append", help=f"default: {', '.join(DEFAULT_SCENARIOS)}")
    p.add_argument("--speedup", type=float, default=10.0, help="arducopter --speedup until the handover")
    p.add_argument("--instance", type=int, help="arducopter -I (default: one whose ports are free)")
    p.add_argument("--priority", type=int, default=0, metavar="P",
                   help="SCHED_FIFO priority 1..99 from the handover on (default 0: normal)")
    p.add_argument("--project", type=Path, metavar="DIR",
                   help="the project FC's flights, DIR/NAME (default: fly them into --out/project)")
    p.add_argument("--no-cover", action="store_true", help="no shortfall cover in the applet")
    p.add_argument("--judge-only", action="store_true", help="judge the flights in --out without flying")
    args = p.parse_args()
    if not 0 <= args.priority <= 99:
        p.error(f"--priority {args.priority}: a SCHED_FIFO priority is 1..99 (0: normal)")
    project_root = args.project or args.out / "project"
    names = args.scenario or DEFAULT_SCENARIOS
    if args.project is not None and (missing := [n for n in names if not (args.project / n / "truth.npz").is_file()]):
        p.error(f"--project {args.project}: no flight of {', '.join(missing)} there (NAME/truth.npz)")
    instance = free_instance() if args.instance is None else args.instance
    rows = []
    for name in names:
        if not args.judge_only:
            fly_ardupilot_one(name, args.out, args.speedup, instance, args.priority, not args.no_cover)
            if args.project is None:
                fly(name, project_root / name, figures=False, progress=False)
        rows += judge(name, args.out, project_root)
        print(*rows[-2:], sep="\n", flush=True)
    print("\n| scenario | flown by | ground contact before the landing | altitude loss (m) | tilt max (deg) | "
          "touchdown (m/s) | fault announced | load |")
    print("|---|---|---|---|---|---|---|---|")
    print("\n".join(rows))


if __name__ == "__main__":
    main()
