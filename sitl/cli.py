"""`m4-sitl`: the simulator's command line.

    m4-sitl serve [--scenario SCENARIO] [--mavlink URL]... [--realtime] [--viewer] [--tlog PATH] [--truth-log PATH]
                  [--signing-key FILE] [--signing-state FILE] [--params FILE] [--companion SYS:COMP] [--seed N]
                  [--duration S] [--lockstep-timeout S] [--link-delay-ms MS] [--link-loss P] [--start-fd FD]
    m4-sitl physics --autopilot ardupilot [--scenario SCENARIO] [--port N] [--truth-log PATH] [--seed N] [--duration S]
    m4-sitl fly-ardupilot SCENARIO [--out DIR] [--speedup N] [--instance I] [--companion] [--priority P]
    m4-sitl list
    m4-sitl fly SCENARIO [--out DIR] [--controller nmpc|fixed-posture] [--seed N] [--port N] [--rate-hz HZ]
                [--realtime] [--viewer] [--link-delay-ms MS] [--link-loss P]
    m4-sitl compare [--out DIR] [--jobs N] [--rate-hz HZ] [--link-delay-ms MS] [--link-loss P]
    m4-sitl campaign [--out DIR] [--samples N | --grid] [--loss X]... [--seed N] [--jobs N] [--rate-hz HZ]
                     [--engine local|dask] [--scheduler ADDRESS] [--link-delay-ms MS] [--link-loss P]
                     [--kind K,... [--esc on,off] [--speed V,...] [--false-alarm-minutes MIN] [--wind M/S]
                      [--turbulence LEVEL,...] [--profile P,...] [--sweep SETTING=V,...]]

A subcommand is one `add_<name>(subparsers)` function that sets `func`, registered under its
name in `SUBCOMMANDS` (the flight subcommands live in sitl/flight_cli.py, the shared argument
types in sitl/cli_args.py); a command line that names one builds that parser alone (the
campaigns' parsers import the campaigns: a cost at every `serve` a campaign starts). Bad input
(unknown scenario, malformed file, bad URL, port in use) prints one line on stderr and exits
with 2; so does an install without the `sim` extra (every subcommand but `list` needs MuJoCo,
matplotlib and tqdm), naming the extra to install.
"""

from __future__ import annotations

import argparse
import gc
import os
import signal
import sys
from pathlib import Path

from m4 import extras
from m4.mavlink import COMPANION_COMPONENT_ID, FC_SYSTEM_ID
from m4.mavlink.link import LinkError
from m4.mavlink.signing import load_key
from m4.scenario import Scenario
from m4.toml_fields import ConfigError
from sitl import scenarios
from m4.arguments import positive_number, seed_number
from sitl.cli_args import BadInput, Parser, add_link_arguments, link_of

EXIT_BAD_INPUT = 2
DEFAULT_URL = "udpout:127.0.0.1:14550"


def _add_serve(sub) -> None:
    p = sub.add_parser("serve", help="run the simulated flight controller for an external companion or GCS")
    p.add_argument("--scenario", help="built-in name or scenario file (default: hover at 2 m, no faults)")
    p.add_argument("--mavlink", action="append", metavar="URL",
                   help=f"udpout:HOST:PORT (send there) or udpin:HOST:PORT (listen); repeat for more links "
                        f"(default: {DEFAULT_URL})")
    p.add_argument("--realtime", action="store_true", help="pace by the wall clock (default: lockstep)")
    p.add_argument("--viewer", action="store_true", help="show MuJoCo's passive viewer")
    p.add_argument("--tlog", type=Path, metavar="PATH", help="write every packet, both directions, as a tlog")
    p.add_argument("--signing-key", type=Path, metavar="FILE", help="MAVLink 2 signing key (64 hex digits or 32 bytes)")
    p.add_argument("--signing-state", type=Path, metavar="FILE",
                   help="where the signing timestamps are kept across restarts, so no captured packet can be "
                        "replayed (default: the key file's path + .timestamps)")
    p.add_argument("--params", type=Path, metavar="FILE",
                   help="where the parameters set over MAVLink are kept and loaded from at start (default: the "
                        "signing key + .params.toml; without a key they last the run)")
    p.add_argument("--companion", type=_ids, default=(FC_SYSTEM_ID, COMPANION_COMPONENT_ID), metavar="SYS:COMP",
                   help="the one system and component whose setpoints and commands are obeyed (default 1:191)")
    p.add_argument("--truth-log", type=Path, metavar="PATH", help="write the plant's true state at 100 Hz (.npz); the last 10 minutes are kept (a ring "
                        "buffer), so memory stays bounded")
    p.add_argument("--seed", type=seed_number, default=0, help="sensor noise seed (default 0)")
    p.add_argument("--duration", type=positive_number, metavar="S",
                   help="stop after S simulated seconds (default: never)")
    p.add_argument("--lockstep-timeout", type=positive_number, default=5.0, metavar="S",
                   help="wall-clock wait for a setpoint before going on in failsafe (default 5)")
    add_link_arguments(p, "with --realtime the same on the wall clock; only the first --mavlink link (the "
                          "companion's)")
    p.add_argument("--start-fd", type=int, metavar="FD",
                   help="an open file descriptor: once the plant is built and the links are open, wait for a line "
                        "on it before serving (end of file first: exit without serving); for a supervisor that "
                        "starts the companion alongside, e.g. m4-sitl fly")
    p.set_defaults(func=_serve)


