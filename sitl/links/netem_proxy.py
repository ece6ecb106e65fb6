"""A small UDP link impairment proxy on loopback: delay, loss, duplication and reordering.

    python -m sitl.links.netem_proxy --listen 127.0.0.1:14551 --to 127.0.0.1:14550 --delay-ms 50 --loss 0.2

Datagrams arriving at `--listen` go to `--to` (the "forward" direction); datagrams coming
back from `--to` go to whoever wrote to `--listen` last (the "back" direction). Each
direction gets the same impairment, independently: every datagram is dropped with
probability `loss`, else held `delay_ms` (plus up to `jitter_ms`, uniform), sent twice with
probability `duplicate`, and with probability `reorder` held `reorder_ms` longer, so later
datagrams overtake it. Put it between `m4-sitl serve --mavlink udpout:127.0.0.1:LISTEN` and
a companion on `udpin:127.0.0.1:TO` (or the other way round).

Bounded: loopback addresses only, at most `MAX_QUEUED` datagrams held (more are dropped and
counted), and it stops by itself after `--duration` seconds (default 600). Tests use
`Netem(...).start()` and `close()`; `counters` says what it did in each direction.
"""

from __future__ import annotations

import argparse
import heapq
import ipaddress
import random
import select
import socket
import sys
import threading
import time
from dataclasses import dataclass, field

from m4.arguments import positive_number

MAX_QUEUED = 10_000
DEFAULT_DURATION_S = 600.0
_DATAGRAM_MAX = 65535


class NetemError(ValueError):
    """A bad address or impairment."""


