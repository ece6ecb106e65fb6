"""`m4-companion watch`: the companion's Zenoh feed, live, in a terminal.

Subscribes to m4/<vehicle>/** and redraws a few lines in place (plain ANSI, no curses):
time, position, attitude, thrusts, hips, a fault banner, the NMPC's solve, link health.
`--once` prints one snapshot when every topic has arrived (or at the timeout) and exits:
0 when all arrived, 1 when some never did.
"""

from __future__ import annotations

import argparse
import json
import re
import shutil
import sys
import threading
import time
from dataclasses import dataclass, field
from typing import Any, TextIO

import zenoh

from m4.feed.payloads import KEY_PREFIX, TOPICS, check_vehicle
from m4.feed.transport import (FeedError, config_from_endpoints, config_from_file,
                                      open_session)

DEFAULT_CONNECT = "tcp/127.0.0.1:7447"     # the robot's local Zenoh router (deploy/)
STALE_AFTER_S = 2.0
REFRESH_S = 0.1

_HOME, _CLEAR_LINE, _CLEAR_BELOW, _CLEAR_SCREEN = "\x1b[H", "\x1b[K", "\x1b[J", "\x1b[2J"
_BANNER_COLOUR = {"confirmed": "\x1b[1;97;41m", "suspect": "\x1b[1;30;43m"}
_RESET = "\x1b[0m"
_BANNER_LINE = 1


@dataclass
class Latest:
    """The newest payload of each topic and when it arrived (receiver's monotonic clock)."""
    payloads: dict[str, dict[str, Any]] = field(default_factory=dict)
    received_s: dict[str, float] = field(default_factory=dict)
    bad_samples: int = 0
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    def take(self, key: str, data: bytes, now_s: float) -> None:
        topic = key.rsplit("/", 1)[-1]
        try:
            payload = json.loads(data)
        except ValueError:
            payload = None
        with self._lock:
            if topic not in TOPICS or not isinstance(payload, dict):
                self.bad_samples += 1
                return
            self.payloads[topic] = payload
            self.received_s[topic] = now_s

    def snapshot(self) -> tuple[dict[str, dict[str, Any]], dict[str, float], int]:
        with self._lock:
            return dict(self.payloads), dict(self.received_s), self.bad_samples

    def complete(self) -> bool:
        with self._lock:
            return set(self.payloads) >= set(TOPICS)


def render(vehicle: str, payloads: dict[str, dict[str, Any]], ages_s: dict[str, float],
           bad_samples: int = 0, colour: bool = False, width: int | None = None) -> list[str]:
    """The view as lines of text; a topic not seen yet says so, an old one says how old.

    width cuts every line to that many characters (a wrapped line would break the redraw);
    colour paints the fault banner (ANSI) for a terminal.
    """
    state, setpoint, fault, nmpc, link = (payloads.get(t) for t in ("state", "setpoint", "fault", "nmpc", "link"))
    t_s = next((p.get("t_s") for p in (state, nmpc, setpoint, link) if p and p.get("t_s") is not None), None)
    lines = [f"M4 feed {KEY_PREFIX}/{vehicle}   t = {_num(t_s, '.2f')} s"
             + (f"   ({bad_samples} unreadable samples)" if bad_samples else "")]
    lines.append(_fault_banner(fault))
    lines += _state_lines(state)
    lines.append(_setpoint_line(setpoint))
    lines.append(_nmpc_line(nmpc))
    lines.append(_link_line(link))
    stale = [f"{t} {ages_s[t]:.1f} s" for t in TOPICS if t in ages_s and ages_s[t] > STALE_AFTER_S]
    if stale:
        lines.append("stale: " + ", ".join(stale))
    if width:
        lines = [line[:width] for line in lines]
    banner_colour = _BANNER_COLOUR.get(str(fault.get("state"))) if fault else None
    if colour and banner_colour:
        lines[_BANNER_LINE] = f"{banner_colour}{lines[_BANNER_LINE]}{_RESET}"
    return lines


def _state_lines(state: dict[str, Any] | None) -> list[str]:
    if state is None:
        return ["state        (waiting)"]
    euler = state.get("euler_deg")
    return [
        f"pos NED m    {_vec(state.get('pos_ned_m'), '+7.2f')}   vel m/s {_vec(state.get('vel_ned_m_s'), '+6.2f')}",
        f"att deg      roll {_num(_at(euler, 0), '+6.1f')}  pitch {_num(_at(euler, 1), '+6.1f')}"
        f"  yaw {_num(_at(euler, 2), '+7.1f')}   rates rad/s {_vec(state.get('rates_frd_rad_s'), '+5.2f')}",
        f"thrust N     {_vec(state.get('thrust_n'), '6.2f')}   hip deg {_vec(state.get('hip_deg'), '6.1f')}",
    ]


def _setpoint_line(setpoint: dict[str, Any] | None) -> str:
    if setpoint is None:
        return "setpoint     (waiting)"
    return (f"setpoint     thrust N {_vec(setpoint.get('thrust_n'), '6.2f')}   hip deg {_vec(setpoint.get('hip_deg'), '6.1f')}"
            + ("   THRUST CUT" if setpoint.get("thrust_cut") else ""))


def _fault_banner(fault: dict[str, Any] | None) -> str:
    if fault is None:
        return "fault        (waiting)"
    state = fault.get("state", "?")
    if state == "healthy":
        return "fault        none"
    text = f" FAULT {str(state).upper()}: {fault.get('message') or 'rotor ' + str(fault.get('rotor'))}"
    text += f" (detected at t = {_num(fault.get('detected_at_s'), '.2f')} s)" if fault.get("detected_at_s") is not None else ""
    text += f"  max thrust N {_vec(fault.get('thrust_max_estimate_n'), '5.1f')} "
    return text


