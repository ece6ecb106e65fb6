"""Speed of the whole loop (plant and companion, lockstep): simulated seconds per wall second.

    python -m sitl.fly_bench [--scenario NAME] [--rate-hz HZ]...

flies the scenario once per control rate (default 10 Hz, the paper's, and 50 Hz) without
figures and prints the real-time factor beside the NMPC's solve times. The target: at least
5x real time at 10 Hz.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

from sitl.flight_run import FlightOptions
from sitl.fly import fly


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m sitl.fly_bench", description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="hover-rotor-loss", help="built-in name or file (default hover-rotor-loss)")
    parser.add_argument("--rate-hz", type=float, action="append", help="control rate; repeat (default 10 and 50)")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        for rate in args.rate_hz or (10.0, 50.0):
            m = fly(args.scenario, Path(tmp) / f"{rate:g}", FlightOptions(rate_hz=rate), figures=False, progress=False)
            n = m["nmpc"]
            print(f"{m['scenario']} at {rate:g} Hz: {m['realtime_factor']:.1f}x real time (lockstep, "
                  f"{m['duration_s']:g} s simulated); NMPC solve median {n['solve_ms_median']:.1f} ms, "
                  f"p99 {n['solve_ms_p99']:.1f} ms; survived: {m['survived']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
