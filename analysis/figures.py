"""The paper's flight figures from a tlog (analysis.tlog_reader), with matplotlib's Agg backend.

- trajectory: north and east, altitude (each on an axis of its own, so a 3 cm sag shows; the
  companion's reference dashed when its log has one), roll, pitch and tilt, yaw (unwrapped,
  on a panel of its own: a spinning robot's yaw would flatten the others); below, the
  altitude and tilt over ZOOM_BEFORE_S + ZOOM_AFTER_S around the first fault, where a
  detection 40 ms after it stands apart;
- velocities_rates: body-frame velocities (the measured NED velocity rotated by the attitude)
  and body rates;
- actuators: per rotor the thrust the companion commanded (M4_SETPOINT, dashed) against what
  the FC sent its ESC (M4_THRUSTER_STATUS: clamped, or its failsafe's; solid) and the limit it
  knows (dotted; no FC measures delivered thrust); the hips commanded against measured; each
  ESC's speed and current (ESC_TELEMETRY_1_TO_4);
- yaw_rate: the body yaw rate alone;
- wind, when the log holds the companion's disturbance estimate or the simulator's air is given:
  the air's velocity at the robot (the simulator's truth: no robot measures it), the force the
  companion estimated its model misses (NAMED_VALUE_FLOAT dist_*: what the robot itself knows,
  the wind's push among mass and thrust errors), and with the air the hull's speed over the
  ground and through it.
Every time plot marks each fault (red dashed line), its detection (black solid line) and the
latency between them (shaded), named in the legend; a confirmation of the companion's that
detects no known fault (the log does not carry the fault's instant) is a black line too. Legends sit to the right of their panel, outside the data.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from analysis.measures import tilt_deg
from analysis.tlog_reader import FlightRecord, Series
from m4.attitude import rotation_ned_from_frd

Marks = tuple[list[dict], list[tuple[float, int, str]]]     # (faults with their detections, confirmations)
FORMATS = ("png", "pdf", "svg")
ROTOR_COLOURS = ("tab:blue", "tab:orange", "tab:green", "tab:purple")    # no red: the fault mark is red
FAULT_STYLE = {"color": "crimson", "ls": "--", "lw": 1.3}
DETECTION_STYLE = {"color": "black", "ls": "-", "lw": 1.3}        # no data line is black
LATENCY_STYLE = {"color": "crimson", "alpha": 0.15, "lw": 0}   # from a fault to its detection
DPI = 110
POSITION_NAMES = ("north", "east", "altitude")
ZOOM_BEFORE_S, ZOOM_AFTER_S = 0.2, 1.0
FIGURES = ("trajectory", "velocities_rates", "actuators", "yaw_rate")
NED_NAMES = ("north", "east", "down")
ESTIMATE_MEAN_S = 0.5          # the disturbance estimate moves a fraction of each step's innovation: noisy


def _fault_label(f: dict) -> str:
    which = "all rotors" if f["rotor"] == 0 else f"rotor {f['rotor']}"
    return f"fault: {which}, {f.get('kind', 'degraded')} {100 * f['loss']:.0f} % ({f['at_s']:.2f} s)"


def _marks(ax, faults: list[dict], confirmations: list[tuple[float, int, str]]) -> None:
    """Each fault (red dashed), its detection (black) and the latency between them (shaded); a
    confirmation of the companion's that detects no given fault, black as well."""
    detected = set()
    for f in faults:
        ax.axvline(f["at_s"], label=_fault_label(f), **FAULT_STYLE)
        if f.get("detected_at_s") is not None:
            detected.add(round(f["detected_at_s"], 6))
            ax.axvline(f["detected_at_s"], label=f"detected: rotor {f['detected_rotor']} ({f['detected_at_s']:.2f} s)",
                       **DETECTION_STYLE)
            ax.axvspan(f["at_s"], f["detected_at_s"], **LATENCY_STYLE)
    for t_s, rotor, kind in confirmations:
        if round(t_s, 6) not in detected:
            ax.axvline(t_s, label=f"confirmed: rotor {rotor}, {kind} ({t_s:.2f} s)", **DETECTION_STYLE)


def _legend(ax) -> None:
    ax.grid(alpha=0.3)
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0, fontsize=8)


