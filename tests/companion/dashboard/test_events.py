import json
import math
import threading

import numpy as np
import pytest

from companion.dashboard.events import (Hub, ReplayError, ReplaySource, dashboard_event, hub_positions,
                                        read_recorded_feed)
from m4.airframe import load_airframe

AF = load_airframe()


def _state(t_s, hip_deg=(45.0, 45.0, 45.0, 45.0)):
    return {"t_s": t_s, "hip_deg": list(hip_deg), "euler_deg": [0.0, 0.0, 0.0]}


def test_state_events_carry_the_hubs_the_airframe_places_for_the_measured_hips():
    hips_deg = [90.0, 0.0, 72.3, 0.0]
    event = dashboard_event("m4/m4/state", _state(1.0, hips_deg), AF)
    expected = AF.thruster_positions_frd_m(np.radians(hips_deg))
    assert event["topic"] == "state"
    np.testing.assert_allclose(event["hub_frd_m"], expected, atol=1e-5)
    assert event["hub_frd_m"][0][1] == pytest.approx(0.10 + AF.leg_length_m, abs=1e-5)   # rotor 1 straight out right


def test_unknown_hips_give_no_hubs_and_foreign_keys_no_event():
    assert hub_positions(AF, [45.0, None, 45.0, 45.0]) is None
    assert hub_positions(AF, [45.0, 45.0]) is None
    assert dashboard_event("m4/m4/other", {"t_s": 0.0}, AF) is None
    assert dashboard_event("m4/m4/state", [1, 2], AF) is None
    assert "hub_frd_m" not in dashboard_event("m4/m4/nmpc", {"t_s": 0.0}, AF)


def test_hub_gives_a_new_page_the_newest_of_each_topic_then_what_follows():
    hub = Hub(AF)
    hub.take("m4/m4/state", json.dumps(_state(1.0)).encode())
    hub.take("m4/m4/state", json.dumps(_state(2.0)).encode())
    hub.take("m4/m4/fault", b'{"t_s": 2.0, "state": "healthy"}')
    stop = threading.Event()
    page = hub.events(stop)
    first = [next(page), next(page)]
    assert sorted((e["topic"], e["payload"]["t_s"]) for e in first) == [("fault", 2.0), ("state", 2.0)]
    hub.take("m4/m4/nmpc", b'{"t_s": 3.0, "solve_ms": 1.0}')
    assert next(page)["topic"] == "nmpc"
    stop.set()
    assert next(page, "finished") == "finished"


def test_hub_counts_unreadable_samples_and_refuses_nan():
    hub = Hub(AF)
    hub.take("m4/m4/state", b"not json")
    hub.take("m4/m4/state", b'{"t_s": NaN}')
    hub.take("m4/m4/elsewhere", b'{"t_s": 1.0}')
    assert hub.bad_samples == 3 and hub.latest() == {}


def test_a_slow_page_loses_its_oldest_events_not_the_newest():
    hub = Hub(AF, max_events=3)
    stop = threading.Event()
    page = hub.events(stop)
    hub.take("m4/m4/nmpc", b'{"t_s": 0.0}')        # the page registers on its first next()
    assert next(page)["payload"]["t_s"] == 0.0
    for k in range(1, 6):
        hub.take("m4/m4/nmpc", json.dumps({"t_s": float(k)}).encode())
    assert [next(page)["payload"]["t_s"] for _ in range(3)] == [3.0, 4.0, 5.0]
    stop.set()


def test_recorded_feed_skips_cut_lines_and_names_a_bad_file(tmp_path):
    path = tmp_path / "feed.jsonl"
    path.write_text(json.dumps({"key": "m4/m4/state", "payload": _state(0.0)}) + "\n"
                    + '{"key": "m4/m4/state", "payl\n' + '"just a string"\n')
    assert [k for k, _ in read_recorded_feed(path)] == ["m4/m4/state"]
    with pytest.raises(ReplayError, match="cannot read"):
        read_recorded_feed(tmp_path / "missing.jsonl")
    (tmp_path / "empty.jsonl").write_text("")
    with pytest.raises(ReplayError, match="no feed samples"):
        read_recorded_feed(tmp_path / "empty.jsonl")


class FakeClock:
    def __init__(self):
        self.now_s = 100.0

    def __call__(self):
        return self.now_s


class SleepingStop(threading.Event):
    """A stop event whose wait() advances the fake clock instead of sleeping."""

    def __init__(self, clock):
        super().__init__()
        self.clock = clock

    def wait(self, timeout=None):
        self.clock.now_s += timeout
        return self.is_set()


def test_replay_paces_by_the_flight_clock_at_the_requested_speed():
    samples = [("m4/m4/state", _state(t)) for t in (10.0, 10.5, 12.0)] + [("m4/m4/link", {"t_s": None})]
    source = ReplaySource(samples, AF, speed=2.0)
    clock = FakeClock()
    emitted = []
    for event in source.events(SleepingStop(clock), clock=clock):
        if event is not None:
            emitted.append((event["payload"]["t_s"], clock.now_s - 100.0))
    assert emitted == [(10.0, 0.0), (10.5, 0.25), (12.0, 1.0), (None, 1.0)]
    assert source.duration_s == 2.0


def test_replay_stops_when_asked_and_refuses_a_bad_speed():
    source = ReplaySource([("m4/m4/state", _state(t)) for t in (0.0, 100.0)], AF)
    stop = threading.Event()
    events = source.events(stop)
    assert next(events)["payload"]["t_s"] == 0.0
    stop.set()
    assert list(events) == []
    for speed in (0.0, -1.0, math.inf):
        with pytest.raises(ReplayError, match="speed"):
            ReplaySource([("m4/m4/state", _state(0.0))], AF, speed=speed)
    with pytest.raises(ReplayError, match="no sample"):
        ReplaySource([("m4/m4/other", {"t_s": 0.0})], AF)


def test_a_seek_sends_the_history_before_its_instant_at_once_then_paces_from_there():
    samples = [("m4/m4/state", _state(t)) for t in (0.0, 10.0, 25.0, 30.0, 31.0, 40.0)]
    source = ReplaySource(samples, AF, speed=1.0)
    clock = FakeClock()
    emitted = [(e["payload"]["t_s"], clock.now_s - 100.0) for e in source.events(SleepingStop(clock), clock=clock,
                                                                                   from_s=30.5) if e is not None]
    # the newest before the 20 s window (10.0), the window (25, 30) at once; 31 at once, 40 nine seconds on
    assert emitted == [(10.0, 0.0), (25.0, 0.0), (30.0, 0.0), (31.0, 0.0), (40.0, 9.0)]
    assert source.start_s == 0.0 and source.duration_s == 40.0
