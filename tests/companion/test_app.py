"""The run loop on a scripted link and a fake clock: link loss and return, and a fuzzed byte
stream of more than 100,000 frames through the whole receive path (parse, lock-on, telemetry,
control) without an exception and without a bad setpoint leaving."""

from __future__ import annotations

import gc
import logging

import math
import random
import re
import struct
from types import SimpleNamespace

import numpy as np
import pytest

from m4.airframe import load_airframe
from companion import flight_log
from companion.app import CompanionApp, collect_due
from companion.config import LogSettings, parse_config
from companion.controller import Controller, ControllerSettings
from companion.core.control_types import FaultState, FaultStatus
from m4.fault_kind import FaultKind
from companion.fc_link import FcLink
from companion.feed_publisher import Feed
from companion.flight_log import FlightLog
from m4.mavlink import COMPANION_COMPONENT_ID, FC_COMPONENT_ID, FC_SYSTEM_ID, mavlink, mavutil, new_mav
from support.fake_transport import FakeTransport
from support.fc_answers import answers
from support.full_disk import FullDisk

AF = load_airframe()
CONFIG = parse_config({"control": {"rate_hz": 50.0}, "link": {"fc_url": "udpin:127.0.0.1:0"}}, "test")
FC_ADDRESS = ("127.0.0.1", 9)            # never written to: the link below captures what it sends
FUZZ_FRAMES = 100_000


class Clock:
    def __init__(self):
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


