"""Speed of the whole loop (plant and companion, lockstep): simulated seconds per wall second.

    python -m sitl.fly_bench [--scenario NAME] [--rate-hz HZ]... [--priority P] [--keep DIR]

flies the scenario once per control rate (default 50 Hz) without figures and prints, per rate:
- the real-time factor of the whole loop (wall clock: noisy on a shared machine);
- the CPU time (time.process_time) of each process per control step: the SITL's (plant,
  flight controller, MAVLink) and the companion's (telemetry in, controller, setpoint out,
  feed and flight log), from their own stop lines in sitl.log and companion.log;
- their sum against the period's budget for the target, and the wall time per step left
  over: the hand-offs between the two processes (and, under load, waiting for a core).
In lockstep the two processes take turns, so the loop runs at best period / (SITL CPU +
companion CPU + hand-offs) times real time. The target: at least 10x real time at 50 Hz,
i.e. both sides together under 2 ms of CPU per 20 ms step. On a shared machine, `--priority P`
runs both processes in SCHED_FIFO at P (the right to do so is needed: root, or LimitRTPRIO): the
others' work then no longer stretches the wall-clock figure, which comes near an idle machine's.
"""

from __future__ import annotations

import argparse
import re
import sys
import tempfile
from pathlib import Path

from m4.toml_fields import ConfigError
from sitl.flight_run import FlightError, FlightFiles, FlightOptions
from sitl.fly import fly

TARGET_FACTOR = 10.0
_SITL_CPU = re.compile(r"CPU ([0-9.]+) s \(")
_COMPANION_CPU = re.compile(r"CPU ([0-9.]+) ms per step")


def _last_match(pattern: re.Pattern, path: Path) -> float | None:
    found = pattern.findall(path.read_text(errors="replace")) if path.exists() else []
    return float(found[-1]) if found else None


def bench_line(scenario: str, rate_hz: float, out_dir: Path, priority: int = 0) -> str:
    """Fly once at `rate_hz` into `out_dir` (both processes in SCHED_FIFO `priority`, 0: normal);
    the figures in one paragraph."""
    options = FlightOptions(rate_hz=rate_hz, companion_priority=priority, sitl_priority=priority)
    m = fly(scenario, out_dir, options, figures=False, progress=False)
    files = FlightFiles(out_dir)
    steps = m["duration_s"] * rate_hz
    sitl_cpu_s = _last_match(_SITL_CPU, files.sitl_log)
    companion_ms = _last_match(_COMPANION_CPU, files.companion_log)
    period_ms = 1e3 / rate_hz
    factor = m["realtime_factor"]
    n = m["nmpc"]
    lines = [f"{m['scenario']} at {rate_hz:g} Hz ({m['duration_s']:g} s simulated, lockstep"
             f"{f', SCHED_FIFO {priority}' if priority else ''}): "
             f"{factor:.1f}x real time; survived: {m['survived']}; "
             f"NMPC solve median {n['solve_ms_median']:.2f} ms, p99 {n['solve_ms_p99']:.1f} ms"]
    if sitl_cpu_s is None or companion_ms is None:
        lines.append("  CPU per step: not found in sitl.log / companion.log")
        return "\n".join(lines)
    sitl_ms = 1e3 * sitl_cpu_s / steps
    both_ms = sitl_ms + companion_ms
    wall_ms = period_ms / factor
    budget_ms = period_ms / TARGET_FACTOR
    lines += [f"  CPU per step: SITL {sitl_ms:.2f} ms + companion {companion_ms:.2f} ms = {both_ms:.2f} ms "
              f"(budget for {TARGET_FACTOR:g}x: {budget_ms:.2f} ms; CPU-bound limit {period_ms / both_ms:.1f}x)",
              f"  CPU per simulated second: SITL {sitl_ms * rate_hz / 1e3:.3f} s, companion "
              f"{companion_ms * rate_hz / 1e3:.3f} s",
              f"  wall per step {wall_ms:.2f} ms: {max(wall_ms - both_ms, 0.0):.2f} ms beyond both sides' CPU "
              "(hand-offs; waiting for a core under load)"]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m sitl.fly_bench", description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="hover-rotor-loss", help="built-in name or file (default hover-rotor-loss)")
    parser.add_argument("--rate-hz", type=float, action="append", help="control rate; repeat (default 50)")
    parser.add_argument("--priority", type=int, default=0, metavar="P",
                        help="both processes in SCHED_FIFO at P, 1..99 (default 0: normal priority)")
    parser.add_argument("--keep", type=Path, metavar="DIR", help="keep the flights' folders in DIR (default: "
                                                                 "a temporary folder)")
    args = parser.parse_args(argv)
    if not 0 <= args.priority <= 99:
        parser.error("--priority must be 0..99")
    with tempfile.TemporaryDirectory() as tmp:
        root = args.keep or Path(tmp)
        for rate in args.rate_hz or (50.0,):
            try:
                print(bench_line(args.scenario, rate, root / f"{rate:g}hz", args.priority), flush=True)
            except (ConfigError, FlightError) as e:
                print(f"python -m sitl.fly_bench: error: {e}", file=sys.stderr)
                return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
