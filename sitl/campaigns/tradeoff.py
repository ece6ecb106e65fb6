"""The detector's latency against its false-alarm rate as one of its settings moves: the
trade-off of a detection campaign with a sweep (sitl.campaigns.detection_campaign).

For each value of the swept setting: the detection latency of the faulted flights (median and
worst over those detected), the flights not detected, and the false alarms per hour of flight
(confirmations before the fault, over the time flown before it: the fault-free flights whole
and the faulted ones up to their fault). The value the companion flies with (its deployed
configuration, deploy/companion.toml) is marked. Drawn with matplotlib's Agg backend (no display).
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from sitl.campaigns.detection_campaign import alarms_per_hour  # noqa: E402

DEPLOYED_CONFIG = Path(__file__).resolve().parents[2] / "deploy" / "companion.toml"


@dataclass(frozen=True)
class TradeoffPoint:
    setting: str
    value: float
    latency_median_s: float        # NaN: nothing detected
    latency_worst_s: float
    missed: int                    # faulted flights not detected
    alarms_per_hour: float
    hours: float                   # flown before the faults
    default: bool = False          # the value the companion flies with


def deployed_value(setting: str, config: Path = DEPLOYED_CONFIG) -> float | None:
    """The [fault_detector] setting's value in the companion's deployed configuration (None: not there)."""
    try:
        value = tomllib.loads(config.read_text()).get("fault_detector", {}).get(setting)
    except (OSError, tomllib.TOMLDecodeError):
        return None
    return float(value) if isinstance(value, (int, float)) else None


def tradeoff_points(rows: list[dict]) -> list[TradeoffPoint]:
    """One point per value of the swept setting, in increasing order (rows without a setting
    are not part of the sweep, stalled flights are left out as in the detection table)."""
    swept = [r for r in rows if r.get("setting") and not r.get("error") and not r.get("stalled")]
    default = deployed_value(swept[0]["setting"]) if swept else None
    points = []
    for value in sorted({r["setting_value"] for r in swept}):
        g = [r for r in swept if r["setting_value"] == value]
        latency = [r["latency_s"] for r in g if r["kind"] and r.get("latency_s") is not None]
        points.append(TradeoffPoint(
            setting=g[0]["setting"], value=value,
            latency_median_s=float(np.median(latency)) if latency else float("nan"),
            latency_worst_s=max(latency) if latency else float("nan"),
            missed=sum(1 for r in g if r["kind"] and not r.get("detected")),
            alarms_per_hour=alarms_per_hour(g), hours=sum(r.get("flown_before_fault_s", 0.0) for r in g) / 3600.0,
            default=value == default))
    return points


def tradeoff_markdown(points: list[TradeoffPoint]) -> str:
    lines = ["| setting | latency median / worst (s) | not detected | false alarms per hour | hours flown before the fault |",
             "|---|---|---|---|---|"]
    lines += [f"| {p.setting} = {p.value:g}{' (default)' * p.default} | {p.latency_median_s:.2f} / {p.latency_worst_s:.2f} | {p.missed} | "
              f"{p.alarms_per_hour:.1f} | {p.hours:.2f} |" for p in points]
    return "\n".join(lines) + "\n"


def point_labels(points: list[TradeoffPoint]) -> dict[tuple[float, float], str]:
    """The label of each spot (false alarms per hour, median latency): the values that land on it,
    in order, the default and the faults missed said."""
    labels: dict[tuple[float, float], list[str]] = {}
    for p in points:
        labels.setdefault((p.alarms_per_hour, p.latency_median_s), []).append(
            f"{p.value:g}" + " (default)" * p.default + (f" ({p.missed} missed)" if p.missed else ""))
    return {spot: ", ".join(names) for spot, names in labels.items()}


def draw_tradeoff(rows: list[dict], path: Path) -> list[TradeoffPoint]:
    """tradeoff.png at path. Left: latency (median, the bar up to the worst) against false alarms
    per hour, values that land on one point named together. Right: both against the setting's
    value, so the figure still reads where every value raised the same number of alarms."""
    points = tradeoff_points(rows)
    setting = points[0].setting if points else "the setting"
    fig, (ax, by) = plt.subplots(1, 2, figsize=(11.0, 4.2))
    x = np.array([p.alarms_per_hour for p in points])
    value = np.array([p.value for p in points])
    median = np.array([p.latency_median_s for p in points])
    bar = [np.zeros_like(median), np.array([p.latency_worst_s for p in points]) - median]
    ax.errorbar(x, median, yerr=bar, fmt="o-", capsize=4, label="latency: median, bar to the worst")
    for spot, label in point_labels(points).items():
        ax.annotate(label, spot, textcoords="offset points", xytext=(6, -12), fontsize=8,
                    fontweight="bold" if "(default)" in label else "normal")
    marked = [p for p in points if p.default]
    if marked:
        ax.plot([p.alarms_per_hour for p in marked], [p.latency_median_s for p in marked], "o", markersize=13,
                markerfacecolor="none", markeredgecolor="tab:red", label="the companion's default")
        by.axvline(marked[0].value, color="tab:red", linestyle=":", label="the companion's default")
    ax.set_xlabel("false alarms per hour of flight")
    ax.set_ylabel("detection latency (s)")
    ax.set_title(f"trade-off as {setting} moves (labels: its value)", fontsize=10)
    by.errorbar(value, median, yerr=bar, fmt="o-", capsize=4, label="latency: median, bar to the worst")
    by.set_xlabel(setting)
    by.set_ylabel("detection latency (s)")
    alarms = by.twinx()
    alarms.plot(value, x, "s--", color="tab:orange", label="false alarms per hour")
    alarms.set_ylabel("false alarms per hour of flight")
    most = max(1.0, 1.1 * float(np.nanmax(x))) if points else 1.0
    ax.set_xlim(-0.05 * most, most)
    alarms.set_ylim(0.0, most)
    by.set_title(f"each against {setting}", fontsize=10)
    for a in (ax, by):
        a.grid(True, alpha=0.3)
    ax.legend(loc="upper right", fontsize=8)
    handles = [h for a in (by, alarms) for h in a.get_legend_handles_labels()[0]]
    by.legend(handles, [h.get_label() for h in handles], loc="upper left", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return points