def _mark_panels(axes, marks: Marks) -> None:
    """The marks and a legend on every panel of a time axis shared by `axes`."""
    for ax in axes:
        _marks(ax, *marks)
        _legend(ax)
    axes[-1].set_xlabel("time (s, flight controller clock)")


def _save(fig, path: Path, title: str) -> Path:
    fig.suptitle(title)
    fig.savefig(path, dpi=DPI)
    plt.close(fig)
    return path


def _finish(fig, axes, marks: Marks, path: Path, title: str) -> Path:
    _mark_panels(axes, marks)
    return _save(fig, path, title)


def _figure(rows: int, height: float, **kwargs):
    fig, axes = plt.subplots(rows, 1, figsize=(11, height), sharex=True, layout="constrained", **kwargs)
    return fig, np.atleast_1d(axes)


def _first_mark_s(marks: Marks) -> float | None:
    faults, confirmations = marks
    return faults[0]["at_s"] if faults else confirmations[0][0] if confirmations else None


def _position(ax, record: FlightRecord, axes_ned: tuple[int, ...], window: tuple[float, float] | None = None) -> None:
    """North/east/altitude (the indices of NED in axes_ned), the reference dashed, in `window` (s)."""
    pos = record.position_ned_m
    for i in axes_ned:
        name, sign = POSITION_NAMES[i], -1 if i == 2 else 1
        keep = slice(None) if window is None else (pos.time_s >= window[0]) & (pos.time_s <= window[1])
        line, = ax.plot(pos.time_s[keep], sign * pos.values[keep, i], label=name)
        ref = record.named.get(f"ref_{'ned'[i]}")
        if ref is not None and len(ref):
            keep = slice(None) if window is None else (ref.time_s >= window[0]) & (ref.time_s <= window[1])
            ax.plot(ref.time_s[keep], sign * ref.values[keep, 0], ls="--", lw=1, color=line.get_color(),
                    label=f"{name} reference (centre of mass)")


def trajectory_figure(path: Path, title: str, record: FlightRecord, marks: Marks) -> Path:
    """North and east, altitude, attitude and yaw each on an axis scaled to it (a 3 cm sag shows);
    below, the altitude and tilt around the first fault, where the fault and its detection stand apart."""
    first_s = _first_mark_s(marks)
    fig = plt.figure(figsize=(11, 13 if first_s is not None else 10), layout="constrained")
    grid = fig.add_gridspec(2 if first_s is not None else 1, 1, height_ratios=(4, 1.3)[:1 + (first_s is not None)])
    axes = np.atleast_1d(grid[0].subgridspec(4, 1, height_ratios=(2, 2, 2, 1.5)).subplots(sharex=True))
    att = record.euler_rad
    _position(axes[0], record, (0, 1))
    axes[0].set_ylabel("north, east (m)")
    _position(axes[1], record, (2,))
    axes[1].set_ylabel("altitude (m)")
    for i, name in enumerate(("roll", "pitch")):
        axes[2].plot(att.time_s, np.degrees(att.values[:, i]), label=name)
    axes[2].plot(att.time_s, tilt_deg(att.values), color="tab:gray", lw=1, label="tilt")
    axes[2].set_ylabel("attitude (deg)")
    axes[3].plot(att.time_s, np.degrees(np.unwrap(att.values[:, 2])), color="tab:green", label="yaw")
    axes[3].set_ylabel("yaw (deg, unwrapped)")
    _mark_panels(axes, marks)
    if first_s is not None:
        _zoom(fig.add_subplot(grid[1]), record, marks, (first_s - ZOOM_BEFORE_S, first_s + ZOOM_AFTER_S))
    return _save(fig, path, title)


