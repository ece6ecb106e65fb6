"""Link delay and loss emulated in simulated time by `m4-sitl serve` (sitl/links/emulation.py):
real sockets on loopback, the real plant, a stand-in companion answering every frame."""

from __future__ import annotations

import time

import pytest

from m4.mavlink import mavlink
from m4.mavlink.link import UdpLink, wait_readable
from sitl.links import emulation as link_emulation
from sitl.cli import main
from sitl.links.emulation import EmulationError, LinkEmulation, LossDraw
from m4.scenario import Scenario
from sitl.serve import ServeOptions
from sitl.standin_companion import StandInCompanion, served

HOVER = Scenario(name="hover", duration_s=60.0)
PERIOD_MS = 20


class TimesyncCompanion(StandInCompanion):
    """Sends a TIMESYNC request (ts1: the answered instant in ns) with every setpoint, in the
    same datagram, as companion/fc_link.py does."""

    def send(self, msg) -> None:
        if msg.get_msgId() != mavlink.MAVLINK_MSG_ID_M4_SETPOINT:
            super().send(msg)
            return
        with self._send_lock:
            self.link.send_all([msg, mavlink.MAVLink_timesync_message(0, msg.time_boot_ms * 1_000_000)])


def _fly(link: LinkEmulation, seconds: float = 1.0, seed: int = 0, companion: StandInCompanion | None = None):
    """(the companion, the server, [(message type, FC instant handled, message)] for everything
    the FC handled); a deadlock would leave the end unreached."""
    companion = companion or StandInCompanion(period_ms=PERIOD_MS)
    handled = []

    def record(server):
        fc = server.vehicle.fc
        handle = fc.handle

        def recording(msg, now_ms, link=0):
            handled.append((msg.get_type(), now_ms, msg))
            return handle(msg, now_ms, link)
        fc.handle = recording

    options = ServeOptions(scenario=HOVER, duration_s=seconds, link=link, seed=seed, lockstep_timeout_s=30.0)
    end_ms = round(seconds * 1000)
    with served(companion, options, prepare=record) as server:
        deadline = time.monotonic() + 25.0
        while server.vehicle.now_ms < end_ms and time.monotonic() < deadline:
            time.sleep(0.01)
    assert server.vehicle.now_ms == end_ms, "the lockstep flight did not reach its end"
    return companion, server, handled


def test_an_answer_acts_exactly_two_delays_later_and_timesync_measures_that_lead():
    delay_ms = 7                                   # 2 D = 14 ms: between the FC's own instants
    companion, server, handled = _fly(LinkEmulation(delay_ms=delay_ms), companion=TimesyncCompanion())
    setpoints = [(now, m.time_boot_ms) for kind, now, m in handled if kind == "M4_SETPOINT"]
    assert len(setpoints) >= 40
    assert all(now == t + 2 * delay_ms for now, t in setpoints)
    assert server.vehicle.fc.counters.setpoints_accepted == len(setpoints)
    replies = [m for m in companion.of_type("TIMESYNC") if m.tc1 != 0]
    assert len(replies) >= 40
    assert {m.tc1 - m.ts1 for m in replies} == {2 * delay_ms * 1_000_000}


def _losses(seed: int):
    companion, server, handled = _fly(LinkEmulation(delay_ms=5, loss=0.3), seed=seed)
    frames = {m.time_boot_ms for m in companion.of_type("M4_THRUSTER_STATUS")}
    applied = {m.time_boot_ms for kind, _, m in handled if kind == "M4_SETPOINT"}
    return frames, applied, server.emulated.counters


def test_loss_drops_the_same_frames_and_setpoints_for_a_seed_and_the_fc_never_waits_for_them():
    frames, applied, counters = _losses(seed=3)
    again_frames, again_applied, _ = _losses(seed=3)
    other_frames, other_applied, _ = _losses(seed=4)
    instants = set(range(0, 1000, PERIOD_MS))
    lost_frames = instants - frames
    assert 0.15 < len(lost_frames) / len(instants) < 0.45
    assert counters.lost_up > 0 and counters.lost_down > 0
    answered = {t for t in frames if t < 1000}
    assert applied < answered and 0.55 < len(applied) / len(answered) < 0.85      # some answers lost on the way up
    assert (frames, applied) == (again_frames, again_applied)
    assert (frames, applied) != (other_frames, other_applied)


