"""The SITL's vehicle alone on a recorded flight: `python -m benchmarks.replay FLIGHT_DIR`.

Replays what the companion sent in a lockstep flight of `m4-sitl fly` (its flight.tlog) into
the vehicle (plant and flight controller, sitl/vehicle.py) in this process, each message at
the instant of the frame it followed, with no sockets, no MAVLink packing and no companion.
Prints the vehicle's CPU per control step (the least of `--repeat` runs: the figure the
machine's load stretches least) and whether the replayed truth equals the flight's truth.npz
bit for bit. The SITL is deterministic, so a change to the plant or the flight controller
that keeps every number gives `identical`; one that moves the flight shows by how much, for
the same companion's commands (open loop: the companion would have answered the moved
flight otherwise).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from m4.airframe import load_airframe
from m4.mavlink import COMPANION_COMPONENT_ID, DIALECT, mavlink, mavutil
from m4.scenario import load_scenario
from m4.toml_fields import ConfigError
from sitl.plant.truth import TruthRecorder, load_truth, truth_differences
from sitl.vehicle import Vehicle


def companion_steps(tlog_path: Path) -> list[tuple[int, list]]:
    """[(frame instant ms, the companion's messages that followed that frame)], in order (a tlog
    cut short, as a killed flight leaves it, is read up to its last whole packet)."""
    conn = mavutil.mavlink_connection(str(tlog_path), dialect=DIALECT)
    steps, frame_ms, following = [], 0, []
    try:
        while (msg := conn.recv_match()) is not None:
            if msg.get_type() == "BAD_DATA":
                continue
            if msg.get_srcComponent() == COMPANION_COMPONENT_ID:
                following.append(msg)
            elif msg.get_msgId() == mavlink.MAVLINK_MSG_ID_M4_THRUSTER_STATUS and msg.time_boot_ms != frame_ms:
                steps.append((frame_ms, following))
                frame_ms, following = msg.time_boot_ms, []
    finally:
        conn.close()
    steps.append((frame_ms, following))
    return steps


def replay(flight: Path, steps: list[tuple[int, list]], seed: int) -> tuple[float, TruthRecorder]:
    """One replay: (CPU seconds of the vehicle's loop, its truth)."""
    scenario = load_scenario(flight / "scenario.toml")
    vehicle = Vehicle(scenario, load_airframe(), seed, lockstep=True)
    truth = TruthRecorder()
    vehicle.observers.append(truth.observe)
    def discard(msgs, link=None):
        return None
    vehicle.start(discard)
    cpu0 = time.process_time()
    for t_ms, msgs in steps:
        if vehicle.now_ms < t_ms:
            vehicle.advance_to(t_ms, discard, frame=True)
        if msgs:
            vehicle.handle(msgs, discard)
    vehicle.advance_to(round(scenario.duration_s * 1000), discard, frame=True)
    return time.process_time() - cpu0, truth


def truth_difference(recorded: Path, replayed: TruthRecorder) -> str:
    """'identical', or the arrays that differ with the largest difference of each."""
    differ = [f"{name} (shape)" if worst is None else f"{name} (by up to {worst:.1e})"
              for name, worst in truth_differences(load_truth(recorded), replayed.truth()).items()]
    return "identical" if not differ else "DIFFERENT: " + ", ".join(differ)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.replay", description=__doc__.splitlines()[0])
    parser.add_argument("flight", type=Path, help="a folder of `m4-sitl fly` (flight.tlog, scenario.toml, truth.npz)")
    parser.add_argument("--repeat", type=int, default=3, help="runs; the least CPU is printed (default 3)")
    parser.add_argument("--seed", type=int, default=0, help="the flight's --seed (default 0, as m4-sitl fly's)")
    args = parser.parse_args(argv)
    missing = [name for name in ("flight.tlog", "scenario.toml", "truth.npz") if not (args.flight / name).is_file()]
    if missing:
        parser.error(f"{args.flight} is not a flight folder of m4-sitl fly: no {', '.join(missing)}")
    if args.repeat < 1:
        parser.error("--repeat must be at least 1")
    steps = companion_steps(args.flight / "flight.tlog")
    try:
        runs = [replay(args.flight, steps, args.seed) for _ in range(args.repeat)]
    except ConfigError as e:
        parser.error(f"{args.flight / 'scenario.toml'}: {e}")
    cpu_s = min(cpu for cpu, _ in runs)
    print(f"{args.flight.name}: the vehicle (plant and FC, no MAVLink) {1e3 * cpu_s / len(steps):.3f} ms of CPU "
          f"per control step ({len(steps)} steps, least of {args.repeat}); truth against the flight's: "
          f"{truth_difference(args.flight / 'truth.npz', runs[0][1])}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
