"""Figures and metrics from a tlog alone (analysis/, `m4-companion plot`), on a synthetic flight:
rotor 4 cut by command at 1 s, detected at 1.06 s, the robot sags 0.1 m, tilts and spins up."""

from __future__ import annotations

import json
import math
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from analysis.figures import body_velocities, draw
from analysis.flight_metrics import telemetry_metrics
from analysis.detection import Fault
from analysis.tlog_reader import read_tlog
from companion.cli import main
from m4.airframe import load_airframe
from m4.mavlink import mavlink, new_mav
from m4.mavlink.tlog import TlogWriter

m = mavlink
AF = load_airframe()
ROOT = Path(__file__).resolve().parents[2]
FAULT_S, DETECTED_S = 1.0, 1.06


class _Tlog:
    """Packs messages as (system 1, component) and records them at a simulated Unix time."""

    def __init__(self, path):
        self.writer = TlogWriter(path)
        self.mavs = {}
        self.t_s = 0.0

    def write(self, packet):
        self.writer.record(packet, unix_time_us=round(1.7e15 + self.t_s * 1e6))

    def send(self, component, msg):
        if component not in self.mavs:
            self.mavs[component] = new_mav(self, 255 if component == 190 else 1, component)
        self.mavs[component].send(msg)


ROTOR_4_LOST = (m.MAV_CMD_M4_ROTOR_LOSS, 4, 1, m.M4_FAULT_KIND_DEGRADED)


def _flight(path, yaw_rad=0.0, vel_ned=(0.0, 0.0, 0.0), injection=ROTOR_4_LOST, announced=(), disturbance=False):
    """injection: (command, its first three params) sent at 1 s and accepted (None: no command);
    announced: (k, text) the FC says at step k, before that step's frame; disturbance: the
    companion logs its disturbance estimate (a 3 N push from the north after 0.5 s)."""
    log = _Tlog(path)
    for k in range(151):
        t_s = k * 0.02
        log.t_s, t_ms = t_s, k * 20
        for text in (text for at, text in announced if at == k):       # as the FC: before the instant's frame
            log.send(1, m.MAVLink_statustext_message(m.MAV_SEVERITY_INFO, text.encode()))
        after = t_s >= FAULT_S
        z = -2.0 + (0.1 * min(t_s - FAULT_S, 0.5) / 0.5 if after else 0.0)
        roll = 0.2 if 1.1 <= t_s < 1.4 else 0.0
        r = 5.0 * min(max(t_s - 1.5, 0.0) / 0.5, 1.0)
        log.send(1, m.MAVLink_heartbeat_message(m.MAV_TYPE_QUADROTOR, m.MAV_AUTOPILOT_GENERIC, 128, 0, 4, 3))
        log.send(1, m.MAVLink_attitude_message(t_ms, roll, 0.0, yaw_rad, 0.0, 0.0, r))
        log.send(1, m.MAVLink_local_position_ned_message(t_ms, 0.0, 0.0, z, *vel_ned))
        log.send(1, m.MAVLink_m4_joint_state_message(t_ms, [0.78] * 4, [0.0] * 4))
        thrust = [22.0, 22.0, 15.0, 0.0] if after else [14.7] * 4
        log.send(1, m.MAVLink_m4_thruster_status_message(t_ms, thrust, [30.0] * 4))
        log.send(1, m.MAVLink_esc_telemetry_1_to_4_message([30] * 4, [1600] * 4, [1500, 1500, 1000, 0], [0] * 4,
                                                           [5500, 5500, 4000, 0 if after else 5500], [k] * 4))
        log.send(191, m.MAVLink_m4_setpoint_message(1, 1, t_ms, 20, [29.0 if after else 14.7] * 4, [0.78] * 4,
                                                   [0.0] * 4, 0))
        confirmed = t_s >= DETECTED_S
        log.send(191, m.MAVLink_m4_fault_status_message(t_ms, 4 if confirmed else 0, [30.0] * 3 + [0.0 if confirmed
                                                        else 30.0], 1060 if confirmed else 0, 2 if confirmed else 0))
        named = [("nmpc_ms", 1.0 + k % 3), ("ref_d", -2.0), ("step_ms", 2.0), ("nmpc_ok", 1.0)]
        if disturbance:
            named += [("dist_n", 3.0 if t_s >= 0.5 else 0.0), ("dist_e", 0.0), ("dist_d", 0.0)]
        for name, value in named:
            log.send(191, m.MAVLink_named_value_float_message(t_ms, name.encode(), value))
        if k == 50 and injection is not None:
            command, *params = injection
            log.send(190, m.MAVLink_command_long_message(1, 1, command, 0, *params, 0, 0, 0, 0))
            log.send(1, m.MAVLink_command_ack_message(command, m.MAV_RESULT_ACCEPTED, 0, 0, 255, 190))
        if k == 53:
            log.send(191, m.MAVLink_statustext_message(m.MAV_SEVERITY_CRITICAL, b"thrust loss rotor 4"))
    log.writer.close()
    return path