class FakeFc:
    """Packs what a flight controller would send: heartbeat and telemetry frames."""

    def __init__(self, link: FakeTransport):
        self.link = link
        self.mav = new_mav(None, FC_SYSTEM_ID, FC_COMPONENT_ID)
        self.kept: mavlink.MAVLink_m4_fault_status_message | None = None
        self.standard_mode = mavlink.MAV_STANDARD_MODE_POSITION_HOLD
        self._read = 0                       # packets of link.sent answered so far

    def send(self, *msgs) -> None:
        for msg in msgs:
            self.link.inbox.append((msg.pack(self.mav), FC_ADDRESS))

    def heartbeat(self) -> None:
        self.send(mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_QUADROTOR, 0, 0, 0, 4, 3))

    def answer(self) -> None:
        """The replies to the commands the companion sent since the last call (support.fc_answers:
        `kept`, the M4_FAULT_STATUS this FC kept; `standard_mode`, its mode)."""
        self._read = min(self._read, len(self.link.sent))          # a test may clear what was sent
        parser = new_mav(None, 255, 0)
        msgs = [msg for packet in self.link.sent[self._read:] for msg in parser.parse_buffer(packet) or ()]
        self._read = len(self.link.sent)
        self.send(*(reply for msg in msgs for reply in answers(msg, self.kept, self.standard_mode)))

    def join(self, app) -> None:
        """HEARTBEAT, then the answers to what the companion asks the FC it finds (as the SITL's
        FC answers: within a millisecond, before its next frame)."""
        self.heartbeat()
        for _ in range(4):
            app.poll()
            self.answer()

    def frame(self, t_ms: int, without: tuple[str, ...] = ()) -> None:
        hover = [AF.hover_thrust_per_rotor_n] * 4
        msgs = (mavlink.MAVLink_attitude_message(t_ms, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
                mavlink.MAVLink_local_position_ned_message(t_ms, 0.0, 0.0, -2.0, 0.0, 0.0, 0.0),
                mavlink.MAVLink_m4_joint_state_message(t_ms, [AF.nominal_hip_rad] * 4, [0.0] * 4),
                mavlink.MAVLink_m4_thruster_status_message(t_ms, hover, [AF.thrust_max_n] * 4))
        self.send(*(msg for msg in msgs if msg.get_type() not in without))


@pytest.fixture(scope="module")
def controller():
    return Controller(ControllerSettings.of(CONFIG))


@pytest.fixture
def rig(controller):
    controller.restart()
    link, clock = FakeTransport(FC_SYSTEM_ID, COMPANION_COMPONENT_ID), Clock()
    app = CompanionApp(CONFIG, FcLink(link), controller, clock=clock)
    yield app, FakeFc(link), link, clock
    link.close()


def recording_feed() -> tuple[Feed, list[tuple[str, dict]]]:
    """A feed whose payloads land in the list, (topic, payload) each."""
    published = []
    return Feed(SimpleNamespace(put=lambda topic, payload: published.append((topic, payload)), close=list)), published


def statustexts(link: FakeTransport) -> list[tuple[int, str]]:
    return [(m.severity, m.text) for m in link.sent_messages() if m.get_type() == "STATUSTEXT"]


def setpoint_times(link: FakeTransport) -> list[int]:
    return [m.time_boot_ms for m in link.sent_messages() if m.get_type() == "M4_SETPOINT"]


def fly(app, fc, clock, t0_ms: int, frames: int, period_ms: int = 20, without: tuple[str, ...] = ()) -> None:
    for k in range(frames):
        fc.frame(t0_ms + k * period_ms, without)
        app.poll()
        fc.answer()
        clock.now += period_ms / 1000.0


def test_no_garbage_collection_runs_between_a_frames_read_and_its_setpoint(rig, monkeypatch):
    """A collection of a young generation (0.1-1.3 ms in flight) in the middle of an answer
    delayed its setpoint by as much: a collection due in a poll runs after it."""
    app, fc, link, clock = rig
    fc.join(app)
    events = []
    receive, send = app.fc.receive, app.fc.send_setpoint
    monkeypatch.setattr(app.fc, "receive", lambda *a: events.append("read") or receive(*a))
    monkeypatch.setattr(app.fc, "send_setpoint", lambda *a, **k: events.append("sent") or send(*a, **k))
    collected = lambda phase, info: events.append("collected") if phase == "start" else None
    threshold = gc.get_threshold()
    gc.callbacks.append(collected)
    gc.set_threshold(1)                      # a collection due at nearly every allocation
    try:
        fly(app, fc, clock, 0, 3)
    finally:
        gc.set_threshold(*threshold)
        gc.callbacks.remove(collected)
    assert events.count("sent") == 3 and "collected" in events
    order = re.sub("c+", "c", "".join({"read": "r", "sent": "s", "collected": "c"}[e] for e in events))
    assert re.fullmatch("c?(rsc)+", order), order      # read, sent, collected: each poll in turn



def test_a_collection_due_in_a_poll_runs_by_its_end_though_nothing_allocates_after_it(rig, monkeypatch):
    """Re-enabled, the collector waits for the next allocation of a tracked object: in the real
    loop soon (its select), but by chance. The poll runs the one due itself, after its _poll."""
    app, fc = rig[:2]
    fc.join(app)
    events = []
    inner = app._poll
    monkeypatch.setattr(app, "_poll", lambda: inner() or events.append("polled"))
    collected = lambda phase, info: events.append("collected") if phase == "start" else None
    threshold = gc.get_threshold()
    gc.callbacks.append(collected)
    gc.set_threshold(1)                      # due after the poll's first allocation
    try:
        fc.frame(0)
        app.poll()
        events.append("returned")            # a string appended: no tracked object allocated
    finally:
        gc.set_threshold(*threshold)
        gc.callbacks.remove(collected)
    assert events[events.index("polled"):events.index("returned")] == ["polled", "collected"], events


def test_the_collection_due_is_of_the_oldest_generation_past_its_threshold():
    """A young collection alone would leave the older generations to an automatic one that never
    comes: every poll ends with the young count reset."""
    generations = []
    collected = lambda phase, info: generations.append(info["generation"]) if phase == "start" else None
    threshold = gc.get_threshold()
    gc.disable()                             # as in a poll
    try:
        gc.set_threshold(10**6, 1, 10**6)
        gc.collect(0)
        gc.collect(0)                        # the middle generation's count is 2: past its threshold
        young = [SimpleNamespace() for _ in range(3)]          # tracked, and from no free list
        gc.callbacks.append(collected)
        collect_due()                        # the young one's is not yet
        gc.set_threshold(1, 1, 10**6)
        collect_due()
        collect_due()                        # nothing due after it
    finally:
        gc.callbacks.remove(collected)
        gc.set_threshold(*threshold)
        gc.enable()
    assert generations == [1] and young

def test_each_frame_is_answered_with_its_instant_and_the_control_period(rig):
    app, fc, link, clock = rig
    fc.join(app)
    fly(app, fc, clock, 0, 10)
    assert setpoint_times(link) == list(range(0, 200, 20))
    assert {m.period_ms for m in link.sent_messages() if m.get_type() == "M4_SETPOINT"} == {20}


def test_frames_between_our_instants_are_not_answered(rig):
    """Telemetry faster than the control rate (a real FC's own stream rate): every 20 ms
    instant is answered, the 10 ms ones between are not."""
    app, fc, link, clock = rig
    fc.join(app)
    fly(app, fc, clock, 0, 10, period_ms=10)
    assert setpoint_times(link) == list(range(0, 100, 20))


def test_telemetry_loss_is_noticed_within_0_3_s_setpoints_stop_and_control_resumes(rig, monkeypatch):
    app, fc, link, clock = rig
    resumes = []
    monkeypatch.setattr(app.controller, "resume", lambda: resumes.append(clock.now))
    app.feed, published = recording_feed()
    fc.join(app)
    fly(app, fc, clock, 0, 10)
    last_frame_s = clock.now - 0.02
    answered = len(setpoint_times(link))
    while app.fc.connected:
        clock.now += 0.01
        app.poll()
    assert 0.3 <= clock.now - last_frame_s <= 0.31
    assert app.counters.link_losses == 1
    texts = [m.text for m in link.sent_messages() if m.get_type() == "STATUSTEXT"]
    assert texts[-1] == "companion: telemetry lost, setpoints stopped"
    link_topic = [p for topic, p in published if topic == "link"]
    assert link_topic[-1]["connected"] is False and link_topic[-1]["last_msg_age_s"] >= 0.3
    clock.now += 1.0
    app.poll()
    assert len(setpoint_times(link)) == answered               # nothing went out while lost
    fly(app, fc, clock, 2000, 5)                               # the FC's clock moved on 1.8 s
    assert app.fc.connected and len(resumes) == 1
    assert setpoint_times(link)[answered:] == [2000, 2020, 2040, 2060, 2080]
    severities = {m.severity for m in link.sent_messages() if m.get_type() == "STATUSTEXT"}
    assert severities.isdisjoint({mavlink.MAV_SEVERITY_EMERGENCY, mavlink.MAV_SEVERITY_ALERT,
                                  mavlink.MAV_SEVERITY_CRITICAL})


def test_the_fcs_shutdown_then_silence_is_the_end_of_the_flight_not_a_lost_link(rig, caplog):
    app, fc, link, clock = rig
    fc.join(app)
    fly(app, fc, clock, 0, 10)
    assert app.end() == "stopped in flight at t=0.180 s, the flight controller still sending"
    fc.send(mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_QUADROTOR, 0, 0, 0, mavlink.MAV_STATE_POWEROFF, 3))
    with caplog.at_level(logging.INFO, logger="m4-companion"):
        while app.fc.connected:
            clock.now += 0.01
            app.poll()
    assert app.counters.link_losses == 0
    assert "companion: telemetry lost, setpoints stopped" not in [text for _, text in statustexts(link)]
    assert not [r for r in caplog.records if r.levelno >= logging.WARNING]
    assert app.end() == "the flight ended: the flight controller shut down at t=0.180 s"