def test_without_loss_every_frame_is_answered_and_applied():
    companion, server, handled = _fly(LinkEmulation(delay_ms=20))
    frames = {m.time_boot_ms for m in companion.of_type("M4_THRUSTER_STATUS") if m.time_boot_ms < 960}
    applied = {m.time_boot_ms for kind, _, m in handled if kind == "M4_SETPOINT"}
    assert frames == set(range(0, 960, PERIOD_MS)) and frames <= applied
    assert server.emulated.counters.lost_up == server.emulated.counters.lost_down == 0


def test_a_loss_draw_depends_on_what_is_sent_when_not_on_what_came_before():
    draw, other = LossDraw(seed=1, loss=0.5), LossDraw(seed=1, loss=0.5)
    for t in range(0, 2000, 20):
        other.lost("down", t, mavlink.MAVLINK_MSG_ID_HEARTBEAT)          # extra datagrams at each instant
    first = [draw.lost("down", t, mavlink.MAVLINK_MSG_ID_ATTITUDE) for t in range(0, 2000, 20)]
    second = [other.lost("down", t, mavlink.MAVLINK_MSG_ID_ATTITUDE) for t in range(0, 2000, 20)]
    assert first == second and 30 < sum(first) < 70


@pytest.mark.parametrize("delay_ms, loss", [(-1.0, 0.0), (2000.5, 0.0), (0.0, 1.0), (0.0, -0.1)])
def test_out_of_range_impairments_are_refused(delay_ms, loss):
    with pytest.raises(EmulationError):
        LinkEmulation(delay_ms=delay_ms, loss=loss)


@pytest.mark.parametrize("args, named", [(["--link-delay-ms", "2500"], "0..2000 ms"),
                                         (["--link-delay-ms", "soon"], "not a number"),
                                         (["--link-loss", "1"], "1 excluded")])
def test_the_cli_refuses_bad_impairments_in_one_line(capsys, args, named):
    for command in (["serve"], ["fly", "hover-rotor-loss"], ["compare"], ["campaign"]):
        assert main([*command, *args]) == 2
        err = capsys.readouterr().err
        assert named in err and err.count("\n") == 1


class SlowCompanion(TimesyncCompanion):
    """Takes 15 ms (wall clock) to answer."""

    def send(self, msg) -> None:
        if msg.get_msgId() == mavlink.MAVLINK_MSG_ID_M4_SETPOINT:
            time.sleep(0.015)
        super().send(msg)


def test_in_real_time_the_lead_is_two_delays_plus_the_companions_own_time():
    companion = SlowCompanion(period_ms=PERIOD_MS)
    options = ServeOptions(scenario=HOVER, duration_s=60.0, link=LinkEmulation(delay_ms=20), realtime=True)
    with served(companion, options):
        companion.wait_for("TIMESYNC", lambda m: m.tc1 != 0 and m.ts1 >= 500_000_000, 20.0)
    leads_ms = [(m.tc1 - m.ts1) / 1e6 for m in companion.of_type("TIMESYNC") if m.tc1 != 0]
    assert len(leads_ms) >= 10
    assert min(leads_ms) >= 40 and max(leads_ms) > 40          # the FC's clock ran on while it answered


def test_a_flood_is_held_up_to_a_bound_and_handed_over_at_its_instant(monkeypatch):
    monkeypatch.setattr(link_emulation, "HELD_MAX", 5)
    now = {"ms": 100}
    fc = link_emulation.EmulatedLink("udpin:127.0.0.1:0", 1, 1, emulation=LinkEmulation(delay_ms=10), seed=0,
                                     clock=lambda: now["ms"])
    sender = UdpLink(f"udpout:127.0.0.1:{fc.local_port}", 1, 191)
    try:
        for _ in range(20):
            sender.send(mavlink.MAVLink_heartbeat_message(18, 8, 0, 0, 4, 3))
        deadline = time.monotonic() + 5.0
        while fc.counters.received < 20 and time.monotonic() < deadline:
            wait_readable([fc], 0.1)
            assert fc.receive_from() == []                     # nothing is due before 100 + 2 D
        assert (fc.counters.received, fc.counters.lost_up, fc.next_delivery_ms()) == (20, 15, 120)
        now["ms"] = 119
        assert fc.deliver() == []
        now["ms"] = 120
        assert [m.get_type() for _, msgs in fc.deliver() for m in msgs] == ["HEARTBEAT"] * 5
    finally:
        sender.close()
        fc.close()
