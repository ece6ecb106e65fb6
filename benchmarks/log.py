"""Does the companion's flight log slow its control loop? The loop's step time with and without it.

    python -m benchmarks.log [--scenario NAME] [--seconds S] [--repeats N]

Flies the scenario against `m4-sitl serve` (lockstep, a subprocess) with the companion's app
in this process, alternately with the flight log on and off, and times every control step's
answer (telemetry in, NMPC, setpoint and fault status out, the log's queueing included).
Prints, for each: the answer's wall time (median, p99, max: what the loop's timing feels,
noisy under load), the loop thread's CPU time per answer (median: robust to load), the whole
process's CPU time per control step (every thread, the log's packing and writing included),
and the answers held up more than WAIT_MS beyond their own CPU time (waiting for the GIL or a
core). With the log on, also the log's two costs, each where it runs: the loop's pack per poll
(`FlightLog.pack`, its CPU time: the records made at the end of each poll, after the send, on
the loop's thread) and the writer thread's CPU time per batch (the write alone: how long it
can keep the GIL from the loop, a write releases it; the cause of held-up answers that load
on the machine cannot fake).
"""

from __future__ import annotations

import argparse
import dataclasses
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from companion.app import close_app, open_app
from companion.config import LogSettings, parse_config
from sitl import scenarios

WARM_START_STEPS = 5
WAIT_MS = 1.0


@dataclass
class StepTimes:
    wall_ms: list[float] = field(default_factory=list)      # each step's wall time
    cpu_ms: list[float] = field(default_factory=list)       # each step's CPU time in the loop's thread
    process_cpu_ms: float = 0.0                             # the process's CPU time over the flight
    pack_cpu_ms: list[float] = field(default_factory=list)  # the loop's pack of the log's records, each poll
    writer_batch_cpu_ms: list[float] = field(default_factory=list)   # the log writer's, each batch

    def __add__(self, other: StepTimes) -> StepTimes:
        return StepTimes(self.wall_ms + other.wall_ms, self.cpu_ms + other.cpu_ms,
                         self.process_cpu_ms + other.process_cpu_ms, self.pack_cpu_ms + other.pack_cpu_ms,
                         self.writer_batch_cpu_ms + other.writer_batch_cpu_ms)


def _cpu_timed(fn, into: list[float]):
    """fn, its calling thread's CPU time (ms) appended to `into` at each call."""
    def timed(*args):
        start_cpu = time.thread_time()
        result = fn(*args)
        into.append((time.thread_time() - start_cpu) * 1e3)
        return result
    return timed


def step_times(scenario: str, seconds: float, log_dir: Path | None) -> StepTimes:
    config = parse_config({"link": {"fc_url": "udpin:127.0.0.1:0", "signing": False}}, "bench")   # as the SITL below
    config = dataclasses.replace(config, mission=scenarios.resolve(scenario).mission,
                                 log=LogSettings(enabled=log_dir is not None, dir=log_dir or Path(".")))
    app = open_app(config)
    times = StepTimes()
    answer = app._answer

    def timed(*args):
        start, start_cpu = time.perf_counter(), time.thread_time()
        answer(*args)
        times.cpu_ms.append((time.thread_time() - start_cpu) * 1e3)
        times.wall_ms.append((time.perf_counter() - start) * 1e3)
    app._answer = timed
    app.flight_log.pack = _cpu_timed(app.flight_log.pack, times.pack_cpu_ms)
    app.flight_log._drain = _cpu_timed(app.flight_log._drain, times.writer_batch_cpu_ms)
    thread = threading.Thread(target=app.run, daemon=True)
    cpu_start = time.process_time()
    thread.start()
    try:
        subprocess.run([sys.executable, "-m", "sitl.cli", "serve", "--scenario", scenario, "--duration", f"{seconds:g}",
                        "--mavlink", f"udpout:127.0.0.1:{app.fc.link.local_port}"], capture_output=True, check=True)
    finally:
        app.stop()
        thread.join(5.0)
        del app.flight_log.pack         # the loop's polls only: the close packs what is left on this thread
        close_app(app)                  # the log's writer flushes and ends here: its CPU counts
    times.process_cpu_ms = (time.process_time() - cpu_start) * 1e3
    skip = WARM_START_STEPS             # the first steps build the warm start
    return StepTimes(times.wall_ms[skip:], times.cpu_ms[skip:], times.process_cpu_ms, times.pack_cpu_ms,
                     times.writer_batch_cpu_ms)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.log", description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="hover-rotor-loss")
    parser.add_argument("--seconds", type=float, default=8.0)
    parser.add_argument("--repeats", type=int, default=2)
    args = parser.parse_args(argv)
    runs = {"log on": StepTimes(), "log off": StepTimes()}
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(args.repeats):
            runs["log on"] += step_times(args.scenario, args.seconds, Path(tmp) / str(i))
            runs["log off"] += step_times(args.scenario, args.seconds, None)
    for label, r in runs.items():
        wall, steps = np.array(r.wall_ms), len(r.wall_ms) + WARM_START_STEPS * args.repeats
        held = int(np.count_nonzero(wall - np.array(r.cpu_ms) > WAIT_MS))
        print(f"{label}: {len(wall)} control steps of {args.scenario}: wall time median {np.median(wall):.2f} ms, "
              f"p99 {np.percentile(wall, 99):.2f} ms, max {wall.max():.2f} ms; CPU time median "
              f"{np.median(r.cpu_ms):.2f} ms (the loop's thread, the answer), {r.process_cpu_ms / steps:.2f} ms per "
              f"step (the whole process); {held} steps held up over {WAIT_MS:g} ms beyond their CPU time")
        if r.writer_batch_cpu_ms:
            pack, batch = np.array(r.pack_cpu_ms), np.array(r.writer_batch_cpu_ms)
            print(f"  the loop's pack per poll (after the send): {len(pack)} polls, CPU time median "
                  f"{np.median(pack):.3f} ms, p99 {np.percentile(pack, 99):.3f} ms, max {pack.max():.2f} ms")
            print(f"  the log's writer: {len(batch)} batches, CPU time per batch (the write alone) median "
                  f"{np.median(batch):.2f} ms, p99 {np.percentile(batch, 99):.2f} ms, max {batch.max():.2f} ms")
    return 0


if __name__ == "__main__":
    sys.exit(main())