def test_a_silence_without_the_fcs_shutdown_is_a_lost_link_at_the_end(rig):
    app, fc, link, clock = rig
    fc.join(app)
    fly(app, fc, clock, 0, 10)
    while app.fc.connected:
        clock.now += 0.01
        app.poll()
    assert app.counters.link_losses == 1 and app.end() == "telemetry lost at t=0.180 s and not back"


def test_a_short_wall_clock_gap_in_lockstep_does_not_reset_the_controller(rig, monkeypatch):
    """In lockstep the FC's clock waits for us: after a slow wall-clock moment the next frame is
    the very next instant, and nothing the controller holds is stale."""
    app, fc, link, clock = rig
    resumes = []
    monkeypatch.setattr(app.controller, "resume", lambda: resumes.append(clock.now))
    fc.join(app)
    fly(app, fc, clock, 0, 5)
    clock.now += 0.5
    app.poll()
    assert not app.fc.connected
    fly(app, fc, clock, 100, 3)
    assert app.fc.connected and resumes == []
    assert setpoint_times(link) == list(range(0, 160, 20))


def test_a_control_step_that_raises_sends_nothing_and_the_loop_goes_on(rig, monkeypatch):
    app, fc, link, clock = rig
    fc.join(app)
    fly(app, fc, clock, 0, 2)
    real_step = app.controller.step
    monkeypatch.setattr(app.controller, "step", lambda *a: 1 / 0)
    fly(app, fc, clock, 40, 2)
    monkeypatch.setattr(app.controller, "step", real_step)
    fly(app, fc, clock, 80, 2)
    assert setpoint_times(link) == [0, 20, 80, 100]
    assert app.counters.control_errors == 2


def test_after_a_reboot_of_the_fc_the_mission_starts_over_on_its_new_clock(rig):
    app, fc, link, clock = rig
    fc.join(app)
    fly(app, fc, clock, 5000, 3)
    first_reference = app.controller.flight.reference
    clock.now += 0.5
    app.poll()
    fc.heartbeat()
    fly(app, fc, clock, 0, 3)
    assert setpoint_times(link) == [5000, 5020, 5040, 0, 20, 40]
    assert app.controller.flight.reference is not first_reference


