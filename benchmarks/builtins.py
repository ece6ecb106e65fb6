"""Every built-in scenario flown, and flights compared side by side: how a change is shown to keep the figures.

    python -m benchmarks.builtins fly OUT [--scenario NAME]... [--rate-hz HZ]
    python -m benchmarks.builtins table DIR [DIR...]

`fly` flies each built-in scenario (`m4-sitl list`; or only those named) in lockstep, as
`m4-sitl fly NAME --out OUT/NAME` does but without figures, one after another, and prints
one line a flight. `table` reads folders of such flights (one flight a sub-folder, by
scenario name: the first DIR is the reference) and prints a Markdown table, one row a
scenario, each cell the DIRs' values side by side: survived (or the checks it failed), the
altitude lost, the largest tilt after the fault, the position RMSE, the touchdown speed and
the instant each fault was named; the last column says whether a flight is the reference's
bit for bit (its truth.npz, and its metrics.json but for the timing figures) or which arrays
and metrics differ. It exits 1 if a scenario is missing from a DIR or a flight failed.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from m4.toml_fields import ConfigError
from sitl import scenarios
from sitl.flights.flight_run import FlightError, FlightOptions
from sitl.flights.fly import fly
from sitl.plant.truth import load_truth, truth_differences

# metrics.json keys that measure the machine, not the flight (compared nowhere)
TIMING_KEYS = frozenset({"realtime_factor", "solve_ms_median", "solve_ms_p99"})
_FIGURES = (("altitude_loss_m", "sag (m)", "{:.3f}"), ("max_tilt_deg_after_fault", "tilt (deg)", "{:.1f}"),
            ("position_rmse_m", "position RMSE (m)", "{:.3f}"), ("touchdown_speed_m_s", "touchdown (m/s)", "{:.3f}"))


def fly_all(out: Path, names: list[str], rate_hz: float | None) -> bool:
    """Fly `names` into out/NAME; a line a flight; False if one could not fly."""
    ok = True
    for name in names:
        try:
            m = fly(name, out / name, FlightOptions(rate_hz=rate_hz), figures=False, progress=False)
        except (ConfigError, FlightError) as e:
            print(f"{name}: error: {e}", flush=True)
            ok = False
            continue
        print(f"{name}: survived {m['survived']}, sag {m['altitude_loss_m']:.3f} m, "
              f"{m['realtime_factor']:.1f}x real time", flush=True)
    return ok


def load_metrics(flight: Path) -> dict | None:
    path = flight / "metrics.json"
    return json.loads(path.read_text()) if path.exists() else None


def survived_cell(m: dict | None) -> str:
    if m is None:
        return "missing"
    if m["survived"]:
        return "yes"
    return "**no** (" + ", ".join(k for k, v in m["checks"].items() if v is False) + ")"


def detected_cell(m: dict | None) -> str:
    if m is None or not m.get("faults"):
        return "-"
    return ", ".join("-" if f.get("detected_at_s") is None else f"{f['detected_at_s']:.2f}" for f in m["faults"])


def figure_cell(m: dict | None, key: str, fmt: str) -> str:
    value = None if m is None else m.get(key)
    return "-" if value is None else fmt.format(value)


def without_timing(value):
    """The metrics with the machine's figures left out, at every depth."""
    if isinstance(value, dict):
        return {k: without_timing(v) for k, v in value.items() if k not in TIMING_KEYS}
    if isinstance(value, list):
        return [without_timing(v) for v in value]
    return value


def differences(reference: Path, flight: Path) -> list[str]:
    """What differs between two flights of a scenario: truth arrays and top-level metrics (empty: bit for bit)."""
    found = sorted(truth_differences(load_truth(reference / "truth.npz"), load_truth(flight / "truth.npz")))
    ma, mb = without_timing(load_metrics(reference)), without_timing(load_metrics(flight))
    if ma is None or mb is None:
        return [*found, "metrics.json missing"]
    found += sorted(f"metrics.{k}" for k in set(ma) | set(mb) if ma.get(k) != mb.get(k))
    return found


def same_cell(reference: Path, flight: Path) -> str:
    if not (flight / "truth.npz").exists() or not (reference / "truth.npz").exists():
        return "-"
    found = differences(reference, flight)
    return "identical" if not found else "differs: " + ", ".join(found)


def table(dirs: list[Path]) -> tuple[list[str], bool]:
    """The Markdown table's lines, and whether every DIR holds every scenario, flown to the end."""
    names = sorted({p.name for d in dirs for p in d.iterdir() if (p / "metrics.json").exists()})
    lines = ["| scenario | survived | " + " | ".join(title for _, title, _ in _FIGURES)
             + " | detected at (s) | against the first |",
             "|---" * (len(_FIGURES) + 4) + "|"]
    complete = True
    for name in names:
        ms = [load_metrics(d / name) for d in dirs]
        complete &= all(m is not None and m["completed"] for m in ms)
        cells = [" / ".join(survived_cell(m) for m in ms)]
        cells += [" / ".join(figure_cell(m, key, fmt) for m in ms) for key, _, fmt in _FIGURES]
        cells.append(" / ".join(detected_cell(m) for m in ms))
        cells.append(" / ".join(same_cell(dirs[0] / name, d / name) for d in dirs[1:]) or "-")
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return lines, complete


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.builtins", description=__doc__.splitlines()[0])
    commands = parser.add_subparsers(dest="command", required=True)
    p = commands.add_parser("fly", help="fly every built-in scenario (or those named) into OUT/NAME")
    p.add_argument("out", type=Path, metavar="OUT")
    p.add_argument("--scenario", action="append", metavar="NAME", help="only this built-in; repeat (default: all)")
    p.add_argument("--rate-hz", type=float, help="the companion's control rate (default: its own)")
    p = commands.add_parser("table", help="flights' figures side by side, the first DIR the reference")
    p.add_argument("dirs", type=Path, nargs="+", metavar="DIR")
    args = parser.parse_args(argv)
    if args.command == "fly":
        known = scenarios.builtin_names()
        unknown = [n for n in args.scenario or () if n not in known]
        if unknown:
            parser.error(f"not a built-in scenario: {', '.join(unknown)} (m4-sitl list)")
        return 0 if fly_all(args.out, args.scenario or list(known), args.rate_hz) else 1
    missing = [str(d) for d in args.dirs if not d.is_dir()]
    if missing:
        parser.error(f"not a folder: {', '.join(missing)}")
    lines, complete = table(args.dirs)
    print("\n".join(lines))
    return 0 if complete else 1


if __name__ == "__main__":
    sys.exit(main())
