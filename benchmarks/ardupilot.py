"""The same scenarios flown by the companion through ArduCopter and the M4 applet, and through
the project's flight controller, judged on the plant's truth alike.

    python -m benchmarks.ardupilot [--out DIR] [--scenario NAME]... [--speedup N] [--instance I] [--judge-only]

Each scenario is flown twice: `m4-sitl fly-ardupilot NAME --companion` (ArduCopter 4.6.3
SITL, the applet, the companion at 50 Hz on the wall clock from the handover on) and
`m4-sitl fly NAME` (the project's FC, lockstep). Writes DIR/ardupilot/NAME and DIR/project/NAME,
a figure DIR/NAME.png with both flights' altitude and tilt on the scenario's clock, and prints a
Markdown table, a row a flight: ground contact before the landing (when), altitude loss and
largest tilt after the first fault (the whole flight without one), the touchdown's vertical
speed, the fault the companion announced and how long after the plant's fault, and the
machine's load average when the flight through ArduCopter started (load.txt). `--judge-only`
judges the flights already in DIR without flying.
"""

from __future__ import annotations

import argparse
import json
import os
import re
from pathlib import Path

import numpy as np

from sitl import scenarios
from sitl.ardupilot.flight import ArduFlightOptions, fly_ardupilot
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


def announced(companion_log: Path, fault_physics_s: float) -> str:
    """The companion's first fault announcement and its time after the plant's fault (its log
    runs on ArduPilot's clock, which is the physics')."""
    found = re.search(r"t=([\d.]+) s: (thrust loss rotor \d)", companion_log.read_text())
    return "" if found is None else f"{found.group(2)} after {float(found.group(1)) - fault_physics_s:.2f} s"


def fly_both(name: str, out: Path, speedup: float, instance: int) -> None:
    scenario = scenarios.resolve(name)
    (out / "ardupilot" / name).mkdir(parents=True, exist_ok=True)
    (out / "ardupilot" / name / "load.txt").write_text(f"{os.getloadavg()[0]:.0f}\n")
    fly_ardupilot(ArduFlightOptions(scenario=scenario, out_dir=out / "ardupilot" / name, speedup=speedup,
                                    instance=instance, companion=True, scenario_file=scenarios.scenario_path(name)),
                  log=lambda _: None)
    fly(name, out / "project" / name, figures=False, progress=False)


def judge(name: str, out: Path) -> list[str]:
    """The two rows of one scenario, and its figure."""
    scenario = scenarios.resolve(name)
    ardu_dir, project_dir = out / "ardupilot" / name, out / "project" / name
    ardu, project = (json.loads((d / "metrics.json").read_text()) for d in (ardu_dir, project_dir))
    t0_s = ardu["scenario_t0_physics_s"]
    ardu_truth, project_truth = load_truth(ardu_dir / "truth.npz"), load_truth(project_dir / "truth.npz")
    fault = next(iter(project["faults"]), None)
    project_said = "" if fault is None or fault["detected_at_s"] is None else \
        f"thrust loss rotor {fault['detected_rotor']} after {fault['latency_s']:.2f} s"
    ardu_said = "" if not scenario.faults else announced(ardu_dir / "companion.log", t0_s + scenario.faults[0].at_s)
    figure(out / f"{name}.png", name, [("ArduCopter + M4 applet", ardu_truth, t0_s), ("project FC", project_truth, 0.0)],
           [f.at_s for f in scenario.faults])
    return [row("ArduCopter + applet", name, judged(ardu_truth, scenario, t0_s), ardu_said,
                (ardu_dir / "load.txt").read_text().strip()),
            row("project FC (lockstep)", name, judged(project_truth, scenario, 0.0), project_said, "-")]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, default=Path("out/ardupilot-table"))
    p.add_argument("--scenario", action="append", help=f"default: {', '.join(DEFAULT_SCENARIOS)}")
    p.add_argument("--speedup", type=float, default=10.0, help="arducopter --speedup until the handover")
    p.add_argument("--instance", type=int, default=6, help="arducopter -I")
    p.add_argument("--judge-only", action="store_true", help="judge the flights in --out without flying")
    args = p.parse_args()
    rows = []
    for name in args.scenario or DEFAULT_SCENARIOS:
        if not args.judge_only:
            fly_both(name, args.out, args.speedup, args.instance)
        rows += judge(name, args.out)
        print(*rows[-2:], sep="\n", flush=True)
    print("\n| scenario | flown by | ground contact before the landing | altitude loss (m) | tilt max (deg) | "
          "touchdown (m/s) | fault announced | load |")
    print("|---|---|---|---|---|---|---|---|")
    print("\n".join(rows))


if __name__ == "__main__":
    main()
