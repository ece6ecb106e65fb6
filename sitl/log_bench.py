"""Does the companion's flight log slow its control loop? The loop's step time with and without it.

    python -m sitl.log_bench [--scenario NAME] [--seconds S] [--repeats N]

Flies the scenario against `m4-sitl serve` (lockstep, a subprocess) with the companion's app
in this process, alternately with the flight log on and off, and times every control step
(telemetry in, NMPC, setpoint and fault status out, the log's share included). Prints the
median, p99 and max step time of each.
"""

from __future__ import annotations

import argparse
import dataclasses
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from companion.app import close_app, open_app
from companion.config import LogSettings, parse_config
from sitl import scenarios


def step_times_ms(scenario: str, seconds: float, log_dir: Path | None) -> np.ndarray:
    config = parse_config({"link": {"fc_url": "udpin:127.0.0.1:0"}}, "bench")
    config = dataclasses.replace(config, mission=scenarios.resolve(scenario).mission,
                                 log=LogSettings(enabled=log_dir is not None, dir=log_dir or Path(".")))
    app = open_app(config)
    times: list[float] = []
    answer = app._answer

    def timed(*args):
        start = time.perf_counter()
        answer(*args)
        times.append((time.perf_counter() - start) * 1e3)
    app._answer = timed
    thread = threading.Thread(target=app.run, daemon=True)
    thread.start()
    try:
        subprocess.run([sys.executable, "-m", "sitl.cli", "serve", "--scenario", scenario, "--duration", f"{seconds:g}",
                        "--mavlink", f"udpout:127.0.0.1:{app.fc.link.local_port}"], capture_output=True, check=True)
    finally:
        app.stop()
        thread.join(5.0)
        close_app(app)
    return np.array(times[5:])          # the first steps build the warm start


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m sitl.log_bench", description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="hover-rotor-loss")
    parser.add_argument("--seconds", type=float, default=8.0)
    parser.add_argument("--repeats", type=int, default=2)
    args = parser.parse_args(argv)
    runs: dict[str, list[np.ndarray]] = {"log on": [], "log off": []}
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(args.repeats):
            runs["log on"].append(step_times_ms(args.scenario, args.seconds, Path(tmp) / str(i)))
            runs["log off"].append(step_times_ms(args.scenario, args.seconds, None))
    for label, parts in runs.items():
        t = np.concatenate(parts)
        print(f"{label}: {len(t)} control steps of {args.scenario}, step time median {np.median(t):.2f} ms, "
              f"p99 {np.percentile(t, 99):.2f} ms, max {t.max():.2f} ms")
    return 0


if __name__ == "__main__":
    sys.exit(main())