def _ids(text: str) -> tuple[int, int]:
    sys_id, _, comp_id = text.partition(":")
    if not (sys_id.isdigit() and comp_id.isdigit() and 1 <= int(sys_id) <= 255 and 1 <= int(comp_id) <= 255):
        raise argparse.ArgumentTypeError(f"expected SYS:COMP, each 1..255, got {text!r}")
    return int(sys_id), int(comp_id)


def _serve(args) -> int:
    scenario = scenarios.resolve(args.scenario) if args.scenario else Scenario(name="hover", duration_s=3600.0)
    key = load_key(args.signing_key) if args.signing_key else None
    if not args.viewer:
        os.environ.setdefault("MUJOCO_GL", "disable")   # MuJoCo then loads no OpenGL (0.1 s of each start)
    from sitl.serve import ServeError, ServeOptions, Server  # MuJoCo only once the input is good

    options = ServeOptions(scenario=scenario, mavlink_urls=tuple(args.mavlink or (DEFAULT_URL,)),
                           realtime=args.realtime, viewer=args.viewer, tlog_path=args.tlog, signing_key=key,
                           seed=args.seed, duration_s=args.duration, lockstep_timeout_s=args.lockstep_timeout,
                           truth_log_path=args.truth_log, companion_ids=args.companion, link=link_of(args),
                           signing_state_path=args.signing_state or (
                               Path(f"{args.signing_key}.timestamps") if args.signing_key else None),
                           params_path=args.params or (Path(f"{args.signing_key}.params.toml") if args.signing_key
                                                       else None))
    if args.start_fd is not None:
        _check_fd(args.start_fd)
    try:
        server = Server(options)
    except ServeError as e:
        raise BadInput(str(e)) from None
    if args.start_fd is not None and not _told_to_start(args.start_fd):
        server.close()
        return 0
    gc.freeze()     # what was built to serve (plant, FC, dialect, links) is never garbage: no full collection walks it
    return _run_until_stopped(server, ServeError)


def _check_fd(fd: int) -> None:
    try:
        os.fstat(fd)
    except OSError as e:
        raise BadInput(f"--start-fd {fd}: {e.strerror}") from None


def _told_to_start(fd: int) -> bool:
    """Wait for a line on `fd` (True) or its end, or Ctrl-C (False: the flight is called off)."""
    with os.fdopen(fd, "rb") as start:
        try:
            return bool(start.readline())
        except KeyboardInterrupt:
            return False


def _run_until_stopped(server, *errors: type[Exception]) -> int:
    """Run a server until it ends, SIGTERM or Ctrl-C, then close it; `errors` raised while it
    runs are bad input (one line)."""
    signal.signal(signal.SIGTERM, lambda *_: server.stop())
    try:
        server.run()
    except KeyboardInterrupt:
        pass
    except errors as e:
        raise BadInput(str(e)) from None
    finally:
        server.close()
    return 0


def _add_physics(sub) -> None:
    p = sub.add_parser("physics", help="the plant as an autopilot's own SITL physics (ArduPilot's JSON interface)")
    p.add_argument("--autopilot", choices=("ardupilot",), required=True,
                   help="whose SITL asks for physics: ardupilot (arducopter --model JSON:127.0.0.1)")
    p.add_argument("--scenario", help="built-in name or scenario file: its start point, faults and [plant] "
                                      "(default: hover at 2 m, no faults)")
    p.add_argument("--port", type=_port, default=9002, help="UDP port on 127.0.0.1 SITL sends to (default 9002)")
    p.add_argument("--truth-log", type=Path, metavar="PATH", help="write the plant's true state at 100 Hz (.npz)")
    p.add_argument("--seed", type=seed_number, default=0, help="seed of the plant's noise (default 0)")
    p.add_argument("--duration", type=positive_number, metavar="S",
                   help="stop after S simulated seconds (default: never)")
    p.set_defaults(func=_physics)


