"""Speed of the whole loop (plant and companion, lockstep): simulated seconds per wall second.

    python -m benchmarks.fly [--scenario NAME] [--rate-hz HZ]... [--priority P] [--feed-rate-hz HZ] [--realtime]
                             [--companion-cpus LIST] [--sitl-cpus LIST] [--link-delay-ms MS] [--keep DIR]

flies the scenario once per control rate (default 50 Hz) without figures and prints, per rate:
- the real-time factor of the whole loop (wall clock: noisy on a shared machine);
- the CPU time (time.process_time) of each process per control step: the SITL's (plant,
  flight controller, MAVLink) and the companion's (telemetry in, controller, setpoint out,
  feed and flight log), from their own stop lines in sitl.log and companion.log;
- their sum against the period's budget for the target;
- the wall time per step, and the companion's part of it: from reading the telemetry frame
  to sending its setpoint (its mean, median and p99, from companion.log).
In lockstep the two processes take turns: the SITL steps while the companion waits for the
frame, the companion answers while the SITL waits for the setpoint (only the companion's
publishing and logging after the send overlap the SITL's step). So the wall time per step is
the SITL's step + the companion's answer + two hand-offs, and the target, at least 10x real
time at 50 Hz, needs them under 2 ms per 20 ms step. On a shared machine, `--priority P`
runs both processes in SCHED_FIFO at P (the right to do so is needed: root, or LimitRTPRIO): the
others' work then no longer stretches the wall-clock figure, which comes near an idle machine's.
The companion's feed records every topic at every step, as `m4-sitl fly` does; `--feed-rate-hz 20`
gives it the robot's default instead (each topic at what a viewer needs: fewer puts per step; the
NMPC figures then come from the solves the feed published). `--realtime` paces the flight by the
wall clock instead, as the robot flies: the SITL sends each stream at its own instant, the
companion wakes for what arrives and sleeps between; the CPU per step and the answer are then
the robot's (the real-time factor says only that it kept up: 1.0x). `--companion-cpus 1
--sitl-cpus 0` pins each process, every thread of it, to those CPUs (comma-separated), to
measure what the placement does (on the robot the FC is other hardware; here the SITL shares
the machine). `--link-delay-ms 50` puts 50 ms each way between the two (as `m4-sitl fly`'s
option): the companion then predicts the state through the setpoints in flight, as on the robot.
"""

from __future__ import annotations

import argparse
import os
import re
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

from m4.toml_fields import ConfigError
from sitl.cli_args import link_delay_ms
from sitl.flights.flight_run import FlightError, FlightFiles, FlightOptions
from sitl.flights.fly import fly
from sitl.links.emulation import LinkEmulation

TARGET_FACTOR = 10.0
_SITL_CPU = re.compile(r"CPU ([0-9.]+) s \(")
_COMPANION_CPU = re.compile(r"CPU ([0-9.]+) ms per step")
_COMPANION_ANSWER = re.compile(r"setpoint sent ([0-9.]+) ms on average")
_ANSWER_QUANTILES = re.compile(r"on average, median ([0-9.]+) ms, p99 ([0-9.]+) ms")


@dataclass(frozen=True)
class LoopCosts:
    """What the two processes of a flight said of their costs when they stopped."""
    sitl_cpu_s: float             # the SITL's loop, the whole flight
    companion_cpu_ms: float       # per control step
    answer_ms: float              # the companion's mean time from telemetry read to setpoint sent
    answer_quantiles_ms: tuple[float, float] | None    # its median and p99 (None: the companion does not say)


def loop_costs(files: FlightFiles) -> LoopCosts | None:
    """From the flight's sitl.log and companion.log (None: a figure is missing)."""
    found = [_last_match(pattern, path) for pattern, path in ((_SITL_CPU, files.sitl_log),
                                                              (_COMPANION_CPU, files.companion_log),
                                                              (_COMPANION_ANSWER, files.companion_log))]
    if None in found:
        return None
    quantiles = _ANSWER_QUANTILES.findall(files.companion_log.read_text(errors="replace"))
    return LoopCosts(*found, tuple(float(v) for v in quantiles[-1]) if quantiles else None)


def _last_match(pattern: re.Pattern, path: Path) -> float | None:
    found = pattern.findall(path.read_text(errors="replace")) if path.exists() else []
    return float(found[-1]) if found else None


