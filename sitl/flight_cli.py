"""The flight subcommands of `m4-sitl` (registered in sitl/cli.py): fly, compare, campaign.

Each `add_<name>(subparsers)` declares the arguments and sets `func`; a flight that cannot
start (FlightError) becomes the CLI's one-line bad-input error, exit code 2. compare and
campaign print their throughput (flights per core-minute); when one of their flights did not
run they say which and why in one line and exit with 1.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from sitl import scenarios
from m4.arguments import number, positive_int, positive_number, seed_number
from m4.scenario import SENSOR_PROFILES, TURBULENCE_LEVELS, WIND_SPEED_MAX_M_S
from sitl.cli_args import BadInput, add_link_arguments, link_of
from sitl.flights.flight_run import CONTROLLERS, FlightError, FlightOptions, make_output_dir

EXIT_FLIGHTS_NOT_RUN = 1


def _loss(text: str) -> float:
    value = number(text)
    if not 0.0 < value <= 1.0:
        raise argparse.ArgumentTypeError(f"must be in (0, 1], got {text}")
    return value


def _rate(p: argparse.ArgumentParser) -> None:
    p.add_argument("--rate-hz", type=positive_number, metavar="HZ",
                   help="the companion's control rate (default: the companion's own, [control] rate_hz)")


def add_fly(sub) -> None:
    p = sub.add_parser("fly", help="fly a scenario: the plant and the companion over loopback MAVLink; metrics, figures")
    p.add_argument("scenario", metavar="SCENARIO", help="built-in name (m4-sitl list) or scenario file")
    p.add_argument("--out", type=Path, metavar="DIR", help="output folder (default runs/<scenario>-<timestamp>)")
    p.add_argument("--controller", choices=CONTROLLERS, default="nmpc", help="nmpc (default) or fixed-posture")
    p.add_argument("--seed", type=seed_number, default=0, help="sensor noise seed (default 0)")
    p.add_argument("--port", type=int, metavar="N", help="loopback UDP port of the MAVLink link (default: a free one)")
    _rate(p)
    p.add_argument("--realtime", action="store_true", help="pace by the wall clock (default: lockstep)")
    p.add_argument("--viewer", action="store_true", help="show MuJoCo's passive viewer")
    p.add_argument("--video", action="store_true",
                   help="then render the flight offscreen: flight.mp4 (chase camera, real time) and snapshots_render.png")
    p.add_argument("--video-size", type=_video_size, default=(640, 360), metavar="WxH",
                   help="with --video: frame size in pixels (default 640x360)")
    _lockstep_timeout(p, FlightOptions.lockstep_timeout_s)
    add_link_arguments(p, "with --realtime through a loopback proxy (sitl/links/netem_proxy.py) instead")
    p.set_defaults(func=_fly)


def _lockstep_timeout(p: argparse.ArgumentParser, default_s: float) -> None:
    p.add_argument("--lockstep-timeout", type=positive_number, default=default_s, metavar="S",
                   help="lockstep: the SITL's wall-clock wait for a setpoint before its FC flies its failsafe "
                        f"(default {default_s:g}; a loaded machine needs more)")


def _video_size(text: str) -> tuple[int, int]:
    try:
        width, height = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT, e.g. 640x360, got {text!r}") from None
    if min(width, height) < 16 or width % 2 or height % 2:
        raise argparse.ArgumentTypeError(f"width and height must be even and >= 16, got {text}")
    return width, height


def _fly(args) -> int:
    from sitl.flights.fly import default_out_dir, fly, summary_line

    options = FlightOptions(controller=args.controller, seed=args.seed, realtime=args.realtime, viewer=args.viewer,
                            port=args.port, rate_hz=args.rate_hz, link=link_of(args),
                            lockstep_timeout_s=args.lockstep_timeout)
    out = args.out or default_out_dir(scenarios.resolve(args.scenario).name)
    try:
        metrics = fly(args.scenario, out, options)
    except FlightError as e:
        raise BadInput(str(e)) from None
    print(summary_line(metrics, out))
    if args.video:
        from sitl.flights.video import VideoError, VideoOptions, make_video

        try:
            paths = make_video(out, VideoOptions(width=args.video_size[0], height=args.video_size[1]))
        except VideoError as e:
            raise BadInput(f"the flight is in {out}, but {e}") from None
        print("video: " + ", ".join(str(p) for p in paths))
    return 0


def add_compare(sub) -> None:
    from sitl.campaigns.compare import DEFAULT_OUT

    p = sub.add_parser("compare", help="posture manipulation vs fixed posture on the paper's scenarios: a Markdown table")
    p.add_argument("--out", type=Path, default=DEFAULT_OUT, metavar="DIR", help=f"output folder (default {DEFAULT_OUT})")
    p.add_argument("--jobs", type=positive_int, metavar="N", help="flights at once (default: one per core)")
    _rate(p)
    add_link_arguments(p, "the same for every flight")
    p.set_defaults(func=_compare)


def _compare(args) -> int:
    from sitl.campaigns.compare import compare

    try:
        make_output_dir(args.out)
    except FlightError as e:
        raise BadInput(str(e)) from None
    table, batch = compare(args.out, workers=args.jobs, rate_hz=args.rate_hz, link=link_of(args))
    print(table, end="")
    return _report(batch)


def add_campaign(sub) -> None:
    from sitl.campaigns.campaign import DEFAULT_OUT
    from sitl.campaigns.detection_campaign import DEFAULT_OUT as DETECTION_OUT, KINDS, LOCKSTEP_TIMEOUT_S
    from sitl.campaigns.parallel import ENGINES

    p = sub.add_parser("campaign", help="many faulted flights in parallel: survival, altitude loss, detection")
    p.add_argument("--out", type=Path, metavar="DIR",
                   help=f"output folder (default {DEFAULT_OUT}; with --kind or --false-alarm-minutes {DETECTION_OUT})")
    p.add_argument("--samples", type=positive_int, default=20, metavar="N", help="random flights (default 20)")
    p.add_argument("--grid", action="store_true", help="the full grid of rotors, losses, speeds, fault times instead")
    p.add_argument("--loss", type=_loss, action="append", metavar="X",
                   help="only this loss of effectiveness (0..1; repeat for more; default 0.33, 0.66 and 1)")
    p.add_argument("--seed", type=seed_number, default=0, help="seed of the sample and of the sensor noise (default 0)")
    p.add_argument("--jobs", type=positive_int, metavar="N", help="flights at once (default: one per core)")
    _rate(p)
    p.add_argument("--engine", choices=ENGINES, default="local", help="local processes (default) or Dask (cluster extra)")
    p.add_argument("--scheduler", metavar="ADDRESS", help="Dask scheduler, e.g. tcp://HOST:8786 (default: a local cluster)")
    p.add_argument("--kind", type=_choices(KINDS), metavar="K,...",
                   help=f"the detection campaign instead: these failure kinds ({','.join(KINDS)}) x every rotor")
    p.add_argument("--esc", type=_choices(("on", "off")), default=("on", "off"), metavar="on,off",
                   help="detection campaign: with and/or without ESC telemetry (default on,off)")
    p.add_argument("--speed", type=_speeds, default=(0.0, 3.0), metavar="V,...",
                   help="detection campaign: speeds at the fault in m/s (default 0,3)")
    p.add_argument("--false-alarm-minutes", type=positive_number, default=0.0, metavar="MIN",
                   help="detection campaign: minutes of fault-free agile flight on a sagging battery (default 0); "
                        "without --kind only these")
    p.add_argument("--wind", type=_wind_speed, default=0.0, metavar="M/S",
                   help="detection campaign: mean wind speed, from a bearing drawn per flight (default 0)")
    p.add_argument("--turbulence", type=_choices(TURBULENCE_LEVELS), default=("none",), metavar="LEVEL,...",
                   help=f"detection campaign: Dryden levels ({','.join(TURBULENCE_LEVELS)}; default none); the "
                        "fault-free flights meet a gust every 10 s when the air moves")
    p.add_argument("--profile", type=_choices(SENSOR_PROFILES), default=("ideal",), metavar="P,...",
                   help=f"detection campaign: the FC's sensor profiles ({','.join(SENSOR_PROFILES)}; default ideal)")
    p.add_argument("--sweep", type=_sweep, default=(), metavar="SETTING=V,...",
                   help="detection campaign: fly every flight at each value of this [fault_detector] setting "
                        "(e.g. chi2_min=10,25,50): the latency / false-alarm trade-off, tradeoff.png")
    _lockstep_timeout(p, LOCKSTEP_TIMEOUT_S)
    add_link_arguments(p, "the same for every flight")
    p.set_defaults(func=_campaign)


def _choices(allowed):
    def parse(text: str) -> tuple[str, ...]:
        items = tuple(t.strip() for t in text.split(",") if t.strip())
        bad = [t for t in items if t not in allowed]
        if bad or not items:
            raise argparse.ArgumentTypeError(f"expected a comma-separated list of {', '.join(allowed)}, got {text!r}")
        return items
    return parse


def _wind_speed(text: str) -> float:
    value = number(text)
    if not 0.0 <= value <= WIND_SPEED_MAX_M_S:
        raise argparse.ArgumentTypeError(f"must be within 0..{WIND_SPEED_MAX_M_S:g} m/s, got {text}")
    return value


def _sweep(text: str) -> tuple[tuple[str, float], ...]:
    name, _, values = text.partition("=")
    try:
        numbers = tuple(float(v) for v in values.split(","))
    except ValueError:
        numbers = ()
    if not name.strip().isidentifier() or not numbers or not all(math.isfinite(v) and v >= 0 for v in numbers):
        raise argparse.ArgumentTypeError(f"expected SETTING=V,... with numbers >= 0, e.g. chi2_min=10,25,50, got {text!r}")
    return tuple((name.strip(), v) for v in numbers)


def _speeds(text: str) -> tuple[float, ...]:
    try:
        speeds = tuple(float(t) for t in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated speeds in m/s, got {text!r}") from None
    if not all(0.0 <= v <= 5.0 for v in speeds):
        raise argparse.ArgumentTypeError(f"speeds must be within 0..5 m/s, got {text!r}")
    return speeds


def _campaign(args) -> int:
    from sitl.campaigns.campaign import DEFAULT_OUT, LOSS_LEVELS, run_campaign
    from sitl.campaigns.detection_campaign import DEFAULT_OUT as DETECTION_OUT, WeatherGrid, run_detection_campaign

    losses = tuple(args.loss) if args.loss else LOSS_LEVELS
    detection = bool(args.kind or args.false_alarm_minutes)
    out = args.out or (DETECTION_OUT if detection else DEFAULT_OUT)
    try:
        make_output_dir(out)
        if detection:
            result = run_detection_campaign(out, args.kind or (), args.speed, tuple(e == "on" for e in args.esc), args.seed,
                                            args.false_alarm_minutes, args.jobs, args.rate_hz, args.engine,
                                            args.scheduler, link_of(args),
                                            WeatherGrid(args.wind, args.turbulence, args.profile), args.sweep,
                                            args.lockstep_timeout)
        else:
            result = run_campaign(out, args.samples, args.seed, args.grid, args.jobs, args.rate_hz, losses,
                                  args.engine, args.scheduler, link_of(args), args.lockstep_timeout)
    except FlightError as e:
        raise BadInput(str(e)) from None
    print(result.summary, end="")
    return _report(result.batch)


def _report(batch) -> int:
    """The throughput on stdout; when a flight did not run, one error line and exit code 1."""
    print(batch.throughput())
    if (not_run := batch.not_run()) is None:
        return 0
    print(f"m4-sitl: error: {not_run}", file=sys.stderr)
    return EXIT_FLIGHTS_NOT_RUN