def _zoom(ax, record: FlightRecord, marks: Marks, window: tuple[float, float]) -> None:
    """Altitude (left) and tilt (right) over `window` around the first fault."""
    _position(ax, record, (2,), window)
    ax.set_ylabel("altitude (m)")
    att = record.euler_rad
    keep = (att.time_s >= window[0]) & (att.time_s <= window[1])
    tilt_ax = ax.twinx()
    tilt_ax.plot(att.time_s[keep], tilt_deg(att.values[keep]), color="tab:gray", lw=1, label="tilt")
    tilt_ax.set_ylabel("tilt (deg)")
    _marks(ax, *marks)
    ax.set_xlim(*window)
    ax.set_title("around the fault", fontsize=9)
    ax.set_xlabel("time (s, flight controller clock)")
    lines = ax.get_legend_handles_labels()
    tilt_lines = tilt_ax.get_legend_handles_labels()
    ax.legend(lines[0] + tilt_lines[0], lines[1] + tilt_lines[1], loc="upper left", bbox_to_anchor=(1.06, 1.0),
              borderaxespad=0.0, fontsize=8)
    ax.grid(alpha=0.3)


def body_velocities(record: FlightRecord) -> Series:
    """The measured NED velocity in the body frame FRD, at the velocity's instants."""
    vel, att = record.velocity_ned_m_s, record.euler_rad
    euler = np.column_stack([np.interp(vel.time_s, att.time_s, np.unwrap(att.values[:, i])) for i in range(3)])
    return Series(vel.time_s, np.array([rotation_ned_from_frd(e).T @ v for e, v in zip(euler, vel.values)]))


def velocities_rates_figure(path: Path, title: str, record: FlightRecord, marks: Marks) -> Path:
    fig, axes = _figure(2, 7)
    body = body_velocities(record)
    for i, name in enumerate(("u (forward)", "v (right)", "w (down)")):
        axes[0].plot(body.time_s, body.values[:, i], label=name)
    axes[0].set_ylabel("body velocity (m/s)")
    rates = record.rates_frd_rad_s
    for i, name in enumerate(("p (roll)", "q (pitch)", "r (yaw)")):
        axes[1].plot(rates.time_s, rates.values[:, i], label=name)
    axes[1].set_ylabel("body rates (rad/s)")
    return _finish(fig, axes, marks, path, title)


def actuators_figure(path: Path, title: str, record: FlightRecord, marks: Marks) -> Path:
    """Thrusts, hips, and what the ESCs measure: speed and current (a stopped motor's fall to zero,
    a lost propeller's overspeed)."""
    fig, axes = _figure(4, 13, height_ratios=(3, 2, 2, 2))
    for i, colour in enumerate(ROTOR_COLOURS):
        n = i + 1
        axes[0].plot(record.thrust_cmd_n.time_s, record.thrust_cmd_n.values[:, i], color=colour,
                     label=f"rotor {n} to the ESC (FC)")
        axes[0].plot(record.setpoint_thrust_n.time_s, record.setpoint_thrust_n.values[:, i], color=colour, ls="--",
                     lw=1, label=f"rotor {n} commanded (companion)")
        axes[0].plot(record.thrust_limit_n.time_s, record.thrust_limit_n.values[:, i], color=colour, ls=":", lw=1,
                     label=f"rotor {n} limit")
        axes[1].plot(record.hip_rad.time_s, np.degrees(record.hip_rad.values[:, i]), color=colour,
                     label=f"hip {n} measured")
        axes[1].plot(record.setpoint_hip_rad.time_s, np.degrees(record.setpoint_hip_rad.values[:, i]), color=colour,
                     ls="--", lw=1, label=f"hip {n} commanded")
        axes[2].plot(record.esc_rpm.time_s, record.esc_rpm.values[:, i], color=colour, label=f"ESC {n}")
        axes[3].plot(record.esc_current_a.time_s, record.esc_current_a.values[:, i], color=colour, label=f"ESC {n}")
    axes[0].set_ylabel("thrust (N)")
    axes[1].set_ylabel("hip angle (deg)")
    axes[2].set_ylabel("ESC speed (rpm)")
    axes[3].set_ylabel("ESC current (A)")
    if not len(record.esc_rpm):
        for ax in axes[2:]:
            ax.text(0.5, 0.5, "no ESC telemetry in this log", transform=ax.transAxes, ha="center", va="center")
    return _finish(fig, axes, marks, path, title)


def yaw_rate_figure(path: Path, title: str, record: FlightRecord, marks: Marks) -> Path:
    fig, axes = _figure(1, 4)
    rates = record.rates_frd_rad_s
    axes[0].plot(rates.time_s, rates.values[:, 2], color="tab:green", label="yaw rate r")
    axes[0].set_ylabel("yaw rate (rad/s)")
    return _finish(fig, axes, marks, path, title)


