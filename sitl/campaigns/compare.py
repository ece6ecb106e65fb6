"""`m4-sitl compare`: posture manipulation against the fixed posture, side by side.

Flies every scenario of COMPARED with both controllers (the NMPC over thrust and hips, and
the same NMPC with every hip pinned at the nominal angle), in parallel, and writes
comparison.md (the Markdown table the README shows) and comparison.json (every flight's
metrics) into the output folder; each flight keeps its own folder with its figures.
"""

from __future__ import annotations

import json
from pathlib import Path

from sitl.flights.flight_run import CONTROLLERS, FlightOptions
from sitl.links.emulation import LinkEmulation
from sitl.campaigns.parallel import Batch, FlightJob, fly_all

COMPARED = ("hover-rotor-loss", "forward-flight-fault", "waypoint-loe", "hover-rotor-loss-tight")
DEFAULT_OUT = Path("runs") / "compare"

COLUMNS = (                  # header, metrics.json key, number format
    ("survived", "survived", ""),
    ("altitude loss (m)", "altitude_loss_m", ".2f"),
    ("max tilt after fault (deg)", "max_tilt_deg_after_fault", ".0f"),
    ("time to yaw saturation (s)", "time_to_yaw_saturation_s", ".2f"),
    ("final yaw rate (rad/s)", "yaw_rate_final_rad_s", ".1f"),
    ("largest thrust (N)", "max_thrust_n", ".1f"),
    ("position RMSE (m)", "position_rmse_m", ".2f"),
)


def _cell(value, number_format: str) -> str:
    if isinstance(value, bool):
        return "yes" if value else "**no**"
    return "-" if value is None else format(value, number_format)


def markdown_table(rows: list[dict]) -> str:
    """One line per flight; a flight that failed to run shows its error."""
    head = ["scenario", "controller"] + [header for header, _, _ in COLUMNS]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for m in rows:
        if "error" in m:
            cells = [m["scenario"], m["controller"], f"not flown: {m['error']}"] + [""] * (len(COLUMNS) - 1)
        else:
            cells = [m["scenario"], m["controller"]] + [_cell(m[key], fmt) for _, key, fmt in COLUMNS]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def compare(out_dir: Path = DEFAULT_OUT, scenarios: tuple[str, ...] = COMPARED, workers: int | None = None,
            rate_hz: float | None = None, link: LinkEmulation | None = None) -> tuple[str, Batch]:
    """The Markdown table (also in comparison.md) and the flights as flown; `link`: the
    companion's link impaired (emulated in lockstep)."""
    out_dir = Path(out_dir)
    pairs = [(s, c) for s in scenarios for c in CONTROLLERS]
    jobs = [FlightJob(s, out_dir / f"{s}-{c}", FlightOptions(controller=c, rate_hz=rate_hz, link=link), figures=True)
            for s, c in pairs]
    batch = fly_all(jobs, workers, "compare")
    results = [{"scenario": s, "controller": c, **m} for (s, c), m in zip(pairs, batch.results)]
    table = markdown_table(results)
    rate_text = "the companion's default rate" if rate_hz is None else f"{rate_hz:g} Hz"
    link_text = "" if link is None else f", link {link.describe()} (emulated in lockstep)"
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "comparison.md").write_text(
        f"Posture manipulation (nmpc) against the fixed posture (fixed-posture), control at {rate_text}{link_text}; "
        "regenerate with `m4-sitl compare`.\n\n" + table)
    (out_dir / "comparison.json").write_text(json.dumps(results, indent=2) + "\n")
    return table, batch