@pytest.fixture(scope="module")
def tlog(tmp_path_factory):
    return _flight(tmp_path_factory.mktemp("tlog") / "flight.tlog")


def test_the_tlog_reads_back_into_series_and_the_injected_fault(tlog):
    record = read_tlog(tlog)
    assert len(record.position_ned_m) == 151 and record.duration_s == pytest.approx(3.0)
    assert record.injected == [Fault(FAULT_S, 4, 1.0)]
    assert len(record.setpoint_thrust_n) == 151 and set(record.named) == {"nmpc_ms", "ref_d", "step_ms", "nmpc_ok"}
    assert [(t, text) for t, _, _, text in record.statustext] == [(1.06, "thrust loss rotor 4")]


@pytest.mark.parametrize("injection, fault", [
    ((m.MAV_CMD_INJECT_FAILURE, m.FAILURE_UNIT_SYSTEM_MOTOR, m.FAILURE_TYPE_OFF, 4), Fault(FAULT_S, 4, 1.0, "motor")),
    ((m.MAV_CMD_M4_ROTOR_LOSS, 2, 0.5, m.M4_FAULT_KIND_DAMAGE), Fault(FAULT_S, 2, 0.5, "damage"))])
def test_an_injected_fault_keeps_its_kind(tmp_path, injection, fault):
    assert read_tlog(_flight(tmp_path / "flight.tlog", injection=injection)).injected == [fault]


def test_the_fc_announcement_gives_the_fault_and_a_restore_ends_it(tmp_path):
    """What the simulated FC says for a scenario's fault and a command's alike: in the companion's log."""
    record = read_tlog(_flight(tmp_path / "flight.tlog", injection=None,
                               announced=[(50, "rotor 4 propeller loss injected"), (120, "rotor 4 restored")]))
    assert record.injected == [Fault(FAULT_S, 4, 1.0, "propeller", until_s=2.4)]
    both = read_tlog(_flight(tmp_path / "both.tlog", announced=[(50, "rotor 4 loss 100% injected")]))
    assert both.injected == [Fault(FAULT_S, 4, 1.0)]                  # a command and its announcement: one fault


def test_esc_speed_and_current_are_read(tlog):
    record = read_tlog(tlog)
    assert record.esc_rpm.values[-1].tolist() == [5500, 5500, 4000, 0]
    assert record.esc_current_a.values[-1].tolist() == [15.0, 15.0, 10.0, 0.0]


