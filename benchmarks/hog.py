"""The hover rotor loss on a busy computer: the companion at normal priority, then real-time.

    python -m benchmarks.hog [--hogs N]... [--rate-hz HZ]... [--scenario NAME] [--priority P]

While N CPU hogs (busy loops at normal priority; default one per core, then four per core)
run beside it, flies the scenario paced by the wall clock (the companion and the SITL as
`m4-sitl fly --realtime`) twice: the companion at normal priority, then with `[control]
realtime_priority = P` (SCHED_FIFO; default 40, the robot's, deploy/companion.toml). The SITL
stands for the flight controller, which on the robot is its own hardware that a busy companion
computer cannot slow: it runs in SCHED_FIFO (priority P + 5) in both flights. Needs the right to
use SCHED_FIFO (root, CAP_SYS_NICE, or an RLIMIT_RTPRIO of P + 5).

Prints a Markdown table, a row a flight: the hogs, survived, altitude loss, max tilt after the
fault, control rate achieved (mean over the flight; the worst second), steps over the control
period, link losses, NMPC solve time p50/p99, and the setpoint lead (the state is predicted
through it) p50/max.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from companion.config import DEFAULT_RATE_HZ, RATE_MAX_HZ, RATE_MIN_HZ
from m4.toml_fields import ConfigError
from sitl import scenarios
from sitl.flights.flight_run import FlightError, FlightOptions
from sitl.flights.fly import fly
from sitl.flights.records import read_feed

ROBOT_PRIORITY = 40           # deploy/companion.toml's [control] realtime_priority
SITL_ABOVE = 5                # the SITL (the FC) runs this far above the companion
HOG = "while True:\n    pass"


def _hogs(count: int) -> contextlib.ExitStack:
    """`count` busy-loop processes at normal priority, stopped when the stack closes."""
    stack = contextlib.ExitStack()
    for _ in range(count):
        hog = subprocess.Popen([sys.executable, "-c", HOG], stdin=subprocess.DEVNULL)
        stack.callback(hog.wait)
        stack.callback(hog.kill)
    return stack


def flight_row(hogs: int, rate_hz: float, label: str, metrics: dict, feed: dict[str, list[dict]]) -> str:
    nmpc = [p for p in feed.get("nmpc", []) if p.get("t_s") is not None]
    rates = [p["rate_hz"] for p in nmpc if p.get("rate_hz") is not None and p["t_s"] >= 1.0]   # whole seconds
    leads = [p["lead_ms"] for p in nmpc if p.get("lead_ms") is not None]
    overruns = nmpc[-1]["overruns"] if nmpc else 0
    link = [p for p in feed.get("link", []) if p.get("t_s") is not None and p["t_s"] < metrics["duration_s"]]
    losses = sum(1 for a, b in zip(link, link[1:]) if a["connected"] and not b["connected"])   # not the SITL's end
    n = metrics["nmpc"]
    mean_rate = len(nmpc) / metrics["duration_s"]
    cells = [str(hogs), f"{rate_hz:g} Hz", label, "yes" if metrics["survived"] else "**no**", f"{metrics['altitude_loss_m']:.2f} m",
             f"{metrics['max_tilt_deg_after_fault']:.1f} deg",
             f"{mean_rate:.0f} Hz ({min(rates):.0f})" if rates else f"{mean_rate:.0f} Hz",
             str(overruns), str(losses),
             f"{n['solve_ms_median']:.1f} / {n['solve_ms_p99']:.1f} ms" if n["solve_ms_median"] is not None else "-",
             f"{np.median(leads):.0f} / {max(leads):.0f} ms" if leads else "-"]
    return "| " + " | ".join(cells) + " |"


HEADER = ("| CPU hogs | control rate asked | companion | survived | altitude loss | max tilt | control rate (worst second) "
          "| steps over the period | link losses | solve p50 / p99 | setpoint lead p50 / max |\n"
          "|---|---|---|---|---|---|---|---|---|---|---|")


def run_bench(scenario: str, hogs: int, rate_hz: float, priority: int, out_dir: Path) -> Iterator[str]:
    """The two flights at `rate_hz` (normal priority, then SCHED_FIFO `priority`) beside `hogs` hogs: a
    table row each."""
    with _hogs(hogs):
        for label, companion_priority in (("normal priority", 0), (f"SCHED_FIFO {priority}", priority)):
            options = FlightOptions(realtime=True, rate_hz=rate_hz, companion_priority=companion_priority,
                                    sitl_priority=priority + SITL_ABOVE)
            folder = out_dir / f"{hogs}-hogs-{rate_hz:g}-hz-{label.replace(' ', '-')}"
            metrics = fly(scenario, folder, options, figures=False, progress=False)
            yield flight_row(hogs, rate_hz, label, metrics, read_feed(folder / "feed.jsonl"))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.hog", description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="hover-rotor-loss", help="built-in name or file (default hover-rotor-loss)")
    parser.add_argument("--hogs", type=int, action="append",
                        help="busy-loop processes beside the flights; repeat (default: one per core, then four)")
    parser.add_argument("--rate-hz", type=float, action="append",
                        help=f"the companion's control rate; repeat (default {DEFAULT_RATE_HZ:g})")
    parser.add_argument("--priority", type=int, default=ROBOT_PRIORITY,
                        help=f"the companion's real-time priority in the second flight (default {ROBOT_PRIORITY})")
    parser.add_argument("--out", type=Path, help="keep the flights' folders here (default: a temporary folder)")
    args = parser.parse_args(argv)
    cores = os.cpu_count() or 1
    loads = args.hogs or [cores, 4 * cores]
    rates = args.rate_hz or [DEFAULT_RATE_HZ]
    if not 1 <= args.priority <= 99 - SITL_ABOVE or min(loads) < 0 or not all(RATE_MIN_HZ <= r <= RATE_MAX_HZ for r in rates):
        print(f"python -m benchmarks.hog: error: --priority must be 1..{99 - SITL_ABOVE}, --hogs >= 0 and --rate-hz "
              f"{RATE_MIN_HZ:g}..{RATE_MAX_HZ:g}", file=sys.stderr)
        return 2
    try:
        name = scenarios.resolve(args.scenario).name
        print(f"{name}, paced by the wall clock, on {cores} cores; the SITL (the flight controller's own hardware "
              f"on the robot) at SCHED_FIFO {args.priority + SITL_ABOVE}\n")
        print(HEADER, flush=True)
        with tempfile.TemporaryDirectory() as tmp:
            for hogs in loads:
                for rate_hz in rates:
                    for row in run_bench(args.scenario, hogs, rate_hz, args.priority, args.out or Path(tmp)):
                        print(row, flush=True)
    except (FlightError, ConfigError) as e:
        print(f"python -m benchmarks.hog: error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
