"""Lockstep speed of `m4-sitl serve` alone: `python -m benchmarks.lockstep`.

Runs `m4-sitl serve` in lockstep against a stand-in companion that answers every frame with
the hover thrust (open loop) and prints simulated seconds per wall second, and the SITL's CPU
per control step from its stop line (the figure other work on the machine stretches least).
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
import tempfile
import time

from sitl.standin_companion import StandInCompanion

_SITL_CPU = re.compile(r"CPU ([0-9.]+) s \(")       # m4-sitl serve's stop line


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.lockstep", description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=10.0, help="simulated seconds (default 10)")
    parser.add_argument("--period-ms", type=int, default=20, help="control period (default 20)")
    args = parser.parse_args(argv)
    companion = StandInCompanion(period_ms=args.period_ms)
    cmd = [sys.executable, "-m", "sitl.cli", "serve", "--mavlink", companion.url, "--duration", str(args.seconds)]
    with tempfile.TemporaryFile(mode="w+") as log:
        proc = subprocess.Popen(cmd, stderr=log)
        try:
            while companion.answered == 0 and proc.poll() is None:
                companion.poll()
            wall0 = time.monotonic()
            while proc.poll() is None:
                companion.poll()
            wall = time.monotonic() - wall0
        finally:
            proc.kill()
            companion.close()
        log.seek(0)
        cpu = _SITL_CPU.findall(log.read())
    steps = args.seconds * 1000 / args.period_ms
    sitl = f"; the SITL's CPU per step {1e3 * float(cpu[-1]) / steps:.2f} ms" if cpu else ""
    print(f"lockstep: {args.seconds:g} s simulated in {wall:.2f} s wall = {args.seconds / wall:.1f} "
          f"simulated s per wall s ({companion.answered} setpoints at {1000 / args.period_ms:g} Hz, "
          f"{len(companion.received)} messages received){sitl}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
