"""`m4-companion plot FLIGHT.tlog`: the paper's figures and the telemetry metrics of any
flight's tlog (the companion's flight log, `m4-sitl serve --tlog`, a ground station's), on a
laptop without MuJoCo: `pip install "m4-fault-recovery[plot]"`.

    m4-companion plot FLIGHT.tlog [--out DIR] [--format png|pdf|svg] [--fault AT_S:ROTOR[:LOSS]]...

Writes DIR/metrics.json (analysis.flight_metrics: fly's keys where both have them) and
DIR/{trajectory, velocities_rates, actuators, yaw_rate}.FORMAT (analysis.figures), and
DIR/wind.FORMAT when the log holds the companion's disturbance estimate: beside it, for a
simulated flight, the air's velocity from the simulator's truth.npz in the tlog's folder or
the one above (`m4-sitl fly --out DIR`'s layout; analysis.sim_truth). DIR defaults to a
folder beside the tlog, named after it. The faults are the tlog's own (the
flight controller's announcements, accepted commands: analysis.tlog_reader) and the
companion's confirmations; `--fault` adds one the log does not carry (a rotor cut by hand),
at AT_S seconds of the flight controller's clock: a degraded motor, LOSS as in a scenario
file (its ceiling (1 - LOSS) x the default airframe's hover thrust, against which
analysis.detection judges the companion's detection). Without any fault the metrics count
"after the fault" from the companion's first confirmation, and say so.

A tlog with bytes that make no whole record (cut short) is read up to them with a warning;
an --out that is a file or cannot be made, and a file that is no tlog, end in one line.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from m4 import extras

EXIT_BAD_INPUT = 2


def _fault(text: str):
    from analysis.detection import Fault

    parts = text.split(":")
    try:
        at_s, rotor, loss = float(parts[0]), int(parts[1]), float(parts[2]) if len(parts) > 2 else 1.0
    except (ValueError, IndexError):
        raise argparse.ArgumentTypeError(f"expected AT_S:ROTOR[:LOSS], e.g. 1.0:4, got {text!r}") from None
    if len(parts) > 3 or not 0 <= rotor <= 4 or not 0.0 <= loss <= 1.0 or at_s < 0:
        raise argparse.ArgumentTypeError(f"expected AT_S >= 0, ROTOR 0..4, LOSS 0..1, got {text!r}")
    return Fault(at_s, rotor, loss)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("tlog", type=Path, metavar="FLIGHT.tlog", help="the flight's tlog")
    p.add_argument("--out", type=Path, metavar="DIR", help="output folder (default: beside the tlog, named after it)")
    p.add_argument("--format", choices=("png", "pdf", "svg"), default="png", help="figure format (default png)")
    p.add_argument("--fault", type=_fault, action="append", default=[], metavar="AT_S:ROTOR[:LOSS]",
                   help="a fault the tlog does not show (repeat for more)")


def run(args: argparse.Namespace) -> int:
    if hint := extras.extra_hint("m4-companion plot", "plot", extras.PLOT):
        return _error(hint)
    from analysis.figures import draw
    from analysis.flight_metrics import telemetry_metrics
    from analysis.measures import rounded
    from analysis.sim_truth import air_velocity, truth_beside
    from analysis.tlog_reader import read_tlog
    from m4.airframe import load_airframe

    if not args.tlog.is_file():
        return _error(f"no such tlog: {args.tlog}")
    out = args.out or args.tlog.with_suffix("")
    if out.exists() and not out.is_dir():
        return _error(f"--out {out}: exists and is not a folder")
    try:
        record = read_tlog(args.tlog)
        if record.unread_bytes == args.tlog.stat().st_size:
            return _error(f"{args.tlog}: not a tlog (no MAVLink packet in it)")
        faults = sorted([*record.injected, *args.fault], key=lambda f: f.at_s)
        metrics = rounded(telemetry_metrics(record, faults, load_airframe()))
        truth = truth_beside(args.tlog)
        air = None if truth is None else air_velocity(truth)
    except (OSError, ValueError) as e:
        return _error(f"{args.tlog}: {e}")
    if record.unread_bytes:
        _warn(f"{args.tlog}: {record.unread_bytes} bytes are no whole record (a file cut short?): "
              f"read up to t = {record.duration_s:.2f} s")
    if (origin := metrics["measured_from"])["what"] != "fault":
        _warn(f"{args.tlog}: no fault instant in the log: \"after the fault\" counts from the "
              f"{origin['what']} (t = {origin['at_s']:.2f} s); --fault AT_S:ROTOR gives it")
    try:
        out.mkdir(parents=True, exist_ok=True)
        (out / "metrics.json").write_text(json.dumps(metrics, indent=2) + "\n")
        paths = draw(record, out, args.tlog.name, metrics["faults"], args.format, air=air)
    except OSError as e:
        return _error(f"--out {out}: cannot write there ({e.strerror or e})")
    print(f"{args.tlog}: {record.duration_s:.1f} s of flight -> {out}/metrics.json, "
          + ", ".join(p.name for p in paths))
    return 0


def _error(text: str) -> int:
    print(f"m4-companion: error: {text}", file=sys.stderr)
    return EXIT_BAD_INPUT


def _warn(text: str) -> None:
    print(f"m4-companion: warning: {text}", file=sys.stderr)