def _port(text: str) -> int:
    if not (text.isdigit() and 1 <= int(text) <= 65535):
        raise argparse.ArgumentTypeError(f"expected a UDP port 1..65535, got {text!r}")
    return int(text)


def _physics(args) -> int:
    scenario = scenarios.resolve(args.scenario) if args.scenario else Scenario(name="hover", duration_s=3600.0)
    from sitl.ardupilot.physics import PhysicsOptions, PhysicsServer  # MuJoCo only once the input is good
    from sitl.vehicle import log

    options = PhysicsOptions(scenario=scenario, port=args.port, seed=args.seed, duration_s=args.duration,
                             truth_log_path=args.truth_log)
    try:
        server = PhysicsServer(options, log=log)
    except OSError as e:
        raise BadInput(str(e)) from None
    return _run_until_stopped(server)


def _add_fly_ardupilot(sub) -> None:
    p = sub.add_parser("fly-ardupilot", help="fly a scenario through ArduCopter SITL's own controller "
                                             "(no companion): the baseline")
    p.add_argument("scenario", help="built-in name or scenario file")
    p.add_argument("--out", type=Path, metavar="DIR", help="output folder (default: out/ardupilot/SCENARIO)")
    p.add_argument("--speedup", type=positive_number, default=10.0,
                   help="arducopter --speedup: how much faster than real time it may run (default 10)")
    p.add_argument("--instance", type=int, choices=range(10), default=0, metavar="I",
                   help="arducopter -I: MAVLink on tcp 5760 + 10 I, physics on udp 9002 + 10 I (default 0)")
    p.add_argument("--companion", action="store_true",
                   help="the companion flies through the M4 Lua applet once the robot holds its start point "
                        "(real time from then on)")
    p.add_argument("--priority", type=int, default=0, metavar="P",
                   help="with --companion: the companion, arducopter and the physics in SCHED_FIFO at P (1..99) "
                        "from the handover on, against a busy machine (default 0: normal priority)")
    p.set_defaults(func=_fly_ardupilot)


def _fly_ardupilot(args) -> int:
    scenario = scenarios.resolve(args.scenario)
    from sitl.ardupilot.flight import ArduFlightOptions, FlightError, fly_ardupilot, summary_line
    from sitl.vehicle import log

    out = args.out or Path("out") / "ardupilot" / scenario.name
    try:
        metrics = fly_ardupilot(ArduFlightOptions(scenario=scenario, out_dir=out, speedup=args.speedup,
                                                  instance=args.instance, companion=args.companion,
                                                  scenario_file=scenarios.scenario_path(args.scenario),
                                                  priority=args.priority), log=log)
    except (FlightError, OSError) as e:
        raise BadInput(str(e)) from None
    print(summary_line(metrics))
    print(f"wrote {out}/truth.npz, metrics.json, flight.png, statustext.txt")
    return 0


def _add_list(sub) -> None:
    p = sub.add_parser("list", help="the built-in scenarios, one a line")
    p.set_defaults(func=_list)


def _list(args) -> int:
    print("\n".join(scenarios.builtin_names()))
    return 0


def _flight_subcommand(name: str):
    """sitl/flight_cli.py's add_<name>, imported when it is built (it loads the flights' runner)."""
    def add(sub) -> None:
        from sitl import flight_cli
        getattr(flight_cli, f"add_{name}")(sub)
    return add


SUBCOMMANDS = {"serve": _add_serve, "physics": _add_physics, "fly-ardupilot": _add_fly_ardupilot, "list": _add_list,
               "fly": _flight_subcommand("fly"), "compare": _flight_subcommand("compare"),
               "campaign": _flight_subcommand("campaign")}


def main(argv: list[str] | None = None) -> int:
    parser = Parser(prog="m4-sitl", description="M4 simulator: MuJoCo plant behind a MAVLink 2 flight controller")
    sub = parser.add_subparsers(dest="command", required=True)
    named = sys.argv[1:2] if argv is None else argv[:1]
    for add in [SUBCOMMANDS[named[0]]] if named and named[0] in SUBCOMMANDS else SUBCOMMANDS.values():
        add(sub)
    try:
        args = parser.parse_args(argv)
        if args.command != "list" and (hint := extras.extra_hint(f"m4-sitl {args.command}", "sim", extras.SIM)):
            raise BadInput(hint)
        return args.func(args)
    except (BadInput, ConfigError, LinkError) as e:
        print(f"m4-sitl: error: {e}", file=sys.stderr)
        return EXIT_BAD_INPUT


if __name__ == "__main__":
    sys.exit(main())