def _nmpc_line(nmpc: dict[str, Any] | None) -> str:
    if nmpc is None:
        return "nmpc         (waiting)"
    predicted = nmpc.get("predicted_p_ned_m") or []
    end = f"   end of horizon NED m {_vec(predicted[-1], '+6.2f')}" if predicted else ""
    flags = ("" if nmpc.get("ok") else "   NOT OK") + ("   FALLBACK" if nmpc.get("fallback") else "")
    return (f"nmpc         solve {_num(nmpc.get('solve_ms'), '5.1f')} ms  iterations {nmpc.get('iterations', '-')}"
            f"  cost {_num(nmpc.get('cost'), '.3g')}  {nmpc.get('status', '-')}{flags}{end}")


def _link_line(link: dict[str, Any] | None) -> str:
    if link is None:
        return "link         (waiting)"
    return (f"link         {'connected' if link.get('connected') else 'LOST'}"
            f"  last msg {_num(link.get('last_msg_age_s'), '.2f')} s ago  {_num(link.get('msgs_per_s'), '.0f')} msg/s"
            f"  bad crc {link.get('bad_crc', '-')}  bad signature {link.get('bad_signature', '-')}"
            f"  foreign {link.get('dropped_foreign', '-')}  feed errors {link.get('feed_errors', '-')}"
            + ("  FLIGHT LOG PAUSED" if link.get("flight_log_paused") else ""))


def _num(value: Any, spec: str) -> str:
    """value formatted by spec; "-" (as wide) when it is missing or not a number."""
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return format(value, spec)
    width = re.match(r"[+\- ]?(\d*)", spec).group(1)
    return "-".rjust(int(width or 1))


def _at(values: Any, i: int) -> Any:
    return values[i] if isinstance(values, list) and len(values) > i else None


def _vec(values: Any, spec: str) -> str:
    if not isinstance(values, list):
        return "-"
    return " ".join(_num(v, spec) for v in values)


def add_connection_arguments(parser: argparse.ArgumentParser) -> argparse._MutuallyExclusiveGroup:
    """--zenoh-config or --connect (one group, returned for a caller to add alternatives), --vehicle."""
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--zenoh-config", metavar="FILE",
                       help="a Zenoh config file (json5), used as written")
    where.add_argument("--connect", metavar="ENDPOINT", action="append",
                       help=f"connect as a Zenoh client to ENDPOINT, scouting off (default {DEFAULT_CONNECT}); repeatable")
    parser.add_argument("--vehicle", default="m4", help="vehicle name in the keys m4/<vehicle>/<topic> (default m4)")
    return where


def connect(args: argparse.Namespace) -> tuple[str, zenoh.Session]:
    """The checked vehicle name and a session opened as add_connection_arguments' options say.
    Raises ValueError or FeedError with one line saying what is wrong."""
    vehicle = check_vehicle(args.vehicle)
    if args.zenoh_config:
        return vehicle, open_session(config_from_file(args.zenoh_config), args.zenoh_config)
    endpoints = tuple(args.connect or [DEFAULT_CONNECT])
    try:
        return vehicle, open_session(config_from_endpoints("client", connect=endpoints), ", ".join(endpoints))
    except FeedError as e:
        raise FeedError(f"{e} (is a Zenoh router, or the companion, listening there?)") from None


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_connection_arguments(parser)
    parser.add_argument("--once", action="store_true",
                        help="print one snapshot when every topic has arrived (or at --timeout) and exit")
    parser.add_argument("--timeout", type=float, default=5.0, metavar="S",
                        help="with --once: seconds to wait for every topic (default 5)")


def run(args: argparse.Namespace, out: TextIO | None = None) -> int:
    out = out or sys.stdout
    try:
        vehicle, session = connect(args)
    except (ValueError, FeedError) as e:
        print(f"m4-companion watch: {e}", file=sys.stderr)
        return 2
    latest = Latest()
    try:
        session.declare_subscriber(f"{KEY_PREFIX}/{vehicle}/**", lambda sample: latest.take(
            str(sample.key_expr), sample.payload.to_bytes(), time.monotonic()))
        if args.once:
            return _once(vehicle, latest, args.timeout, out)
        return _live(vehicle, latest, out)
    finally:
        session.close()


def _view(vehicle: str, latest: Latest, colour: bool = False, width: int | None = None) -> list[str]:
    payloads, received_s, bad = latest.snapshot()
    now_s = time.monotonic()
    return render(vehicle, payloads, {t: now_s - s for t, s in received_s.items()}, bad, colour, width)


def _once(vehicle: str, latest: Latest, timeout_s: float, out: TextIO) -> int:
    deadline_s = time.monotonic() + timeout_s
    while not latest.complete() and time.monotonic() < deadline_s:
        time.sleep(0.02)
    out.write("\n".join(_view(vehicle, latest)) + "\n")
    missing = [t for t in TOPICS if t not in latest.snapshot()[0]]
    if missing:
        print(f"m4-companion watch: no {', '.join(missing)} within {timeout_s:g} s", file=sys.stderr)
        return 1
    return 0


def _live(vehicle: str, latest: Latest, out: TextIO) -> int:
    colour = out.isatty()
    out.write(_CLEAR_SCREEN)
    try:
        while True:
            lines = _view(vehicle, latest, colour, shutil.get_terminal_size().columns)
            out.write(_HOME + "".join(line + _CLEAR_LINE + "\n" for line in lines) + _CLEAR_BELOW)
            out.flush()
            time.sleep(REFRESH_S)
    except KeyboardInterrupt:
        out.write("\n")
        return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="m4-companion watch", description=__doc__.splitlines()[0])
    add_arguments(parser)
    return run(parser.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