def test_metrics_from_telemetry(tlog):
    record = read_tlog(tlog)
    metrics = telemetry_metrics(record, record.injected, AF)
    [fault] = metrics["faults"]
    assert fault["detected_rotor"] == 4 and fault["latency_s"] == pytest.approx(DETECTED_S - FAULT_S)
    assert metrics["altitude_loss_m"] == pytest.approx(0.1, abs=1e-6)
    assert metrics["max_tilt_deg_after_fault"] == pytest.approx(math.degrees(0.2), abs=1e-3)
    assert metrics["tilt_recovered_s"] == pytest.approx(0.4)      # 11.5 deg from 1.1 to 1.4 s
    assert metrics["yaw_rate_final_rad_s"] == pytest.approx(5.0)
    assert metrics["time_to_yaw_saturation_s"] == pytest.approx(0.5 + 0.9 * 0.5, abs=0.021)
    assert metrics["max_thrust_commanded_n"] == 29.0 and metrics["max_thrust_n"] == 22.0
    assert metrics["nmpc"] == {"rate_hz": pytest.approx(50.0), "solve_ms_median": 2.0,
                               "solve_ms_p99": pytest.approx(3.0), "solve_failures": 0}
    assert metrics["measured_from"] == {"what": "fault", "at_s": FAULT_S}
    assert metrics["confirmations"] == [{"at_s": DETECTED_S, "rotor": 4, "kind": "unknown"}]
    assert metrics["critical_messages"] == ["thrust loss rotor 4"]
    json.dumps(metrics)


def test_plot_and_fly_share_every_key_they_both_have(tlog):
    """One vocabulary: the keys of fly's metrics.json that a tlog can give, with fly's nmpc summary."""
    record = read_tlog(tlog)
    metrics = telemetry_metrics(record, record.injected, AF)
    shared = {"duration_s", "faults", "altitude_loss_m", "max_tilt_deg_after_fault", "tilt_recovered_s",
              "position_rmse_m", "yaw_rate_final_rad_s", "time_to_yaw_saturation_s", "max_thrust_n", "nmpc"}
    assert shared <= set(metrics)
    assert set(metrics["nmpc"]) == {"rate_hz", "solve_ms_median", "solve_ms_p99", "solve_failures"}


def test_flying_north_while_facing_east_is_flying_to_the_left_in_the_body_frame(tmp_path):
    record = read_tlog(_flight(tmp_path / "east.tlog", yaw_rad=math.pi / 2, vel_ned=(2.0, 0.0, 0.5)))
    assert np.allclose(body_velocities(record).values[:3], [[0.0, -2.0, 0.5]] * 3, atol=1e-6)


@pytest.mark.parametrize("fmt, magic", [("png", b"\x89PNG"), ("pdf", b"%PDF"), ("svg", b"<?xml")])
def test_every_figure_in_every_format_with_legends_beside_the_data(tlog, tmp_path, fmt, magic):
    record = read_tlog(tlog)
    faults = telemetry_metrics(record, record.injected, AF)["faults"]
    paths = draw(record, tmp_path, "synthetic", faults, fmt)
    assert [p.name for p in paths] == [f"{n}.{fmt}" for n in ("trajectory", "velocities_rates", "actuators",
                                                               "yaw_rate")]
    assert all(p.read_bytes().startswith(magic) for p in paths)


def test_legends_sit_outside_the_panels_and_name_fault_and_detection(tlog, tmp_path, drawn_figures):
    record = read_tlog(tlog)
    faults = telemetry_metrics(record, record.injected, AF)["faults"]
    seen = drawn_figures
    draw(record, tmp_path, "synthetic", faults)
    fault, detected = "fault: rotor 4, degraded 100 % (1.00 s)", "detected: rotor 4 (1.06 s)"
    for fig in seen:
        fig.canvas.draw()
        panels = [ax for ax in fig.axes if ax.get_legend() is not None]
        assert len(panels) >= len(fig.axes) - 1              # the zoom's tilt axis shares its panel's legend
        for ax in panels:
            legend = ax.get_legend()
            assert legend.get_window_extent().x0 >= ax.get_window_extent().x1        # hides no data
            labels = [t.get_text() for t in legend.get_texts()]
            assert fault in labels and detected in labels
            styles = {line.get_label(): (line.get_color(), line.get_linestyle()) for line in ax.get_lines()}
            assert styles[fault] != styles[detected]


