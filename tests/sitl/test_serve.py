"""`m4-sitl serve` in lockstep: deterministic, faults from the scenario, tlog, signing."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from m4.airframe import load_airframe
from m4.mavlink import mavlink, mavutil
from m4.mavlink.link import UdpLink, wait_readable
from m4.scenario import Fault, PlantOptions, Scenario
from sitl.flights.flight_run import free_port
from sitl.serve import ServeOptions, Server
from sitl.plant.truth import load_truth
from sitl.standin_companion import StandInCompanion, served

KEY = bytes(range(1, 33))
NOISY_FAULT = Scenario(name="noisy-fault", duration_s=60.0, faults=(Fault(at_s=1.0, rotor=4, loss=1.0),),
                       plant=PlantOptions(sensor_noise=True))


def _fly(seconds: float, companion: StandInCompanion | None = None, **options):
    companion = companion or StandInCompanion()
    scenario = options.pop("scenario", NOISY_FAULT)
    with served(companion, ServeOptions(scenario=scenario, duration_s=seconds, **options)) as server:
        companion.wait_for("M4_THRUSTER_STATUS", lambda m: m.time_boot_ms >= round(seconds * 1000), 60.0)
    return companion, server


def _instants_before(companion, end_ms):
    """Control instants before the end: lockstep waited for (and got) a setpoint for each."""
    return len({m.time_boot_ms for m in companion.of_type("M4_THRUSTER_STATUS") if m.time_boot_ms < end_ms})


def _telemetry_bytes(companion):
    """Every packet from the FC, sequence byte blanked, repeats dropped (lockstep sends a frame
    again when the companion takes over a second to answer: not part of the flight)."""
    packets = [bytearray(m.get_msgbuf()) for m in companion.received if m.get_srcComponent() == 1]
    for p in packets:
        p[4] = 0
    return list(dict.fromkeys(bytes(p) for p in packets))


def test_same_scenario_and_seed_give_identical_telemetry():
    first = _telemetry_bytes(_fly(2.0, seed=7)[0])
    second = _telemetry_bytes(_fly(2.0, seed=7)[0])
    other_seed = _telemetry_bytes(_fly(2.0, seed=8)[0])
    assert len(first) > 500
    assert first == second
    assert first != other_seed


def test_scenario_fault_caps_the_rotor_at_its_time(tmp_path):
    af = load_airframe()
    scenario = Scenario(name="loe", duration_s=60.0, faults=(Fault(at_s=0.5, rotor=3, loss=0.33),))
    _fly(0.7, scenario=scenario, truth_log_path=tmp_path / "truth.npz")
    truth = load_truth(tmp_path / "truth.npz")
    delivered = dict(zip(np.round(truth.time_s * 1000).astype(int), truth.thrust_n[:, 2]))
    assert delivered[480] == pytest.approx(af.hover_thrust_per_rotor_n, abs=0.05)
    assert delivered[700] == pytest.approx(0.67 * af.hover_thrust_per_rotor_n, abs=0.05)   # after the motor lag


def test_tlog_has_every_packet_of_both_directions(tmp_path):
    path = tmp_path / "serve.tlog"
    companion, _ = _fly(0.5, tlog_path=path)
    log = mavutil.mavlink_connection(str(path))
    logged = []
    while (msg := log.recv_match(blocking=False)) is not None:
        logged.append(msg)
    from_fc = [m for m in logged if m.get_srcComponent() == 1]
    setpoints = [m for m in logged if m.get_type() == "M4_SETPOINT"]
    assert len(from_fc) == len([m for m in companion.received if m.get_srcComponent() == 1])
    assert len(setpoints) == _instants_before(companion, 500) == 25
    stamps = [m._timestamp for m in logged]
    assert stamps == sorted(stamps)


def test_signed_setpoints_fly_and_unsigned_ones_are_dropped_and_counted():
    thrust = [14.0, 15.0, 15.5, 14.5]
    answer = lambda t_ms: (thrust, [0.78] * 4, [0.0] * 4, 0)
    signed, server = _fly(0.3, StandInCompanion(key=KEY, answer=answer), signing_key=KEY)
    assert np.allclose(signed.of_type("M4_THRUSTER_STATUS")[-1].thrust_cmd_n, thrust, atol=1e-4)
    assert server.vehicle.fc.counters.setpoints_accepted == _instants_before(signed, 300)
    assert all(m.get_signed() for m in signed.received)

    unsigned, server = _fly(0.3, StandInCompanion(answer=answer), signing_key=KEY, lockstep_timeout_s=0.1)
    assert unsigned.answered > 0
    assert server.vehicle.fc.counters.setpoints_accepted == 0
    assert 0 < server.links[0].signing_counters().rejected <= unsigned.answered
    assert not np.allclose(unsigned.of_type("M4_THRUSTER_STATUS")[-1].thrust_cmd_n, thrust, atol=0.2)


def test_companion_that_starts_late_still_gets_the_first_frame():
    port = free_port()
    server = Server(ServeOptions(scenario=NOISY_FAULT, mavlink_urls=(f"udpout:127.0.0.1:{port}",), duration_s=0.2))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    time.sleep(0.3)                            # the t = 0 frame went nowhere
    companion = StandInCompanion(port=port).start()
    thread.join(timeout=10.0)
    companion.close()
    server.close()
    assert not thread.is_alive()
    assert server.vehicle.fc.counters.setpoints_accepted == 10


def test_realtime_applies_the_freshest_setpoints():
    thrust = [14.2, 15.2, 15.2, 14.2]
    companion = StandInCompanion(answer=lambda t_ms: (thrust, [0.78] * 4, [0.0] * 4, 0))
    _, server = _fly(0.5, companion, scenario=Scenario(name="hover", duration_s=60.0), realtime=True)
    assert server.vehicle.fc.counters.setpoints_accepted >= 10
    assert np.allclose(companion.of_type("M4_THRUSTER_STATUS")[-1].thrust_cmd_n, thrust, atol=1e-4)


def test_a_ground_station_on_a_second_link_gets_what_the_companion_says_and_vice_versa():
    gcs = UdpLink("udpin:127.0.0.1:0", 255, 190)
    companion = StandInCompanion()
    heard = []
    try:
        with served(companion, ServeOptions(scenario=NOISY_FAULT, duration_s=60.0),
                    more_urls=(f"udpout:127.0.0.1:{gcs.local_port}",)):
            companion.send(mavlink.MAVLink_statustext_message(mavlink.MAV_SEVERITY_CRITICAL, b"thrust loss rotor 4"))
            companion.send(mavlink.MAVLink_m4_fault_status_message(1000, 4, [30.0, 30.0, 30.0, 0.5], 1000, 2))
            deadline = time.monotonic() + 10.0
            while time.monotonic() < deadline and not (
                    any(m.get_type() == "M4_FAULT_STATUS" for m in heard)
                    and any(m.get_type() == "STATUSTEXT" and "thrust" in m.text for m in heard)):
                wait_readable([gcs], 0.1)
                heard += gcs.receive()
            gcs.send(mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID,
                                                       0, 0, 0, 3))
            for target in (191, 1):            # one for the companion, one for the FC alone
                gcs.send(mavlink.MAVLink_command_long_message(1, target, mavlink.MAV_CMD_REQUEST_MESSAGE, 0,
                                                              float(mavlink.MAVLINK_MSG_ID_HEARTBEAT), *[0.0] * 6))
            companion.wait_for("COMMAND_LONG", timeout_s=5.0)
            companion.wait_for("COMMAND_ACK", lambda a: a.target_system == 255, timeout_s=5.0)
    finally:
        gcs.close()
    from_companion = [m for m in heard if m.get_srcComponent() == 191]
    texts = [(m.get_srcComponent(), m.text) for m in heard if m.get_type() == "STATUSTEXT" and "thrust" in m.text]
    assert texts == [(1, "thrust loss rotor 4")]              # once, as the FC's own (sitl/fc/routing.py)
    assert any(m.get_type() == "M4_FAULT_STATUS" and m.rotor == 4 for m in from_companion)
    assert not any(m.get_type() == "M4_SETPOINT" for m in heard)            # for the FC alone
    from_gcs = [m for m in companion.received if m.get_srcSystem() == 255]
    assert {m.get_type() for m in from_gcs} == {"HEARTBEAT", "COMMAND_LONG"}
    assert [m.target_component for m in from_gcs if m.get_type() == "COMMAND_LONG"] == [191]


def test_in_lockstep_what_the_fc_says_between_frames_goes_out_with_the_next_frame():
    """One datagram a control period: the companion wakes once, not at every instant a stream
    is due (ATTITUDE at 100 Hz, GLOBAL_POSITION_INT at 20 Hz)."""
    companion = StandInCompanion()
    datagrams = []
    ingest = companion.link.ingest

    def recording(data, sender):
        msgs = ingest(data, sender)
        datagrams.append([m.get_type() for m in msgs if m.get_srcComponent() == 1])
        return msgs

    companion.link.ingest = recording
    _fly(0.5, companion)
    streams = [d for d in datagrams if "ATTITUDE" in d]         # the FC's own replies (STATUSTEXT) go at once
    assert len(streams) > 20
    assert all("M4_THRUSTER_STATUS" in d for d in streams)
    assert sum(d.count("ATTITUDE") for d in streams) > 1.5 * len(streams)      # the instants between, kept