def bench_line(scenario: str, rate_hz: float, out_dir: Path, priority: int = 0, feed_rate_hz: float = 0.0,
               realtime: bool = False, companion_cpus: frozenset[int] = frozenset(),
               sitl_cpus: frozenset[int] = frozenset(), link_delay_ms: float = 0.0) -> str:
    """Fly once at `rate_hz` into `out_dir` (both processes in SCHED_FIFO `priority`, 0: normal;
    the companion's feed at most `feed_rate_hz` per topic, 0: every step; paced by the wall clock
    with `realtime`; each process pinned to its CPUs, none: anywhere; `link_delay_ms` each way
    between them); the figures in one paragraph."""
    options = FlightOptions(rate_hz=rate_hz, companion_priority=priority, sitl_priority=priority,
                            feed_rate_hz=feed_rate_hz, realtime=realtime, companion_cpus=companion_cpus,
                            sitl_cpus=sitl_cpus, link=LinkEmulation(delay_ms=link_delay_ms) if link_delay_ms else None)
    m = fly(scenario, out_dir, options, figures=False, progress=False)
    costs = loop_costs(FlightFiles(out_dir))
    period_ms, factor, n = 1e3 / rate_hz, m["realtime_factor"], m["nmpc"]
    lines = [f"{m['scenario']} at {rate_hz:g} Hz ({m['duration_s']:g} s simulated, "
             f"{'paced by the wall clock' if realtime else 'lockstep'}"
             f"{f', SCHED_FIFO {priority}' if priority else ''}"
             f"{f', feed at most {feed_rate_hz:g} Hz a topic' if feed_rate_hz else ''}"
             f"{_placement('companion', companion_cpus)}{_placement('SITL', sitl_cpus)}"
             f"{f', link delay {link_delay_ms:g} ms each way' if link_delay_ms else ''}): "
             f"{factor:.1f}x real time; survived: {m['survived']}; "
             f"NMPC solve median {n['solve_ms_median']:.2f} ms, p99 {n['solve_ms_p99']:.1f} ms"]
    if costs is None:
        return "\n".join([*lines, "  CPU per step: not found in sitl.log / companion.log"])
    sitl_ms = 1e3 * costs.sitl_cpu_s / (m["duration_s"] * rate_hz)
    both_ms = sitl_ms + costs.companion_cpu_ms
    quantiles = "" if costs.answer_quantiles_ms is None else \
        " (median {:.2f} ms, p99 {:.2f} ms)".format(*costs.answer_quantiles_ms)
    if realtime:
        return "\n".join([*lines, f"  CPU per step: SITL {sitl_ms:.2f} ms, companion {costs.companion_cpu_ms:.2f} ms",
                           f"  the companion's answer (telemetry read to setpoint sent) {costs.answer_ms:.2f} ms"
                           f"{quantiles}"])
    lines += [f"  CPU per step: SITL {sitl_ms:.2f} ms + companion {costs.companion_cpu_ms:.2f} ms = {both_ms:.2f} ms "
              f"(budget for {TARGET_FACTOR:g}x: {period_ms / TARGET_FACTOR:.2f} ms)",
              f"  CPU per simulated second: SITL {sitl_ms * rate_hz / 1e3:.3f} s, companion "
              f"{costs.companion_cpu_ms * rate_hz / 1e3:.3f} s",
              f"  wall per step {period_ms / factor:.2f} ms, of which the companion's answer (telemetry read to "
              f"setpoint sent) {costs.answer_ms:.2f} ms{quantiles}; the rest is the SITL's step and the hand-offs (the "
              "companion's publishing after its send overlaps the SITL's step)"]
    return "\n".join(lines)


def _placement(who: str, cpus: frozenset[int]) -> str:
    return f", {who} on CPU {','.join(map(str, sorted(cpus)))}" if cpus else ""


def _cpus(option: str, text: str) -> frozenset[int]:
    """A comma-separated list of CPUs this process may use; ValueError naming `option` if not."""
    usable = os.sched_getaffinity(0)
    try:
        cpus = frozenset(int(part) for part in text.split(","))
    except ValueError:
        raise ValueError(f"{option} {text}: not a comma-separated list of CPU numbers") from None
    if not cpus <= usable:
        raise ValueError(f"{option} {text}: CPU {min(cpus - usable)} is not one this machine lets it use "
                         f"({','.join(map(str, sorted(usable)))})")
    return cpus


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.fly", description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="hover-rotor-loss", help="built-in name or file (default hover-rotor-loss)")
    parser.add_argument("--rate-hz", type=float, action="append", help="control rate; repeat (default 50)")
    parser.add_argument("--priority", type=int, default=0, metavar="P",
                        help="both processes in SCHED_FIFO at P, 1..99 (default 0: normal priority)")
    parser.add_argument("--feed-rate-hz", type=float, default=0.0, metavar="HZ",
                        help="the companion's [feed] max_rate_hz (default 0: every topic every step, as m4-sitl fly "
                             "records; 20: the robot's default)")
    parser.add_argument("--realtime", action="store_true",
                        help="paced by the wall clock, as the robot flies (default: lockstep, as fast as it goes)")
    parser.add_argument("--companion-cpus", metavar="LIST", default="",
                        help="pin the companion, every thread, to these CPUs, e.g. 1 (default: anywhere)")
    parser.add_argument("--sitl-cpus", metavar="LIST", default="",
                        help="pin the SITL, every thread, to these CPUs, e.g. 0 (default: anywhere)")
    parser.add_argument("--link-delay-ms", type=link_delay_ms, default=0.0, metavar="MS",
                        help="delay on the companion's link each way, as m4-sitl fly's (default 0)")
    parser.add_argument("--keep", type=Path, metavar="DIR", help="keep the flights' folders in DIR (default: "
                                                                 "a temporary folder)")
    args = parser.parse_args(argv)
    if not 0 <= args.priority <= 99:
        parser.error("--priority must be 0..99")
    if not 0 <= args.feed_rate_hz <= 100:
        parser.error("--feed-rate-hz must be 0..100")
    try:
        placement = [_cpus(option, text) if text else frozenset()
                     for option, text in (("--companion-cpus", args.companion_cpus), ("--sitl-cpus", args.sitl_cpus))]
    except ValueError as e:
        parser.error(str(e))
    with tempfile.TemporaryDirectory() as tmp:
        root = args.keep or Path(tmp)
        for rate in args.rate_hz or (50.0,):
            try:
                print(bench_line(args.scenario, rate, root / f"{rate:g}hz", args.priority, args.feed_rate_hz,
                                 args.realtime, *placement, args.link_delay_ms), flush=True)
            except (ConfigError, FlightError) as e:
                print(f"python -m benchmarks.fly: error: {e}", file=sys.stderr)
                return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