def test_plot_command_writes_metrics_and_figures(tlog, tmp_path, capsys):
    assert main(["plot", str(tlog), "--out", str(tmp_path), "--format", "svg", "--fault", "2.0:3:0.5"]) == 0
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    assert [(f["at_s"], f["rotor"]) for f in metrics["faults"]] == [(1.0, 4), (2.0, 3)]
    assert (tmp_path / "actuators.svg").exists() and "metrics.json" in capsys.readouterr().out


def test_without_a_fault_in_the_log_the_metrics_count_from_the_first_confirmation_and_say_so(tmp_path, capsys):
    tlog = _flight(tmp_path / "flight.tlog", injection=None)
    assert main(["plot", str(tlog), "--out", str(tmp_path / "out")]) == 0
    metrics = json.loads((tmp_path / "out" / "metrics.json").read_text())
    assert metrics["faults"] == [] and metrics["measured_from"] == {"what": "first confirmation", "at_s": DETECTED_S}
    assert metrics["time_to_yaw_saturation_s"] == pytest.approx(0.44 + 0.9 * 0.5, abs=0.021)
    assert "no fault instant in the log" in capsys.readouterr().err


def _figure_axes(record, faults, tmp_path, drawn_figures) -> dict[str, list]:
    before = len(drawn_figures)
    draw(record, tmp_path, "synthetic", faults)
    return {fig.get_suptitle() + str(i): fig.axes for i, fig in enumerate(drawn_figures[before:])}


def test_the_altitude_has_an_axis_scaled_to_the_sag_and_esc_speed_and_current_are_drawn(tlog, tmp_path,
                                                                                         drawn_figures):
    record = read_tlog(tlog)
    axes = [ax for fig_axes in _figure_axes(record, [], tmp_path, drawn_figures).values() for ax in fig_axes]
    [altitude] = [ax for ax in axes if ax.get_ylabel() == "altitude (m)" and ax.get_title() == ""]
    low, high = altitude.get_ylim()
    assert high - low < 0.2                                  # the 0.1 m sag fills the panel
    assert {"ESC speed (rpm)", "ESC current (A)"} <= {ax.get_ylabel() for ax in axes}


def test_a_confirmation_is_drawn_without_a_fault_and_a_fault_stands_apart_from_its_detection(tlog, tmp_path,
                                                                                             drawn_figures):
    record = read_tlog(tlog)
    for ax in (ax for fig_axes in _figure_axes(record, [], tmp_path, drawn_figures).values() for ax in fig_axes
               if ax.get_legend() is not None):
        assert "confirmed: rotor 4, unknown (1.06 s)" in [t.get_text() for t in ax.get_legend().get_texts()]
    faults = telemetry_metrics(record, record.injected, AF)["faults"]
    [zoom] = [ax for fig_axes in _figure_axes(record, faults, tmp_path, drawn_figures).values() for ax in fig_axes
              if ax.get_title() == "around the fault"]
    low, high = zoom.get_xlim()
    assert (DETECTED_S - FAULT_S) / (high - low) > 0.04     # 6 ms apart on a 1 s window: 40 px on 1000


def test_a_windy_simulated_flight_draws_the_air_as_truth_beside_the_companions_estimate(tmp_path, drawn_figures,
                                                                                        capsys):
    """m4-sitl fly's layout: truth.npz in the folder above the companion's log. The wind figure
    draws the simulator's air (so labelled) and the companion's disturbance estimate."""
    tlog = _flight(tmp_path / "companion-log" / "flight-1.tlog", disturbance=True)
    t = np.arange(0.0, 3.0, 0.01)
    np.savez(tmp_path / "truth.npz", time_s=t, wind_ned_m_s=np.column_stack([-5.0 - np.sin(t), 0 * t, 0 * t]))
    seen = drawn_figures
    assert main(["plot", str(tlog), "--out", str(tmp_path / "out")]) == 0
    assert "wind.png" in capsys.readouterr().out and (tmp_path / "out" / "wind.png").stat().st_size > 0
    [air, estimate, speed] = next(fig.axes for fig in seen if "air velocity (m/s, NED)" in
                                  [ax.get_ylabel() for ax in fig.axes])
    assert "simulator's truth" in air.get_title() and air.get_lines()[0].get_ydata().min() < -5.5
    assert estimate.get_ylabel() == "force (N, NED)" and "companion" in estimate.get_title()
    assert max(np.max(line.get_ydata()) for line in estimate.get_lines()) == pytest.approx(3.0)
    assert speed.get_ylabel() == "hull speed (m/s)"


