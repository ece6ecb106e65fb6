"""`m4-companion dashboard`: serve the dashboard of the live feed, or of a recorded flight.

    m4-companion dashboard --connect tcp/ROBOT:7447 --port 8080      # live, from the robot's Zenoh
    m4-companion dashboard --replay runs/X/feed.jsonl --speed 2      # a flight m4-sitl fly recorded
    m4-companion dashboard --replay FLIGHT.tlog                      # a flight's MAVLink log

then open http://HOST:PORT/ in a browser. Live, the server subscribes to m4/<vehicle>/**
as `m4-companion watch` does; replayed, every page that opens watches the flight from its
start, paced by the flight's own clock, and can pause it and seek in it. A tlog replays the
state, setpoints, faults and NMPC solves its MAVLink messages carry
(companion.dashboard.tlog); the link plot stays empty. A file that is neither says so in
one line naming it.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from companion import watch
from companion.dashboard.events import Hub, ReplaySource, airframe_view, read_recorded_feed
from companion.dashboard.server import DashboardServer
from companion.dashboard.tlog import tlog_samples
from m4.airframe import load_airframe
from m4.feed.payloads import KEY_PREFIX
from m4.feed.transport import FeedError

DEFAULT_PORT = 8080
PROG = "m4-companion dashboard"


def _speed(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not 0 < value < float("inf"):
        raise argparse.ArgumentTypeError(f"must be a finite number > 0, got {text}")
    return value


def add_arguments(parser: argparse.ArgumentParser) -> None:
    where = watch.add_connection_arguments(parser)
    where.add_argument("--replay", type=Path, metavar="FILE",
                       help="replay a recorded flight instead of the live feed: a feed.jsonl (m4-sitl fly) or a .tlog")
    parser.add_argument("--speed", type=_speed, default=1.0, metavar="X",
                        help="with --replay: X times real time (default 1)")
    parser.add_argument("--host", default="127.0.0.1",
                        help="address to serve on (default 127.0.0.1; 0.0.0.0 for every interface)")
    parser.add_argument("--port", type=int, default=DEFAULT_PORT, help=f"TCP port to serve on (default {DEFAULT_PORT}; 0: any free one)")


def run(args: argparse.Namespace) -> int:
    af = load_airframe()
    config = {"vehicle": args.vehicle, "airframe": airframe_view(af)}
    session = None
    try:
        if args.replay is not None:
            samples = (tlog_samples(args.replay, af, args.vehicle) if args.replay.suffix == ".tlog"
                       else read_recorded_feed(args.replay))
            source = ReplaySource(samples, af, args.speed)
            config |= {"mode": "replay", "source": f"{args.replay} at {args.speed:g}x",
                       "replay": source.span()}
        else:
            vehicle, session = watch.connect(args)
            source = Hub(af)
            session.declare_subscriber(f"{KEY_PREFIX}/{vehicle}/**", lambda sample: source.take(
                str(sample.key_expr), sample.payload.to_bytes()))
            config |= {"mode": "live", "source": ", ".join(args.connect or [args.zenoh_config or watch.DEFAULT_CONNECT])}
        server = DashboardServer(source, config, args.host, args.port)
    except (ValueError, FeedError, OSError) as e:
        if session is not None:
            session.close()
        print(f"{PROG}: {_reason(e, args)}", file=sys.stderr)
        return 2
    print(f"{PROG}: {config['mode']} {config['source']} on {server.url}", file=sys.stderr, flush=True)
    try:
        server.serve_forever()
    except KeyboardInterrupt:
        pass
    finally:
        server.stopping.set()
        server.server_close()
        if session is not None:
            session.close()
    return 0


def _reason(error: Exception, args: argparse.Namespace) -> str:
    if isinstance(error, OSError):
        return f"cannot serve on {args.host}:{args.port}: {error.strerror or error}"
    return str(error)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog=PROG, description=__doc__.splitlines()[0])
    add_arguments(parser)
    return run(parser.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
