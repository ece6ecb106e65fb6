"""The frame's read before the answer, on a recorded flight: `python -m benchmarks.frame_read FLIGHT_DIR`.

FLIGHT_DIR is what `m4-sitl fly SCENARIO --out DIR` leaves (flight.tlog; mavlink.key when the
flight was signed). The flight controller's packets between two of the companion's are taken
for one telemetry datagram (in lockstep they are one; a HEARTBEAT, STATUSTEXT or ack the FC
sends on its own between two answers counts in the next frame's); each is read as the companion reads it before its control step:
the datagram decoded (signatures checked: `MavlinkLink.parse`), the telemetry's samples taken
(`TelemetryAssembler.add`), then the snapshot and the ROM state (`rom_state`). Prints the median
of each part per datagram, warm (datagram after datagram) and cold (the caches flushed before
each datagram by a pass over a 32 MB array, as the SITL's step and the companion's own work
after its send flush them in flight, where the parts take about as long as this cold figure),
the least of `--repeat` runs: the figure the machine's load stretches least.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

from companion.core.com_offset import ComOffset
from companion.telemetry import TelemetryAssembler, rom_state
from m4.airframe import load_airframe
from m4.mavlink import COMPANION_COMPONENT_ID, mavlink
from m4.mavlink.link import MavlinkLink
from m4.mavlink.signing import SIGNATURE_BYTES, load_key
from m4.mavlink.tlog import TLOG_TIME

_SIGNED_TAIL = 2 + 1 + SIGNATURE_BYTES + 6         # CRC, link id, signature, timestamp
PARTS = ("read", "samples", "snapshot and ROM state")


class _Reader(MavlinkLink):
    """A link that only parses (the datagrams come from the tlog, not a socket)."""

    def write(self, packet: bytes) -> None:
        raise AssertionError("the benchmark sends nothing")


def telemetry_datagrams(tlog_path: Path) -> list[list[bytes]]:
    """The flight controller's packets between two of the companion's, each run: the datagrams
    the companion read (MAVLink 2 only, as the SITL sends; a tlog cut short is read up to its
    last whole packet)."""
    data, at, datagrams, run = tlog_path.read_bytes(), 0, [], []
    while at + TLOG_TIME.size + mavlink.HEADER_LEN_V2 <= len(data):
        start = at + TLOG_TIME.size
        if data[start] != mavlink.PROTOCOL_MARKER_V2:
            raise SystemExit(f"{tlog_path}: not a MAVLink 2 packet at byte {start}")
        end = start + mavlink.HEADER_LEN_V2 + data[start + 1] + \
            (_SIGNED_TAIL if data[start + 2] & mavlink.MAVLINK_IFLAG_SIGNED else 2)
        if end > len(data):
            break                       # cut short, as a killed flight leaves it: read up to its last whole packet
        if data[start + 6] == COMPANION_COMPONENT_ID:
            if run:
                datagrams.append(run)
            run = []
        else:
            run.append(data[start:end])
        at = end
    return datagrams


def read_once(datagrams: list[bytes], key: bytes | None, cold: bool) -> list[list[float]]:
    """Each part's time per datagram (s), [[read, samples, snapshot and ROM state], ...]."""
    link = _Reader(1, COMPANION_COMPONENT_ID, None, key, 0)
    if key is not None:       # the recorded timestamps are older than a new stream may start: accept them
        link.mav.signing.stream_timestamps.update({(d[-13], d[5], d[6]): 0 for d in datagrams})
    telemetry, com = TelemetryAssembler(), ComOffset(load_airframe())
    flush, out = (np.ones(4_000_000) if cold else None), []
    for i, datagram in enumerate(datagrams):
        if flush is not None:
            flush.sum()
        t0 = time.perf_counter()
        msgs = link.parse(datagram, None)
        t1 = time.perf_counter()
        for msg in msgs:
            telemetry.add(msg, i * 0.02)
        t2 = time.perf_counter()
        snap = telemetry.snapshot()
        if snap is not None:
            rom_state(snap, com)
        out.append([t1 - t0, t2 - t1, time.perf_counter() - t2])
    if link.bad_packets:
        raise SystemExit(f"{link.bad_packets} packets refused: a key other than the flight's?")
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.frame_read", description=__doc__.splitlines()[0])
    parser.add_argument("flight_dir", type=Path, help="a directory of `m4-sitl fly --out` (flight.tlog, mavlink.key)")
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args(argv)
    if args.repeat < 1:
        parser.error(f"--repeat must be at least 1, got {args.repeat}")
    tlog, key_path = args.flight_dir / "flight.tlog", args.flight_dir / "mavlink.key"
    if not tlog.is_file():
        print(f"{tlog}: no such file (fly one: m4-sitl fly hover-rotor-loss --out DIR)", file=sys.stderr)
        return 2
    key = load_key(key_path) if key_path.is_file() else None
    runs_of_packets = telemetry_datagrams(tlog)
    datagrams = [b"".join(packets) for packets in runs_of_packets]
    print(f"{len(datagrams)} telemetry datagrams ({'signed' if key else 'unsigned'}), median "
          f"{statistics.median(map(len, runs_of_packets)):.0f} packets each; median per datagram, least of "
          f"{args.repeat} runs:")
    for cold in (False, True):
        runs = [np.median(np.array(read_once(datagrams, key, cold)), axis=0) for _ in range(args.repeat)]
        best = np.min(runs, axis=0) * 1e3
        figures = ", ".join(f"{name} {ms:.3f} ms" for name, ms in zip(PARTS, best))
        print(f"  {'cold' if cold else 'warm'}: {figures}; together {best.sum():.3f} ms")
    return 0


if __name__ == "__main__":
    sys.exit(main())