def test_a_real_flights_log_draws_the_companions_estimate_alone(tmp_path, drawn_figures):
    tlog = _flight(tmp_path / "flight.tlog", disturbance=True)
    seen = drawn_figures
    assert main(["plot", str(tlog), "--out", str(tmp_path / "out")]) == 0
    [estimate] = next(fig.axes for fig in seen if "force (N, NED)" in [ax.get_ylabel() for ax in fig.axes])
    assert len(estimate.get_lines()) >= 3


def test_a_truth_beside_the_log_that_numpy_cannot_read_says_so_in_one_line(tlog, tmp_path, capsys):
    log = tmp_path / "flight.tlog"
    log.write_bytes(tlog.read_bytes())
    (tmp_path / "truth.npz").write_text("not an archive")
    assert main(["plot", str(log), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "truth.npz: not the simulator's truth" in err


def test_a_truncated_tlog_is_plotted_with_a_warning(tlog, tmp_path, capsys):
    cut = tmp_path / "cut.tlog"
    cut.write_bytes(tlog.read_bytes()[:-7])
    assert main(["plot", str(cut), "--out", str(tmp_path / "out")]) == 0
    [warning] = [line for line in capsys.readouterr().err.splitlines() if "whole record" in line]
    assert warning.startswith(f"m4-companion: warning: {cut}: ")


@pytest.mark.parametrize("out", ["a-file", "a-file/below"])
def test_plot_to_a_bad_out_says_so_in_one_line(tlog, tmp_path, capsys, out):
    (tmp_path / "a-file").write_text("")
    assert main(["plot", str(tlog), "--out", str(tmp_path / out)]) == 2
    [line] = capsys.readouterr().err.strip().splitlines()
    assert line.startswith(f"m4-companion: error: --out {tmp_path / out}: ")


def test_plot_of_a_file_that_is_no_tlog_says_so_in_one_line(tmp_path, capsys):
    text = tmp_path / "notes.tlog"
    text.write_text("not a flight\n" * 50)
    assert main(["plot", str(text)]) == 2
    assert capsys.readouterr().err.strip() == f"m4-companion: error: {text}: not a tlog (no MAVLink packet in it)"


def test_plot_of_a_missing_tlog_says_so_in_one_line(capsys):
    assert main(["plot", "nope.tlog"]) == 2
    assert capsys.readouterr().err.strip() == "m4-companion: error: no such tlog: nope.tlog"


def test_a_malformed_fault_is_refused_by_the_argument_parser(tlog, capsys):
    with pytest.raises(SystemExit):
        main(["plot", str(tlog), "--fault", "x:4"])
    assert "expected AT_S:ROTOR[:LOSS]" in capsys.readouterr().err


def test_plot_without_matplotlib_names_the_plot_extra(tlog):
    script = textwrap.dedent(f"""
        import sys
        sys.modules["matplotlib"] = None
        from companion.cli import main
        sys.exit(main(["plot", {str(tlog)!r}]))
    """)
    result = subprocess.run([sys.executable, "-c", script], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert result.returncode == 2
    assert result.stderr.strip() == ("m4-companion: error: m4-companion plot needs the 'plot' extra (matplotlib not "
                                     "installed): pip install 'm4-fault-recovery[plot]'")