def disturbance_force_ned_n(record: FlightRecord) -> Series | None:
    """The companion's disturbance force estimate, NED N (None: its log holds none)."""
    axes = [record.named.get(f"dist_{axis}") for axis in "ned"]
    if any(a is None or not len(a) for a in axes):
        return None
    t = axes[0].time_s
    return Series(t, np.column_stack([np.interp(t, a.time_s, a.values[:, 0]) for a in axes]))


def _running_mean(series: Series, span_s: float) -> Series:
    """The mean of each column over the span_s before each instant (fewer samples at the start)."""
    t, v = series.time_s, series.values
    first = np.searchsorted(t, t - span_s, side="right")
    total = np.vstack([np.zeros((1, v.shape[1])), np.cumsum(v, axis=0)])
    count = (np.arange(len(t)) + 1 - first)[:, None]
    return Series(t, (total[1:] - total[first]) / count)


def wind_figure(path: Path, title: str, record: FlightRecord, marks: Marks, air: Series | None) -> Path:
    """The air (truth, when given), the companion's disturbance estimate, the hull's speeds."""
    estimate = disturbance_force_ned_n(record)
    fig, axes = _figure(1 + 2 * (air is not None), 9 if air is not None else 4)
    panels = iter(axes)
    if air is not None:
        ax = next(panels)
        for i, name in enumerate(NED_NAMES):
            ax.plot(air.time_s, air.values[:, i], label=name)
        ax.set_ylabel("air velocity (m/s, NED)")
        ax.set_title("the air at the robot: the simulator's truth (no robot measures it)", fontsize=9)
    ax = next(panels)
    if estimate is None:
        ax.text(0.5, 0.5, "no disturbance estimate in this log", transform=ax.transAxes, ha="center", va="center")
    else:
        mean = _running_mean(estimate, ESTIMATE_MEAN_S)
        for i, name in enumerate(NED_NAMES):
            line, = ax.plot(mean.time_s, mean.values[:, i], lw=1.8, label=f"{name}, {ESTIMATE_MEAN_S:g} s mean")
            ax.plot(estimate.time_s, estimate.values[:, i], lw=0.6, alpha=0.35, color=line.get_color(),
                    label=f"{name}, each step")
    ax.set_ylabel("force (N, NED)")
    ax.set_title("what the companion estimated its model misses (wind, mass and thrust errors): "
                 "what the robot knows", fontsize=9)
    if air is not None:
        ax = next(panels)
        vel = record.velocity_ned_m_s
        air_then = np.column_stack([np.interp(vel.time_s, air.time_s, air.values[:, i]) for i in range(3)])
        ax.plot(vel.time_s, np.linalg.norm(vel.values, axis=1), label="over the ground")
        ax.plot(vel.time_s, np.linalg.norm(vel.values - air_then, axis=1), label="through the air (truth's air)")
        ax.set_ylabel("hull speed (m/s)")
    return _finish(fig, axes, marks, path, title)


def draw(record: FlightRecord, out_dir: Path, title: str, faults: list[dict], fmt: str = "png",
         air: Series | None = None) -> list[Path]:
    """Every figure of FIGURES as out_dir/<name>.<fmt>, and wind.<fmt> when the record has the
    companion's disturbance estimate or `air` (the simulator's truth) is given; `faults`:
    analysis.flight_metrics.detections(). The companion's confirmations come from the record."""
    if fmt not in FORMATS:
        raise ValueError(f"unknown figure format {fmt!r}; choose from {', '.join(FORMATS)}")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    draw_one = {"trajectory": trajectory_figure, "velocities_rates": velocities_rates_figure,
                "actuators": actuators_figure, "yaw_rate": yaw_rate_figure}
    marks = (faults, record.confirmations())
    paths = [draw_one[name](out_dir / f"{name}.{fmt}", title, record, marks) for name in FIGURES]
    if air is not None or disturbance_force_ned_n(record) is not None:
        paths.append(wind_figure(out_dir / f"wind.{fmt}", title, record, marks, air))
    return paths