@dataclass(frozen=True)
class Impairment:
    delay_ms: float = 0.0
    jitter_ms: float = 0.0
    loss: float = 0.0              # probability a datagram is dropped
    duplicate: float = 0.0         # probability a datagram is sent twice
    reorder: float = 0.0           # probability a datagram is held `reorder_ms` longer
    reorder_ms: float = 20.0

    def __post_init__(self):
        for name in ("loss", "duplicate", "reorder"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise NetemError(f"{name} must be within 0..1, got {getattr(self, name)}")
        for name in ("delay_ms", "jitter_ms", "reorder_ms"):
            if not 0.0 <= getattr(self, name) <= 60_000.0:
                raise NetemError(f"{name} must be within 0..60000 ms, got {getattr(self, name)}")


@dataclass
class DirectionCounters:
    received: int = 0
    sent: int = 0
    lost: int = 0
    duplicated: int = 0
    reordered: int = 0
    overflowed: int = 0            # dropped because MAX_QUEUED datagrams were already held


@dataclass
class NetemCounters:
    forward: DirectionCounters = field(default_factory=DirectionCounters)
    back: DirectionCounters = field(default_factory=DirectionCounters)


def loopback_address(text: str) -> tuple[str, int]:
    """`HOST:PORT` on loopback (127.0.0.0/8 or localhost) -> (host, port); NetemError otherwise."""
    host, sep, port = text.rpartition(":")
    host = "127.0.0.1" if host == "localhost" else host
    try:
        loopback = ipaddress.ip_address(host).is_loopback
    except ValueError:
        loopback = False
    if not sep or not loopback or not port.isdigit() or not 0 <= int(port) <= 65535:
        raise NetemError(f"bad address {text!r}: expected 127.x.x.x:PORT (loopback only)")
    return host, int(port)


class Netem:
    def __init__(self, listen: tuple[str, int], to: tuple[str, int], impairment: Impairment = Impairment(),
                 seed: int | None = None, duration_s: float = DEFAULT_DURATION_S):
        self.impairment = impairment
        self.to = to
        self.duration_s = duration_s
        self.counters = NetemCounters()
        self._rng = random.Random(seed)
        self._client: tuple[str, int] | None = None
        self._queue: list[tuple[float, int, socket.socket, bytes, tuple[str, int] | None]] = []
        self._seq = 0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.listen_sock = self._socket(listen)
        self.to_sock = self._socket((to[0], 0))

    @staticmethod
    def _socket(address: tuple[str, int]) -> socket.socket:
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            sock.bind(address)
        except OSError as e:
            sock.close()
            raise NetemError(f"cannot listen on {address[0]}:{address[1]}: {e.strerror or e}") from None
        sock.setblocking(False)
        return sock

    @property
    def listen_port(self) -> int:
        return self.listen_sock.getsockname()[1]

    # -- one datagram ---------------------------------------------------------------------------
    def _schedule(self, now: float, data: bytes, out: socket.socket, back: bool) -> None:
        imp, c = self.impairment, (self.counters.back if back else self.counters.forward)
        c.received += 1
        if self._rng.random() < imp.loss:
            c.lost += 1
            return
        copies = 2 if self._rng.random() < imp.duplicate else 1
        c.duplicated += copies - 1
        for _ in range(copies):
            delay_ms = imp.delay_ms + self._rng.uniform(0.0, imp.jitter_ms)
            if self._rng.random() < imp.reorder:
                delay_ms += imp.reorder_ms
                c.reordered += 1
            if len(self._queue) >= MAX_QUEUED:
                c.overflowed += 1
                continue
            self._seq += 1
            heapq.heappush(self._queue, (now + delay_ms / 1000.0, self._seq, out, data, None if back else self.to))

    def _release(self, now: float) -> None:
        while self._queue and self._queue[0][0] <= now:
            _, _, out, data, dest = heapq.heappop(self._queue)
            back = dest is None
            dest = self._client if back else dest
            if dest is None:
                continue
            try:
                out.sendto(data, dest)
            except OSError:
                continue                 # nobody listening there (yet): UDP drops
            (self.counters.back if back else self.counters.forward).sent += 1

    def _drain(self, sock: socket.socket, now: float) -> None:
        back = sock is self.to_sock
        while True:
            try:
                data, sender = sock.recvfrom(_DATAGRAM_MAX)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                continue                 # an ICMP "port unreachable" from an earlier send
            if back:
                self._schedule(now, data, self.listen_sock, back=True)
            else:
                self._client = sender
                self._schedule(now, data, self.to_sock, back=False)

    # -- the loop ---------------------------------------------------------------------------------
    def run(self) -> None:
        """Relay until close() or `duration_s` has passed."""
        end = time.monotonic() + self.duration_s
        socks = [self.listen_sock, self.to_sock]
        while not self._stop.is_set():
            now = time.monotonic()
            if now >= end:
                return
            self._release(now)
            wake = min(end, self._queue[0][0] if self._queue else now + 0.05, now + 0.05)
            readable, _, _ = select.select(socks, [], [], max(wake - now, 0.0))
            now = time.monotonic()
            for sock in readable:
                self._drain(sock, now)

    def start(self) -> Netem:
        self._thread = threading.Thread(target=self.run, daemon=True)
        self._thread.start()
        return self

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
        self.listen_sock.close()
        self.to_sock.close()


def _fraction(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not 0.0 <= value <= 1.0:
        raise argparse.ArgumentTypeError(f"must be within 0..1, got {text}")
    return value


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m sitl.links.netem_proxy",
                                description="UDP delay/loss/duplicate/reorder proxy on loopback (both directions)")
    p.add_argument("--listen", required=True, metavar="HOST:PORT", help="where the proxy receives (loopback)")
    p.add_argument("--to", required=True, metavar="HOST:PORT", help="where it forwards to (loopback)")
    p.add_argument("--delay-ms", type=float, default=0.0, help="added delay each way (default 0)")
    p.add_argument("--jitter-ms", type=float, default=0.0, help="extra delay, uniform in 0..J (default 0)")
    p.add_argument("--loss", type=_fraction, default=0.0, help="drop probability each way (default 0)")
    p.add_argument("--duplicate", type=_fraction, default=0.0, help="duplicate probability (default 0)")
    p.add_argument("--reorder", type=_fraction, default=0.0, help="probability a datagram is held back (default 0)")
    p.add_argument("--reorder-ms", type=float, default=20.0, help="how long it is held back (default 20)")
    p.add_argument("--seed", type=int, help="random seed (default: random)")
    p.add_argument("--duration", type=positive_number, default=DEFAULT_DURATION_S, metavar="S",
                   help=f"stop after S seconds (default {DEFAULT_DURATION_S:g})")
    args = p.parse_args(argv)
    try:
        imp = Impairment(delay_ms=args.delay_ms, jitter_ms=args.jitter_ms, loss=args.loss,
                         duplicate=args.duplicate, reorder=args.reorder, reorder_ms=args.reorder_ms)
        netem = Netem(loopback_address(args.listen), loopback_address(args.to), imp, args.seed, args.duration)
    except NetemError as e:
        print(f"netem: error: {e}", file=sys.stderr)
        return 2
    host, port = netem.listen_sock.getsockname()
    print(f"netem: {host}:{port} -> {args.to}: {imp}", file=sys.stderr, flush=True)
    try:
        netem.run()
    except KeyboardInterrupt:
        pass
    finally:
        netem.close()
    print(f"netem: {netem.counters}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
