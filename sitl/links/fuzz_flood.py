"""A MAVLink fuzzer for robustness tests: datagrams of mangled MAVLink 2 frames at a set rate.

    python -m sitl.links.fuzz_flood --to 127.0.0.1:14550 --rate 10000 --count 100000

Each datagram is one valid frame (a random message of the dialect with random fields, from a
random system) with, most of the time, a few bytes flipped: some pass the CRC and reach the
message handlers, most are garbage to the parser. Loopback only; it stops after `--count`.
`python -m benchmarks.flood` floods a served SITL with it and prints how the telemetry kept
its rate.
"""

from __future__ import annotations

import argparse
import itertools
import random
import socket
import sys
import time

from m4.mavlink import mavlink, new_mav
from sitl.links.netem_proxy import NetemError, loopback_address

_MESSAGES = (
    lambda r: mavlink.MAVLink_m4_setpoint_message(1, 1, r.getrandbits(32), r.getrandbits(16),
                                                  [r.uniform(-1e3, 1e3) for _ in range(4)], [r.random()] * 4,
                                                  [r.random()] * 4, r.getrandbits(8)),
    lambda r: mavlink.MAVLink_command_long_message(1, 1, r.choice((400, 511, 512, 420, 31000 + r.getrandbits(4))), 0,
                                                   *[r.uniform(-10, 1e6) for _ in range(7)]),
    lambda r: mavlink.MAVLink_heartbeat_message(r.getrandbits(8), r.getrandbits(8), 0, 0, 0, 3),
    lambda r: mavlink.MAVLink_timesync_message(0, r.getrandbits(63)),
    lambda r: mavlink.MAVLink_statustext_message(6, bytes(r.getrandbits(8) % 95 + 32 for _ in range(50))),
)


class _Sink:
    def write(self, packet):
        self.packet = bytes(packet)


def fuzzed_frames(seed: int = 0):
    """An endless supply of fuzzed frames (bytes)."""
    r = random.Random(seed)
    sink = _Sink()
    while True:
        mav = new_mav(sink, r.randint(1, 255), r.randint(0, 255))
        mav.send(r.choice(_MESSAGES)(r))
        frame = bytearray(sink.packet)
        for _ in range(r.choice((0, 1, 1, 2, 3))):
            frame[r.randrange(len(frame))] = r.getrandbits(8)
        yield bytes(frame)


def flood(to: tuple[str, int], rate_hz: float, count: int, seed: int = 0) -> float:
    """Send `count` fuzzed frames to `to` at `rate_hz` (made beforehand); the seconds it took."""
    frames = iter(list(itertools.islice(fuzzed_frames(seed), count)))
    print("flood: sending", flush=True)
    start = time.monotonic()
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        for i in range(count):
            delay = start + i / rate_hz - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            try:
                s.sendto(next(frames), to)
            except OSError:
                pass                 # nobody listening: UDP drops
    return time.monotonic() - start


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m sitl.links.fuzz_flood", description="flood a MAVLink UDP port with fuzzed frames")
    p.add_argument("--to", metavar="HOST:PORT", help="where to send (loopback only)")
    p.add_argument("--rate", type=float, default=10_000.0, help="frames per second (default 10000)")
    p.add_argument("--count", type=int, default=100_000, help="frames to send (default 100000)")
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)
    try:
        to = loopback_address(args.to or "")
    except NetemError as e:
        print(f"flood: error: {e}", file=sys.stderr)
        return 2
    seconds = flood(to, args.rate, args.count, args.seed)
    print(f"flood: {args.count} frames in {seconds:.1f} s ({args.count / seconds:.0f}/s)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