def test_a_stale_attitude_stops_the_setpoints_is_asked_for_again_reported_and_control_resumes(rig):
    """ATTITUDE stops while the other streams go on (a third party stopped it): within five
    periods no setpoint goes out, ATTITUDE and ATTITUDE_QUATERNION are asked for again, the
    warning goes out (STATUSTEXT, the feed's link topic, the log); when it comes back, so do
    the setpoints, and the all-clear is said once a second has passed since the warning."""
    app, fc, link, clock = rig
    published = []
    app.feed = Feed(SimpleNamespace(put=lambda topic, payload: published.append((topic, payload)), close=list))
    fc.join(app)
    fly(app, fc, clock, 0, 10)
    link.sent.clear()
    fly(app, fc, clock, 200, 10, without=("ATTITUDE",))
    sent = link.sent_messages()
    assert setpoint_times(link) == [200, 220, 240, 260, 280]
    asked = [(int(m.param1), m.param2) for m in sent if m.get_type() == "COMMAND_LONG"]
    assert asked == [(mavlink.MAVLINK_MSG_ID_ATTITUDE, 20000.0), (mavlink.MAVLINK_MSG_ID_ATTITUDE_QUATERNION, 20000.0)]
    fly(app, fc, clock, 400, 50)
    texts = [(m.severity, m.text) for m in link.sent_messages() if m.get_type() == "STATUSTEXT"]
    assert texts == [(mavlink.MAV_SEVERITY_WARNING, "companion: stale attitude: no setpoints"),
                     (mavlink.MAV_SEVERITY_NOTICE, "companion: telemetry fresh again")]
    assert setpoint_times(link)[5:] == list(range(400, 1400, 20))
    stale_topic = [p["stale_streams"] for topic, p in published if topic == "link"]
    assert ["attitude"] in stale_topic and stale_topic[-1] == []
    assert app.counters.skipped_stale == 5


def test_stale_esc_telemetry_is_asked_for_again_and_the_controller_flies_without_it(rig, monkeypatch):
    app, fc, link, clock = rig
    given = []
    real_step = app.controller.step
    monkeypatch.setattr(app.controller, "step",
                        lambda t, x, esc, *a, **k: (given.append(esc), real_step(t, x, esc, *a, **k))[1])
    esc = mavlink.MAVLink_esc_telemetry_1_to_4_message([30] * 4, [1480] * 4, [2250] * 4, [0] * 4, [5522] * 4, [1] * 4)
    fc.join(app)
    for k in range(20):
        if k < 10:
            fc.send(esc)
        fly(app, fc, clock, 20 * k, 1)
    assert given[1] is not None and given[-1] is None and len(given) == 20
    asked = [int(m.param1) for m in link.sent_messages() if m.get_type() == "COMMAND_LONG"]
    assert asked.count(mavlink.MAVLINK_MSG_ID_ESC_TELEMETRY_1_TO_4) == 2      # at lock-on, and when it went stale
    texts = [m.text for m in link.sent_messages() if m.get_type() == "STATUSTEXT"]
    assert texts == ["companion: stale ESC, flying without it"]


class ScriptedDetector:
    """A detector whose rotor 4 is confirmed from 0.1 s with the kind `kind_at(t_s)`."""

    def __init__(self, kind_at):
        self.kind_at = kind_at
        self.status = self._status(0.0)

    def _status(self, t_s: float) -> FaultStatus:
        confirmed = t_s >= 0.1
        limit = np.full(4, AF.thrust_max_n)
        if confirmed:
            limit[3] = AF.thrust_min_n
        kind = self.kind_at(t_s) if confirmed else FaultKind.UNKNOWN
        return FaultStatus(state=FaultState.CONFIRMED if confirmed else FaultState.HEALTHY,
                           rotor=4 if confirmed else None, kind=kind, thrust_max_estimate_n=limit,
                           thrust_bound_n=limit, detected_at_s=0.1 if confirmed else None,
                           message=f"thrust loss rotor 4 ({kind.name.lower()})" if confirmed else "",
                           deficit_n=np.zeros(4))

    def cannot_confirm(self, *_args) -> bool:
        return False                           # every frame may confirm: read before the solve

    def update(self, time_s: float, *_args, **_kwargs) -> FaultStatus:
        self.status = self._status(time_s)
        return self.status


