"""Delay and loss tolerance: scenarios flown behind an emulated link, one table.

    python -m benchmarks.link [--scenario NAME]... [--delay-ms D]... [--loss P]... [--seed S]

Flies every scenario (default: hover-rotor-loss, forward-flight-fault, fault-free) at every
delay each way (default 0, 10, 20, 30, 40, 50 ms) and loss both ways (default 0 and 0.2), in
lockstep with the link emulated in simulated time (sitl/links/emulation.py): the verdicts do not
depend on the machine's load, and the same seed gives the same table. Prints a Markdown table,
a row a flight: survived, altitude loss, max tilt after the fault (or over the flight), the
fault's detection (rotor and latency) or, without a fault, any false alarm, and the setpoint
lead the companion measured.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

from analysis.detection import CONFIRMED
from m4.toml_fields import ConfigError
from sitl import scenarios
from sitl.flights.flight_run import FlightError, FlightFiles, FlightOptions
from sitl.flights.fly import fly
from sitl.links.emulation import LinkEmulation
from sitl.flights.records import read_fault_status

DEFAULT_SCENARIOS = ("hover-rotor-loss", "forward-flight-fault", "fault-free")
DEFAULT_DELAYS_MS = (0.0, 10.0, 20.0, 30.0, 40.0, 50.0)
DEFAULT_LOSSES = (0.0, 0.2)
HEADER = ("| scenario | delay each way | loss | survived | altitude loss | max tilt | detection | setpoint lead |\n"
          "|---|---|---|---|---|---|---|---|")


def _detection(metrics: dict, flight_dir: Path) -> str:
    """The faults' detections; without a fault, the first confirmation if any (a false alarm)."""
    faults = metrics["faults"]
    if not faults:
        status = read_fault_status(FlightFiles(flight_dir).tlog)
        confirmed = np.flatnonzero(status.state == CONFIRMED)
        if not confirmed.size:
            return "no alarm"
        k = confirmed[0]
        return f"**false alarm**: rotor {int(status.rotor[k])} at {status.time_s[k]:.2f} s"
    parts = []
    for f in faults:
        if f.get("detected_at_s") is None:
            parts.append(f"rotor {f['rotor']} not found")
        else:
            parts.append(f"rotor {f['detected_rotor']} after {1000 * (f['detected_at_s'] - f['at_s']):.0f} ms")
    return ", ".join(parts)


def row(scenario: str, delay_ms: float, loss: float, metrics: dict, flight_dir: Path) -> str:
    tilt = metrics.get("max_tilt_deg_after_fault")
    lead = metrics.get("link", {}).get("setpoint_lead_ms")
    return (f"| {scenario} | {delay_ms:g} ms | {loss:g} | {'yes' if metrics['survived'] else '**no**'} | "
            f"{metrics['altitude_loss_m']:.2f} m | {'-' if tilt is None else f'{tilt:.0f} deg'} | "
            f"{_detection(metrics, flight_dir)} | {'-' if lead is None else f'{lead:.0f} ms'} |")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.link", description=__doc__.split("\n\n")[0])
    p.add_argument("--scenario", action="append", help="built-in name or scenario file (repeatable)")
    p.add_argument("--delay-ms", action="append", type=float, help="delay each way, ms (repeatable)")
    p.add_argument("--loss", action="append", type=float, help="share of datagrams lost each way (repeatable)")
    p.add_argument("--seed", type=int, default=0, help="noise and loss seed (default 0)")
    args = p.parse_args(argv)
    try:
        links = [LinkEmulation(delay_ms=d, loss=q) for d in args.delay_ms or DEFAULT_DELAYS_MS
                 for q in args.loss or DEFAULT_LOSSES]
        names = args.scenario or list(DEFAULT_SCENARIOS)
        for name in names:
            scenarios.scenario_path(name)
    except (ValueError, ConfigError) as e:
        print(f"link_bench: error: {e}", file=sys.stderr)
        return 2
    print(HEADER, flush=True)
    with tempfile.TemporaryDirectory(prefix="m4-link-bench-") as tmp:
        for name in names:
            for i, link in enumerate(links):
                out = Path(tmp) / f"{Path(name).stem}-{i}"
                try:
                    metrics = fly(name, out, FlightOptions(link=link, seed=args.seed), figures=False, progress=False)
                except (FlightError, ConfigError) as e:
                    print(f"| {name} | {link.delay_ms:g} ms | {link.loss:g} | did not fly: {e} | | | | |", flush=True)
                    continue
                print(row(name, link.delay_ms, link.loss, metrics, out), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
