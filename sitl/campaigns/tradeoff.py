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


def draw_tradeoff(rows: list[dict], path: Path) -> list[TradeoffPoint]:
    """tradeoff.png at path: latency (median, the bar up to the worst) against false alarms per hour."""
    points = tradeoff_points(rows)
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    x = np.array([p.alarms_per_hour for p in points])
    median = np.array([p.latency_median_s for p in points])
    worst = np.array([p.latency_worst_s for p in points])
    ax.errorbar(x, median, yerr=[np.zeros_like(median), worst - median], fmt="o-", capsize=4,
                label="latency: median, bar to the worst")
    for p in points:
        label = f"{p.value:g}" + " (default)" * p.default + (f" ({p.missed} missed)" if p.missed else "")
        ax.annotate(label, (p.alarms_per_hour, p.latency_median_s), textcoords="offset points", xytext=(6, -12),
                    fontsize=8, fontweight="bold" if p.default else "normal")
    marked = [p for p in points if p.default]
    if marked:
        ax.plot([p.alarms_per_hour for p in marked], [p.latency_median_s for p in marked], "o", markersize=13,
                markerfacecolor="none", markeredgecolor="tab:red", label="the companion's default")
    ax.set_xlabel("false alarms per hour of flight")
    ax.set_ylabel("detection latency (s)")
    ax.set_title(f"trade-off as {points[0].setting if points else 'the setting'} moves (labels: its value)")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return points