class ConfirmedFrameAfterTheSend(ScriptedDetector):
    """The scripted detector, its frames read after the send once the fault is confirmed."""

    def cannot_confirm(self, *_args) -> bool:
        return self.status.state is FaultState.CONFIRMED


def test_a_frame_read_after_the_send_has_its_status_sent_alone_right_after_its_setpoint(rig):
    """Rotor 4 confirmed damaged at 0.1 s, lost from 0.3 s, its frames read after the send once
    confirmed: each of them goes out as its setpoint alone, then the status after the frame,
    stamped with it (one status an instant: the one at 0.3 s says propeller)."""
    app, fc, link, clock = rig
    app.controller.detector = ConfirmedFrameAfterTheSend(
        lambda t_s: FaultKind.DAMAGE if t_s < 0.3 else FaultKind.PROPELLER)
    fc.join(app)
    sends, send, send_all = [], link.send, link.send_all
    link.send = lambda msg: sends.append([msg]) or send(msg)
    link.send_all = lambda msgs: sends.append(list(msgs)) or send_all(msgs)
    fly(app, fc, clock, 0, 20)
    at_300 = [[(m.get_type(), getattr(m, "kind", None)) for m in group if m.get_type() != "TIMESYNC"]
              for group in sends if any(getattr(m, "time_boot_ms", None) == 300 for m in group)]
    assert at_300 == [[("M4_SETPOINT", None)], [("M4_FAULT_STATUS", int(FaultKind.PROPELLER))]]
    said = [(m.get_type(), m.time_boot_ms) for m in link.sent_messages()
            if m.get_type() in ("M4_SETPOINT", "M4_FAULT_STATUS")]
    statuses = [t_ms for kind_of, t_ms in said if kind_of == "M4_FAULT_STATUS"]
    assert statuses == sorted(set(statuses)) == [t_ms for kind_of, t_ms in said if kind_of == "M4_SETPOINT"]


def test_a_failing_preparation_is_said_and_counted_and_the_frames_status_has_gone_out_before_it(rig, caplog,
                                                                                                monkeypatch):
    """The work after the send is guarded as the step is: a defect there is one logged error and
    a counter, the companion flies on, and the frame's status left before the preparation ran."""
    app, fc, link, clock = rig
    app.controller.detector = ConfirmedFrameAfterTheSend(lambda t_s: FaultKind.PROPELLER)
    fc.join(app)

    def broken():
        raise RuntimeError("a defect in the preparation")
    monkeypatch.setattr(app.controller, "prepare", broken)      # the controller is the module's: undone after
    fly(app, fc, clock, 0, 20)
    statuses = [m.time_boot_ms for m in link.sent_messages() if m.get_type() == "M4_FAULT_STATUS"]
    assert {200, 300} <= set(statuses)
    assert app.counters.control_errors > 0 and "the detector or the NMPC's preparation failed" in caplog.text


def test_a_re_settled_fault_kind_is_announced_once_more_and_not_at_every_step(rig):
    """Damage confirmed at 0.1 s; the kind flips between damage and propeller every frame from
    0.3 s, settles on propeller at 0.5 s: one more announcement, 1 s after the first (the
    kind then), and none after."""
    app, fc, link, clock = rig

    def kind_at(t_s):
        flipping = 0.3 <= t_s < 0.5 and round(t_s / 0.02) % 2 == 0
        return FaultKind.DAMAGE if t_s < 0.3 or flipping else FaultKind.PROPELLER
    app.controller.detector = ScriptedDetector(kind_at)
    fc.join(app)
    critical = []
    for k in range(150):
        fly(app, fc, clock, 20 * k, 1)
        critical += [(20 * k, m.text) for m in link.sent_messages()
                     if m.get_type() == "STATUSTEXT" and m.severity == mavlink.MAV_SEVERITY_CRITICAL]
        link.sent.clear()
    assert critical == [(100, "thrust loss rotor 4 (damage)"), (1100, "thrust loss rotor 4 (propeller)")]


# -------------------------------------------------------------------------------------------------
def _frame(msg_id: int, payload: bytes, seq: int, sysid: int, compid: int) -> bytes:
    header = struct.pack("<BBBBBBBHB", 0xFD, len(payload), 0, 0, seq & 0xFF, sysid, compid, msg_id & 0xFFFF,
                         msg_id >> 16)
    crc_extra = mavlink.mavlink_map[msg_id].crc_extra if msg_id in mavlink.mavlink_map else 0
    crc = mavlink.x25crc(header[1:] + payload)
    crc.accumulate(struct.pack("B", crc_extra))
    return header + payload + struct.pack("<H", crc.crc)


