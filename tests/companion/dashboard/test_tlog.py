"""A tlog replayed as the feed it implies: written here with the project's own dialect and writer."""

import math

import pytest

from companion.core.esc_evidence import PropellerModel
from companion.dashboard import command
from companion.dashboard.tlog import TlogError, tlog_samples
from m4.airframe import load_airframe
from m4.mavlink import COMPANION_COMPONENT_ID, FC_COMPONENT_ID, FC_SYSTEM_ID, mavlink, new_mav
from m4.mavlink.tlog import TlogWriter

T0_US = 1_796_000_000_000_000
AF = load_airframe()


def _write(path, messages) -> None:
    """messages: (component, time_s, encode-method name, args); packed and recorded in order."""
    macs = {c: new_mav(None, FC_SYSTEM_ID, c) for c in (FC_COMPONENT_ID, COMPANION_COMPONENT_ID)}
    with TlogWriter(path) as tlog:
        for component, t_s, name, args in messages:
            mav = macs[component]
            tlog.record(getattr(mav, f"{name}_encode")(*args).pack(mav), T0_US + int(t_s * 1e6))


def _flight(ms: int, fault_state: int, cut: bool = False) -> list:
    fc, comp = FC_COMPONENT_ID, COMPANION_COMPONENT_ID
    hips = [math.radians(a) for a in (90.0, 0.0, 60.0, 20.0)]
    t_s = ms / 1000
    return [
        (fc, t_s, "local_position_ned", (ms, 1.0, 2.0, -3.0, 0.1, 0.2, -0.3)),
        (fc, t_s, "m4_joint_state", (ms, hips, [0.0] * 4)),
        (fc, t_s, "m4_thruster_status", (ms, [20.0, 21.0, 15.0, 0.0], [30.0] * 4)),
        (fc, t_s, "attitude", (ms, 0.1, -0.2, 3.0, 0.0, 0.0, 8.5)),
        (comp, t_s, "m4_setpoint", (FC_SYSTEM_ID, FC_COMPONENT_ID, ms, 20, [20.0, 21.0, 15.0, 0.0], hips, [0.0] * 4,
                                    mavlink.M4_SETPOINT_FLAG_THRUST_CUT if cut else 0)),
        (comp, t_s, "m4_fault_status", (ms, 4 if fault_state else 0, [30.0, 30.0, 30.0, 0.2 if fault_state else 30.0],
                                        1040 if fault_state == 2 else 0, fault_state)),
    ]


def test_a_tlog_gives_state_setpoint_and_fault_payloads_with_the_companions_words(tmp_path):
    path = tmp_path / "flight.tlog"
    statustext = (COMPANION_COMPONENT_ID, 1.04, "statustext", (mavlink.MAV_SEVERITY_CRITICAL, b"thrust loss rotor 4"))
    _write(path, _flight(1000, 0) + _flight(1020, 1) + [statustext] + _flight(1040, 2, cut=True))
    samples = tlog_samples(path, AF, "test")
    assert [k.rsplit("/", 1)[-1] for k, _ in samples] == ["state", "setpoint", "fault"] * 3
    state = samples[0][1]
    assert state["t_s"] == 1.0 and state["wall_time_unix_s"] == pytest.approx(T0_US / 1e6 + 1.0, abs=1e-5)
    assert state["pos_ned_m"] == [1.0, 2.0, -3.0] and state["hip_deg"] == pytest.approx([90.0, 0.0, 60.0, 20.0])
    assert state["euler_deg"][2] == pytest.approx(math.degrees(3.0), rel=1e-6) and state["rates_frd_rad_s"][2] == 8.5
    assert state["thrust_n"] == [None] * 4          # delivered thrust: no flight controller measures it
    suspect, confirmed = samples[5][1], samples[8][1]
    assert suspect["state"] == "suspect" and suspect["message"] == "" and suspect["detected_at_s"] is None
    assert confirmed == {**confirmed, "state": "confirmed", "rotor": 4, "message": "thrust loss rotor 4",
                         "detected_at_s": 1.04}
    assert samples[7][1]["thrust_cut"] is True and samples[1][1]["thrust_cut"] is False


def test_no_state_before_position_and_hips(tmp_path):
    path = tmp_path / "flight.tlog"
    fc = FC_COMPONENT_ID
    _write(path, [(fc, 0.0, "attitude", (0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)),
                  (fc, 0.0, "local_position_ned", (0, 0.0, 0.0, -2.0, 0.0, 0.0, 0.0)),
                  (fc, 0.0, "m4_joint_state", (0, [0.8] * 4, [0.0] * 4)),
                  (fc, 0.02, "attitude", (20, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0))])
    samples = tlog_samples(path, AF)
    assert len(samples) == 1 and samples[0][1]["t_s"] == 0.02 and samples[0][1]["thrust_n"] == [None] * 4


def test_a_missing_or_empty_tlog_is_one_line_and_exit_2(tmp_path, capsys):
    with pytest.raises(TlogError, match="no such tlog"):
        tlog_samples(tmp_path / "none.tlog", AF)
    (tmp_path / "empty.tlog").write_bytes(b"")
    assert command.main(["--replay", str(tmp_path / "empty.tlog"), "--port", "0"]) == 2
    err = capsys.readouterr().err
    assert "empty.tlog: no flight controller state nor companion messages" in err and err.count("\n") == 1


def test_a_companion_log_replays_its_nmpc_solves_and_the_thrust_its_escs_imply(tmp_path):
    """What `m4-companion plot` reads, the replay shows: the NMPC's decisions and the ESC speeds."""
    path = tmp_path / "flight.tlog"
    fc, comp = FC_COMPONENT_ID, COMPANION_COMPONENT_ID
    decisions = [(comp, 0.02, "named_value_float", (20, name.encode(), value)) for name, value in
                 (("step_ms", 2.5), ("dist_n", -3.5), ("dist_e", 1.25), ("dist_d", 0.5), ("nmpc_ms", 1.25),
                  ("nmpc_iter", 3.0), ("nmpc_cost", 0.5), ("nmpc_ok", 1.0), ("nmpc_fb", 0.0))]
    esc = (fc, 0.02, "esc_telemetry_1_to_4", ([30] * 4, [1600] * 4, [1500] * 4, [0] * 4, [5500, 5500, 4000, 0],
                                             [1] * 4))
    _write(path, [esc] + _flight(20, 0) + decisions)
    samples = dict((k.rsplit("/", 1)[-1], p) for k, p in tlog_samples(path, AF))
    assert samples["state"]["thrust_n"] == pytest.approx(
        PropellerModel.from_airframe(AF).thrust_n([5500, 5500, 4000, 0]).tolist(), rel=1e-6)
    nmpc = samples["nmpc"]
    assert (nmpc["t_s"], nmpc["solve_ms"], nmpc["iterations"], nmpc["cost"], nmpc["ok"], nmpc["fallback"]) == (
        0.02, 1.25, 3, 0.5, True, False)
    assert nmpc["predicted_p_ned_m"] == []
    assert nmpc["disturbance_force_ned_n"] == [-3.5, 1.25, 0.5] and nmpc["disturbance_torque_frd_n_m"] == [None] * 3


def test_a_file_that_is_no_log_is_one_line_naming_it(tmp_path, capsys):
    picture = tmp_path / "figure.png"
    picture.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(range(256)))
    assert command.main(["--replay", str(picture), "--port", "0"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{picture}: not a recorded feed (feed.jsonl) nor a .tlog" in err
