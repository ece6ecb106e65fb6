"""The paper's flight figures from a tlog (analysis.tlog_reader), with matplotlib's Agg backend.

- trajectory: position (north, east, altitude; the companion's reference dashed when its log
  has one), roll and pitch, yaw (unwrapped, on a panel of its own: a spinning robot's yaw
  would flatten the others);
- velocities_rates: body-frame velocities (the measured NED velocity rotated by the attitude)
  and body rates;
- actuators: per rotor the thrust the companion commanded (M4_SETPOINT, dashed) against what
  the FC sent its ESC (M4_THRUSTER_STATUS: clamped, or its failsafe's; solid) and the limit it
  knows (dotted; no FC measures delivered thrust); the hips commanded against measured;
- yaw_rate: the body yaw rate alone.
Every time plot marks each fault (red dashed line) and its detection (black solid line), both
named in the legend. Legends sit to the right of their panel, outside the data.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from analysis.tlog_reader import FlightRecord, Series
from m4.attitude import rotation_ned_from_frd

FORMATS = ("png", "pdf", "svg")
ROTOR_COLOURS = ("tab:blue", "tab:orange", "tab:green", "tab:purple")    # no red: the fault mark is red
FAULT_STYLE = {"color": "crimson", "ls": "--", "lw": 1.3}
DETECTION_STYLE = {"color": "black", "ls": "-", "lw": 1.3}        # no data line is black
DPI = 110
FIGURES = ("trajectory", "velocities_rates", "actuators", "yaw_rate")


def _marks(ax, faults: list[dict]) -> None:
    for f in faults:
        which = "all rotors" if f["rotor"] == 0 else f"rotor {f['rotor']}"
        ax.axvline(f["at_s"], label=f"fault: {which}, {100 * f['loss']:.0f} % ({f['at_s']:.2f} s)", **FAULT_STYLE)
        if f.get("detected_at_s") is not None:
            ax.axvline(f["detected_at_s"], label=f"detected: rotor {f['detected_rotor']} ({f['detected_at_s']:.2f} s)",
                       **DETECTION_STYLE)


def _finish(fig, axes, faults: list[dict], path: Path, title: str) -> Path:
    for ax in axes:
        _marks(ax, faults)
        ax.grid(alpha=0.3)
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0, fontsize=8)
    axes[-1].set_xlabel("time (s, flight controller clock)")
    fig.suptitle(title)
    fig.savefig(path, dpi=DPI)
    plt.close(fig)
    return path


def _figure(rows: int, height: float, **kwargs):
    fig, axes = plt.subplots(rows, 1, figsize=(11, height), sharex=True, layout="constrained", **kwargs)
    return fig, np.atleast_1d(axes)


def trajectory_figure(path: Path, title: str, record: FlightRecord, faults: list[dict]) -> Path:
    fig, axes = _figure(3, 9, height_ratios=(3, 3, 2))
    pos, att = record.position_ned_m, record.euler_rad
    for i, (name, sign) in enumerate((("north", 1), ("east", 1), ("altitude", -1))):
        line, = axes[0].plot(pos.time_s, sign * pos.values[:, i], label=name)
        ref = record.named.get(f"ref_{'ned'[i]}")
        if ref is not None and len(ref):
            axes[0].plot(ref.time_s, sign * ref.values[:, 0], ls="--", lw=1, color=line.get_color(),
                         label=f"{name} reference (centre of mass)")
    axes[0].set_ylabel("position (m)")
    for i, name in enumerate(("roll", "pitch")):
        axes[1].plot(att.time_s, np.degrees(att.values[:, i]), label=name)
    axes[1].set_ylabel("roll, pitch (deg)")
    axes[2].plot(att.time_s, np.degrees(np.unwrap(att.values[:, 2])), color="tab:green", label="yaw")
    axes[2].set_ylabel("yaw (deg, unwrapped)")
    return _finish(fig, axes, faults, path, title)


def body_velocities(record: FlightRecord) -> Series:
    """The measured NED velocity in the body frame FRD, at the velocity's instants."""
    vel, att = record.velocity_ned_m_s, record.euler_rad
    euler = np.column_stack([np.interp(vel.time_s, att.time_s, np.unwrap(att.values[:, i])) for i in range(3)])
    return Series(vel.time_s, np.array([rotation_ned_from_frd(e).T @ v for e, v in zip(euler, vel.values)]))


def velocities_rates_figure(path: Path, title: str, record: FlightRecord, faults: list[dict]) -> Path:
    fig, axes = _figure(2, 7)
    body = body_velocities(record)
    for i, name in enumerate(("u (forward)", "v (right)", "w (down)")):
        axes[0].plot(body.time_s, body.values[:, i], label=name)
    axes[0].set_ylabel("body velocity (m/s)")
    rates = record.rates_frd_rad_s
    for i, name in enumerate(("p (roll)", "q (pitch)", "r (yaw)")):
        axes[1].plot(rates.time_s, rates.values[:, i], label=name)
    axes[1].set_ylabel("body rates (rad/s)")
    return _finish(fig, axes, faults, path, title)


def actuators_figure(path: Path, title: str, record: FlightRecord, faults: list[dict]) -> Path:
    fig, axes = _figure(2, 8)
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
    axes[0].set_ylabel("thrust (N)")
    axes[1].set_ylabel("hip angle (deg)")
    return _finish(fig, axes, faults, path, title)


def yaw_rate_figure(path: Path, title: str, record: FlightRecord, faults: list[dict]) -> Path:
    fig, axes = _figure(1, 4)
    rates = record.rates_frd_rad_s
    axes[0].plot(rates.time_s, rates.values[:, 2], color="tab:green", label="yaw rate r")
    axes[0].set_ylabel("yaw rate (rad/s)")
    return _finish(fig, axes, faults, path, title)


def draw(record: FlightRecord, out_dir: Path, title: str, faults: list[dict], fmt: str = "png") -> list[Path]:
    """Every figure of FIGURES as out_dir/<name>.<fmt>; `faults`: analysis.flight_metrics.detections()."""
    if fmt not in FORMATS:
        raise ValueError(f"unknown figure format {fmt!r}; choose from {', '.join(FORMATS)}")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    draw_one = {"trajectory": trajectory_figure, "velocities_rates": velocities_rates_figure,
                "actuators": actuators_figure, "yaw_rate": yaw_rate_figure}
    return [draw_one[name](out_dir / f"{name}.{fmt}", title, record, faults) for name in FIGURES]