class Fuzzer:
    """Datagrams of one MAVLink frame each (or garbage), counted by kind."""

    TELEMETRY = (mavlink.MAVLINK_MSG_ID_ATTITUDE, mavlink.MAVLINK_MSG_ID_ATTITUDE_QUATERNION,
                 mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED, mavlink.MAVLINK_MSG_ID_M4_JOINT_STATE,
                 mavlink.MAVLINK_MSG_ID_M4_THRUSTER_STATUS, mavlink.MAVLINK_MSG_ID_HEARTBEAT,
                 mavlink.MAVLINK_MSG_ID_COMMAND_ACK, mavlink.MAVLINK_MSG_ID_STATUSTEXT)

    def __init__(self, seed: int):
        self.rng = random.Random(seed)
        self.known = sorted(mavlink.mavlink_map)
        self.counts = {"garbage": 0, "bad_crc": 0, "unknown_id": 0, "random_fields": 0, "plausible": 0}
        self.seq = 0
        self.t_ms = 0

    def _ids(self) -> tuple[int, int]:
        return (FC_SYSTEM_ID, FC_COMPONENT_ID) if self.rng.random() < 0.9 else (self.rng.randrange(256),
                                                                              self.rng.randrange(256))

    def _random_payload(self, msg_id: int) -> bytes:
        size = mavlink.mavlink_map[msg_id].unpacker.size
        return bytes(self.rng.randrange(256) for _ in range(self.rng.randint(1, size)))

    def _plausible(self, msg_id: int) -> bytes:
        """A telemetry message with sane values, NaN/inf sprinkled in, time jumping around."""
        r = self.rng
        self.t_ms = max(0, self.t_ms + r.choice([20, 20, 20, 0, -20, -5000, 7]))
        f = [r.choice([r.uniform(-1, 1), r.uniform(-1, 1), r.uniform(-1, 1), math.nan, math.inf, 1e30])
             for _ in range(16)]
        build = {
            mavlink.MAVLINK_MSG_ID_ATTITUDE: lambda: mavlink.MAVLink_attitude_message(self.t_ms, *f[:6]),
            mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED:
                lambda: mavlink.MAVLink_local_position_ned_message(self.t_ms, *f[:6]),
            mavlink.MAVLINK_MSG_ID_M4_JOINT_STATE:
                lambda: mavlink.MAVLink_m4_joint_state_message(self.t_ms, [0.8 + v for v in f[:4]], f[4:8]),
            mavlink.MAVLINK_MSG_ID_M4_THRUSTER_STATUS:
                lambda: mavlink.MAVLink_m4_thruster_status_message(self.t_ms, [15 + v for v in f[:4]],
                                                                   [30 * v for v in f[8:12]]),
        }.get(msg_id, lambda: mavlink.MAVLink_attitude_quaternion_message(self.t_ms, 1.0, *f[:6], f[6:10]))
        return build().pack(new_mav(None, *self._ids()))

    def datagram(self) -> bytes:
        r = self.rng
        kind = r.random()
        self.seq += 1
        if kind < 0.2:
            self.counts["garbage"] += 1
            return bytes(r.randrange(256) for _ in range(r.randint(1, 300)))
        if kind < 0.35:
            self.counts["bad_crc"] += 1
            data = bytearray(_frame(r.choice(self.TELEMETRY), self._random_payload(r.choice(self.TELEMETRY)),
                                    self.seq, *self._ids()))
            data[r.randrange(1, len(data))] ^= 1 << r.randrange(8)
            return bytes(data)
        if kind < 0.45:
            self.counts["unknown_id"] += 1
            msg_id = r.choice([i for i in (r.randrange(1 << 24) for _ in range(3)) if i not in mavlink.mavlink_map])
            return _frame(msg_id, bytes(r.randrange(256) for _ in range(r.randint(1, 60))), self.seq, *self._ids())
        if kind < 0.75:
            self.counts["random_fields"] += 1
            msg_id = r.choice(self.TELEMETRY) if r.random() < 0.7 else r.choice(self.known)
            return _frame(msg_id, self._random_payload(msg_id), self.seq, *self._ids())
        self.counts["plausible"] += 1
        return self._plausible(r.choice(self.TELEMETRY[:5]))


