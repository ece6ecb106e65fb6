"""Does a flood stall the simulated FC? `python -m benchmarks.flood` runs `m4-sitl serve
--realtime` in this process with a stand-in companion answering, floods the FC's port with
fuzzed frames from a subprocess (sitl.links.fuzz_flood), and measures, during the flood, the telemetry
rate the companion receives, the longest wall-clock gap between two of its ATTITUDE
messages and how many setpoints the FC accepted from the real companion; and the same rates
over the QUIET_S just before the flood, on the same machine at the same load, to measure the
flood's share against."""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from dataclasses import dataclass

from m4.mavlink import mavlink
from m4.scenario import Scenario
from sitl.serve import ServeOptions
from sitl.standin_companion import StandInCompanion, served


QUIET_S = 1.0


@dataclass(frozen=True)
class FloodFigures:
    frames: int
    flood_s: float
    attitude_hz: float          # ATTITUDE messages received per wall second during the flood (100 Hz asked)
    longest_gap_s: float        # longest wall-clock gap between two ATTITUDE arrivals
    setpoints_accepted: int     # from the stand-in companion, during the flood
    refused_foreign: int
    garbled: int
    quiet_attitude_hz: float    # the same over the QUIET_S before the flood
    quiet_setpoints_hz: float   # setpoints accepted per wall second over the QUIET_S before the flood

    @property
    def setpoints_hz(self) -> float:
        return self.setpoints_accepted / self.flood_s

    def __str__(self) -> str:
        return (f"flood of {self.frames} fuzzed frames in {self.flood_s:.1f} s ({self.frames / self.flood_s:.0f}/s): "
                f"ATTITUDE at {self.attitude_hz:.1f} Hz (100 Hz asked; {self.quiet_attitude_hz:.1f} Hz just before), "
                f"longest gap {1000 * self.longest_gap_s:.0f} ms; {self.setpoints_accepted} companion setpoints "
                f"accepted meanwhile ({self.setpoints_hz:.1f}/s; {self.quiet_setpoints_hz:.1f}/s just before); "
                f"{self.refused_foreign} messages refused as foreign, {self.garbled} garbled packets")


class _Timed(StandInCompanion):
    """A stand-in that notes the wall-clock arrival of each ATTITUDE."""

    def __init__(self):
        super().__init__()
        self.attitude_at: list[float] = []

    def poll(self, timeout_s: float = 0.05) -> None:
        n = len(self.received)
        super().poll(timeout_s)
        now = time.monotonic()
        self.attitude_at += [now for msg in self.received[n:] if msg.get_msgId() == mavlink.MAVLINK_MSG_ID_ATTITUDE]


def measure(rate_hz: float, count: int, seed: int = 0) -> FloodFigures:
    companion = _Timed()
    with served(companion, ServeOptions(scenario=Scenario(name="hover", duration_s=3600.0), realtime=True)) as server:
        companion.wait_for("M4_THRUSTER_STATUS", lambda s: s.time_boot_ms >= 500)
        fc, link = server.vehicle.fc, server.links[0]
        quiet_start, quiet_accepted = time.monotonic(), fc.counters.setpoints_accepted
        time.sleep(QUIET_S)
        quiet_s = time.monotonic() - quiet_start
        quiet_setpoints_hz = (fc.counters.setpoints_accepted - quiet_accepted) / quiet_s
        quiet_attitude_hz = sum(quiet_start <= t for t in companion.attitude_at) / quiet_s
        flooder = subprocess.Popen([sys.executable, "-m", "sitl.links.fuzz_flood", "--to", f"127.0.0.1:{link.local_port}",
                                    "--rate", str(rate_hz), "--count", str(count), "--seed", str(seed)],
                                   stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        flooder.stdout.readline()                   # "flood: sending", once its frames are made
        start, accepted = time.monotonic(), fc.counters.setpoints_accepted
        flooder.wait()
        end = time.monotonic()
        arrivals = [t for t in companion.attitude_at if start <= t <= end]
        gaps = [b - a for a, b in zip(arrivals, arrivals[1:])]
        return FloodFigures(frames=count, flood_s=end - start, attitude_hz=len(arrivals) / (end - start),
                            longest_gap_s=max(gaps, default=end - start),
                            setpoints_accepted=fc.counters.setpoints_accepted - accepted,
                            refused_foreign=fc.counters.refused_foreign,
                            garbled=link.bad_packets - link.signing_counters().rejected,
                            quiet_attitude_hz=quiet_attitude_hz, quiet_setpoints_hz=quiet_setpoints_hz)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.flood", description=__doc__.splitlines()[0])
    p.add_argument("--rate", type=float, default=10_000.0, help="frames per second (default 10000)")
    p.add_argument("--count", type=int, default=100_000, help="frames to send (default 100000)")
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)
    print(measure(args.rate, args.count, args.seed))
    return 0


if __name__ == "__main__":
    sys.exit(main())