def test_a_fuzzed_byte_stream_never_raises_and_never_lets_a_bad_setpoint_out(rig):
    app, fc, link, clock = rig
    fc.join(app)
    fuzz = Fuzzer(seed=4)
    senders = [FC_ADDRESS, FC_ADDRESS, FC_ADDRESS, ("127.0.0.1", 10)]
    for k in range(FUZZ_FRAMES):
        link.inbox.append((fuzz.datagram(), senders[k % len(senders)]))
        if k % 8 == 7:
            app.poll()
            clock.now += 0.004
    app.poll()
    health, telemetry = app.fc.health(), app.telemetry.counters
    sent = link.sent_messages()
    setpoints = [m for m in sent if m.get_type() == "M4_SETPOINT"]
    print(f"\nfuzz: {FUZZ_FRAMES} frames {fuzz.counts}; link: bad CRC {health.bad_crc}, foreign {health.foreign}; "
          f"telemetry: accepted {telemetry.accepted}, stale {telemetry.stale}, non-finite {telemetry.nonfinite}, "
          f"{len(setpoints)} setpoints sent")
    assert sum(fuzz.counts.values()) == FUZZ_FRAMES >= 100_000
    assert health.bad_crc > 0.1 * FUZZ_FRAMES and health.foreign > 0.2 * FUZZ_FRAMES
    assert telemetry.nonfinite > 0 and telemetry.stale > 0 and telemetry.accepted > 0
    assert setpoints, "the fuzz never completed a frame: it does not reach the controller"
    for m in setpoints:
        values = np.array([*m.thrust_n, *m.hip_angle_rad, *m.hip_rate_rad_s])
        assert np.all(np.isfinite(values))
        assert np.all((np.array(m.thrust_n) >= 0) & (np.array(m.thrust_n) <= AF.thrust_max_n))
        assert np.all((np.array(m.hip_angle_rad) >= AF.hip_min_rad) & (np.array(m.hip_angle_rad) <= AF.hip_max_rad))
        assert np.all(np.abs(m.hip_rate_rad_s) <= AF.hip_rate_max_rad_s)


def test_a_long_setpoint_lead_is_warned_once_published_and_planned_through(rig):
    """The FC answers our TIMESYNC requests as if each setpoint arrived 150 ms after the instant
    it answers, then 40 ms: one warning, one notice, never CRITICAL; the feed shows the lead."""
    app, fc, link, clock = rig
    app.feed, published = recording_feed()
    fc.join(app)
    answered = set()
    for k in range(140):
        lead_ms = 150 if k < 40 else 40
        for m in link.sent_messages():
            if m.get_type() == "TIMESYNC" and m.ts1 not in answered:
                answered.add(m.ts1)
                fc.send(mavlink.MAVLink_timesync_message(m.ts1 + lead_ms * 1_000_000, m.ts1))
        fly(app, fc, clock, 20 * k, 1)
        if k == 39:
            assert app.fc.delay.lead_s == pytest.approx(0.15)
            assert [p["lead_ms"] for t, p in published if t == "nmpc"][-1] == pytest.approx(150.0)
            assert [p["setpoint_lead_ms"] for t, p in published if t == "link"][-1] == pytest.approx(150.0)
    assert statustexts(link) == [(mavlink.MAV_SEVERITY_WARNING, "companion: link delay 150 ms"),
                     (mavlink.MAV_SEVERITY_NOTICE, "companion: link delay back to 40 ms")]


def test_a_gap_in_the_flight_log_is_sent_as_a_statustext_warning_and_published(rig, tmp_path, monkeypatch,
                                                                               wait_until):
    app, fc, link, clock = rig
    disk = FullDisk(tmp_path, monkeypatch)
    monkeypatch.setattr(flight_log, "RETRY_S", 0.05)
    app.flight_log = FlightLog(LogSettings(dir=tmp_path)).start()
    app.feed, published = recording_feed()
    fc.join(app)
    frames = iter(range(0, 10**6, 20))

    def fly_until(done) -> bool:
        return wait_until(lambda: fly(app, fc, clock, next(frames), 1) or done())

    try:
        assert fly_until(lambda: app.flight_log.records > 0)
        disk.full = True
        assert fly_until(lambda: app.flight_log.paused)
        fly(app, fc, clock, next(frames), 1)
        assert [p["flight_log_paused"] for t, p in published if t == "link"][-1] is True
        disk.full = False
        assert fly_until(lambda: not app.flight_log.paused)
        fly(app, fc, clock, next(frames), 1)
    finally:
        app.flight_log.close()
    said = statustexts(link)
    assert said[0] == (mavlink.MAV_SEVERITY_WARNING, "companion: log paused: No space left on device")
    assert said[1][0] == mavlink.MAV_SEVERITY_WARNING and said[1][1].startswith("companion: log resumed after a ")
    assert len(said) == 2
    link_payload = [p for t, p in published if t == "link"][-1]
    assert (link_payload["flight_log_paused"], link_payload["flight_log_gaps"]) == (False, 1)


def test_a_record_the_flight_log_cannot_pack_stops_the_log_not_the_flight(rig, tmp_path, monkeypatch, caplog):
    """The loop packs the log's records itself (after its send): a defect there used to end only
    the writer's thread, and would now end the loop. Said once, the log stops; the flight goes on."""
    app, fc, link, clock = rig
    app.flight_log = link.tlog = FlightLog(LogSettings(dir=tmp_path)).start()

    def unpackable(*args):
        raise ValueError("could not convert string to float: 'nan?'")

    monkeypatch.setattr(app.flight_log._decision_frames, "pack", unpackable)     # every decision's record
    try:
        with caplog.at_level(logging.INFO, logger="m4-companion"):
            fc.join(app)
            fly(app, fc, clock, 0, 3)
            queued = app.flight_log.position()
            fly(app, fc, clock, 60, 3)
    finally:
        app.flight_log.close()
    assert setpoint_times(link) == list(range(0, 120, 20))
    said = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert said == [("flight log stopped for the rest of the process: cannot pack its records (ValueError: could "
                     "not convert string to float: 'nan?'); the flight goes on")]
    assert app.flight_log.position() == queued and not app.flight_log._queue      # nothing queued since

def test_overruns_are_sent_as_statustext_warnings_at_most_every_5_s_with_their_count_and_published(rig, monkeypatch):
    app, fc, link, clock = rig
    real_step = app.controller.step

    def slow_step(*args, **kwargs):
        clock.now += 0.03                                   # 30 ms: over the 20 ms period
        return real_step(*args, **kwargs)

    monkeypatch.setattr(app.controller, "step", slow_step)
    app.feed, published = recording_feed()
    fc.join(app)
    fly(app, fc, clock, 0, 250)                             # a step every 50 ms of the clock: 12.5 s
    said = statustexts(link)
    assert {severity for severity, _ in said} == {mavlink.MAV_SEVERITY_WARNING}
    assert len(said) == 3 and said[0][1] == "companion: 1 overruns, 1 Hz, max 30 ms"
    for _, text in said[1:]:                                # 5 s of steps 50 ms apart (give or take one)
        assert re.fullmatch(r"companion: 10[01] overruns, 2[01] Hz, max 30 ms", text), text
    assert [p["overruns"] for t, p in published if t == "link"][-1] == 250


def test_a_new_flight_starts_its_log_file_with_its_poll_though_the_writer_drains_during_the_answer(rig, tmp_path,
                                                                                                 monkeypatch):
    """The flight log's writer thread may drain while the answer's send gives up the GIL: the
    arming HEARTBEAT read in the same poll must have marked the new flight by then, or its packets
    land in the last flight's file."""
    app, fc, link, clock = rig
    monkeypatch.setattr(flight_log, "FLUSH_S", 3600.0)       # the writer drains only where this test says
    monkeypatch.setattr(flight_log, "IDLE_FLUSH_S", 3600.0)
    app.flight_log = link.tlog = FlightLog(LogSettings(dir=tmp_path)).start()
    send = app.fc.send_setpoint

    def draining_send(*args, **kwargs):
        app.flight_log._flush()                              # what the writer thread may do here
        send(*args, **kwargs)

    monkeypatch.setattr(app.fc, "send_setpoint", draining_send)
    try:
        fc.join(app)                                         # its HEARTBEAT says disarmed
        fly(app, fc, clock, 0, 3)
        fc.send(mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_QUADROTOR, 0, mavlink.MAV_MODE_FLAG_SAFETY_ARMED,
                                                  0, 4, 3))
        fly(app, fc, clock, 60, 3)                           # armed, and its first frame answered in that poll
    finally:
        app.flight_log.close()
    assert len(app.flight_log.files) == 2
    assert [_heartbeats_armed(path) for path in app.flight_log.files] == [[False], [True]]


def _heartbeats_armed(tlog) -> list[bool]:
    """Armed or not, each HEARTBEAT from the FC in a flight log file."""
    conn = mavutil.mavlink_connection(str(tlog), dialect="m4")
    out = []
    while (msg := conn.recv_match(type="HEARTBEAT")) is not None:
        if msg.get_srcComponent() == FC_COMPONENT_ID:
            out.append(bool(msg.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED))
    conn.close()
    return out
