import json
import logging
import math
import time

import numpy as np
import pytest
import zenoh

from companion.feed_publisher import open_feed
from m4.feed.payloads import TOPICS, key_for
from m4.feed.settings import FeedSettings, parse_feed_settings
from m4.feed.transport import FeedError
from m4.feed import payloads
from companion.feed_publisher import Feed
from m4.feed.transport import config_from_endpoints, config_from_file, open_session
from m4.toml_fields import ConfigError, Table


# --- payloads: plain data in, strict JSON out ----------------------------------------------

def test_state_payload_has_units_in_names_degrees_for_angles_and_null_for_nan(topic_fields):
    p = payloads.state_payload(5.0, 1.7e9, **topic_fields["state"])
    assert p["t_s"] == 5.0 and p["wall_time_unix_s"] == 1.7e9
    assert p["pos_ned_m"] == [1.0, -2.0, -3.0]
    assert p["euler_deg"] == pytest.approx([0.0, 10.0, 180.0])
    assert p["hip_deg"] == pytest.approx([30.0] * 4)
    assert p["rates_frd_rad_s"] == pytest.approx([0.01, -0.02, 3.5])
    assert p["thrust_n"] == [7.0, 7.5, 8.0, None]          # NaN from the FC: unknown
    json.dumps(p, allow_nan=False)


def test_setpoint_payload_converts_hip_angles_and_rates_to_degrees(topic_fields):
    p = payloads.setpoint_payload(5.0, 0.0, **topic_fields["setpoint"])
    assert p["hip_deg"] == pytest.approx([45.0] * 4)
    assert p["hip_rate_deg_s"] == pytest.approx([90.0, 0.0, 0.0, 0.0])
    assert p["thrust_cut"] is False


def test_nmpc_payload_lists_one_predicted_position_per_node(topic_fields):
    p = payloads.nmpc_payload(5.0, 0.0, **topic_fields["nmpc"])
    assert p["predicted_p_ned_m"] == topic_fields["nmpc"]["predicted_p_ned_m"].tolist()
    assert (p["solve_ms"], p["iterations"], p["ok"], p["fallback"]) == (3.25, 2, True, False)
    assert p["altitude_first"] is False
    assert payloads.nmpc_payload(5.0, 0.0, **topic_fields["nmpc"], altitude_first=True)["altitude_first"] is True
    assert p["disturbance_force_ned_n"] == [None] * 3 and p["disturbance_torque_frd_n_m"] == [None] * 3   # not given
    json.dumps(p, allow_nan=False)


def test_nmpc_payload_carries_the_disturbance_estimate_the_solve_planned_with(topic_fields):
    p = payloads.nmpc_payload(5.0, 0.0, **topic_fields["nmpc"], disturbance_force_ned_n=np.array([-3.5, 1.0, np.nan]),
                              disturbance_torque_frd_n_m=np.array([0.0, 0.25, -0.5]))
    assert p["disturbance_force_ned_n"] == [-3.5, 1.0, None] and p["disturbance_torque_frd_n_m"] == [0.0, 0.25, -0.5]
    with pytest.raises(ValueError, match="disturbance_force_ned_n"):
        payloads.nmpc_payload(5.0, 0.0, **topic_fields["nmpc"], disturbance_force_ned_n=[1.0, 2.0])


def test_fault_payload_takes_the_detector_state_number_and_keeps_the_statustext_words(topic_fields):
    fields = dict(topic_fields["fault"], state=2)             # M4_FAULT_STATUS: 2 = confirmed
    p = payloads.fault_payload(5.0, 0.0, **fields)
    assert (p["state"], p["rotor"], p["message"]) == ("confirmed", 4, "thrust loss rotor 4")
    assert p["thrust_max_estimate_n"] == [30.0, 30.0, 30.0, 0.0]
    healthy = payloads.fault_payload(1.0, 0.0, state="healthy", rotor=None,
                                     thrust_max_estimate_n=np.full(4, 30.0), message="")
    assert healthy["rotor"] is None and healthy["detected_at_s"] is None


@pytest.mark.parametrize("build, fields, named", [
    (payloads.state_payload, {"pos_ned_m": [0.0, 0.0]}, "pos_ned_m"),
    (payloads.fault_payload, {"state": "broken"}, "fault state"),
    (payloads.fault_payload, {"rotor": 5}, "fault rotor"),
    (payloads.nmpc_payload, {"predicted_p_ned_m": np.zeros((6, 2))}, "predicted_p_ned_m"),
    (payloads.link_payload, {"bad_crc": -1}, "bad_crc"),
])
def test_malformed_field_is_an_error_naming_the_field(topic_fields, build, fields, named):
    topic = build.__name__.removesuffix("_payload")
    base = dict(topic_fields[topic], feed_errors=0) if topic == "link" else topic_fields[topic]
    with pytest.raises(ValueError, match=named):
        build(1.0, 0.0, **{**base, **fields})


@pytest.mark.parametrize("vehicle", ["m4/x", "*", "m4 x", ""])
def test_vehicle_name_that_would_change_the_key_expression_is_rejected(vehicle):
    with pytest.raises(ValueError, match="vehicle"):
        key_for(vehicle, "state")


# --- the Feed object, without Zenoh ----------------------------------------------------------

class RecordingSink:
    def __init__(self, fail: bool = False):
        self.fail = fail
        self.sent: list[tuple[str, dict]] = []
        self.closed = False

    def put(self, topic, payload):
        if self.fail:
            raise ConnectionError("network down")
        self.sent.append((topic, payload))

    def close(self):
        self.closed = True


class FakeClock:
    def __init__(self):
        self.now_s = 100.0

    def __call__(self):
        return self.now_s


def test_disabled_feed_accepts_every_call_and_does_nothing(publish_all):
    feed = open_feed(FeedSettings(enabled=False, vehicle="not a valid name"))
    assert not feed.enabled
    publish_all(feed)
    feed.state(1.0, pos_ned_m="nonsense")                 # not even built, so no error
    feed.close()
    assert (feed.published, feed.errors) == (0, 0)


def test_failing_sink_is_counted_and_reported_in_link_health_never_raised(publish_all, topic_fields):
    sink = RecordingSink(fail=True)
    feed = Feed(sink)
    publish_all(feed)
    feed.state(1.0, pos_ned_m=[0.0])                       # a payload that cannot be built
    assert feed.errors == len(TOPICS) + 1 and feed.published == 0
    sink.fail = False
    feed.link(2.0, **topic_fields["link"])
    assert sink.sent[-1][1]["feed_errors"] == len(TOPICS) + 1


def test_each_topic_is_published_at_most_at_the_rate_limit(topic_fields):
    sink, clock = RecordingSink(), FakeClock()
    feed = Feed(sink, max_rate_hz=10.0, clock=clock)
    for _ in range(5):                                      # 5 calls within 40 ms: one goes out
        feed.state(1.0, **topic_fields["state"])
        clock.now_s += 0.01
    clock.now_s += 0.1
    feed.state(1.1, **topic_fields["state"])
    assert [p["t_s"] for _, p in sink.sent] == [1.0, 1.1]


def test_each_topic_goes_out_at_what_a_viewer_needs_under_the_rate_limit(publish_all):
    """State and setpoint 20 Hz, the NMPC 10, the fault and the link's health 2: three seconds of
    calls at 100 Hz."""
    sink, clock = RecordingSink(), FakeClock()
    feed = Feed(sink, max_rate_hz=20.0, clock=clock)
    for k in range(300):
        clock.now_s = 100.0 + k / 100.0
        publish_all(feed)
    counts = {topic: sum(1 for sent, _ in sink.sent if sent == topic) for topic in TOPICS}
    assert counts == pytest.approx({"state": 60, "setpoint": 60, "nmpc": 30, "fault": 6, "link": 6}, rel=0.2)


def test_a_topic_not_due_is_not_wanted_so_its_fields_need_not_be_gathered(topic_fields):
    sink, clock = RecordingSink(), FakeClock()
    feed = Feed(sink, max_rate_hz=20.0, clock=clock)
    assert feed.wants("link")
    feed.link(1.0, **topic_fields["link"])
    clock.now_s += 0.1
    assert not feed.wants("link") and feed.wants("state")
    clock.now_s += 0.5
    assert feed.wants("link")
    assert not Feed.disabled().wants("state")


def test_fault_change_goes_out_at_once_despite_the_rate_limit(topic_fields):
    sink, clock = RecordingSink(), FakeClock()
    feed = Feed(sink, max_rate_hz=1.0, clock=clock)
    healthy = dict(topic_fields["fault"], state="healthy", rotor=None, message="")
    feed.fault(1.0, **healthy)
    clock.now_s += 0.01
    feed.fault(1.01, **healthy)                             # same status: rate-limited
    clock.now_s += 0.01
    feed.fault(1.02, **topic_fields["fault"])               # confirmed: immediately
    assert [(p["t_s"], p["state"]) for _, p in sink.sent] == [(1.0, "healthy"), (1.02, "confirmed")]


# --- settings -------------------------------------------------------------------------------

def test_feed_table_defaults_to_vehicle_m4_and_resolves_a_relative_zenoh_config(tmp_path):
    s = parse_feed_settings(Table({"zenoh_config": "zenoh.json5"}, "companion.toml [feed]"), tmp_path)
    assert (s.enabled, s.vehicle, s.zenoh_config) == (True, "m4", tmp_path / "zenoh.json5")


@pytest.mark.parametrize("table, named", [
    ({"mode": "client"}, "client mode needs connect"),
    ({"zenoh_config": "z.json5", "connect": "tcp/127.0.0.1:7447"}, "either zenoh_config"),
    ({"zenoh_config": "z.json5", "mode": "client"}, "either zenoh_config"),
    ({"connect": "127.0.0.1:7447"}, "connect"),
    ({"vehicle": "m4/*", "connect": "tcp/127.0.0.1:7447"}, "vehicle"),
    ({"mode": "router"}, "mode"),
    ({"rate": 5}, "unknown key"),
])
def test_bad_feed_table_is_an_error_that_says_what(table, named):
    with pytest.raises(ConfigError, match=named):
        parse_feed_settings(Table(table, "companion.toml [feed]"))


def test_bad_zenoh_config_file_is_an_error_naming_the_file(tmp_path):
    bad = tmp_path / "bad.json5"
    bad.write_text("{ mode: 'peer', scouting: { multicast: { enabled: 'maybe' } } }")
    with pytest.raises(FeedError, match="bad.json5"):
        config_from_file(bad)
    with pytest.raises(FeedError, match="no such"):
        config_from_file(tmp_path / "missing.json5")


# --- over Zenoh on loopback (scouting off, 127.0.0.1 only) ------------------------------------

def _subscribe(endpoint, key):
    session = open_session(config_from_endpoints("client", connect=(endpoint,)), endpoint)
    received: dict[str, tuple[str, dict]] = {}
    session.declare_subscriber(key, lambda s: received.__setitem__(
        str(s.key_expr), (str(s.encoding), json.loads(s.payload.to_bytes()))))
    return session, received


def _peer_config(endpoint: str) -> str:
    return json.dumps({"mode": "peer", "listen": {"endpoints": [endpoint]}, "connect": {"endpoints": []},
                       "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": False}}})


def _feed_until_received(feed, received, publish_all, wait_until):
    return wait_until(lambda: publish_all(feed) or len(received) == len(TOPICS))


def test_subscriber_receives_every_topic_under_its_key_as_json(endpoint, publish_all, wait_until):
    feed = open_feed(FeedSettings(vehicle="test", listen=(endpoint,), max_rate_hz=0.0))
    session, received = _subscribe(endpoint, "m4/test/**")
    try:
        assert _feed_until_received(feed, received, publish_all, wait_until)
    finally:
        session.close()
        feed.close()
    assert set(received) == {f"m4/test/{t}" for t in TOPICS}
    assert {enc for enc, _ in received.values()} == {"application/json"}
    state = received["m4/test/state"][1]
    assert state["euler_deg"] == pytest.approx([0.0, 10.0, 180.0]) and state["thrust_n"][3] is None
    assert received["m4/test/fault"][1]["message"] == "thrust loss rotor 4"
    assert received["m4/test/link"][1]["feed_errors"] == 0
    assert math.isclose(received["m4/test/nmpc"][1]["solve_ms"], 3.25)


def test_feed_opened_from_a_zenoh_config_file_publishes(tmp_path, endpoint, publish_all, wait_until):
    config = tmp_path / "zenoh-companion.json5"
    config.write_text(_peer_config(endpoint))
    feed = open_feed(FeedSettings(zenoh_config=config, max_rate_hz=0.0))
    session, received = _subscribe(endpoint, "m4/m4/**")
    try:
        assert _feed_until_received(feed, received, publish_all, wait_until)
    finally:
        session.close()
        feed.close()


def test_publishing_after_the_session_died_is_counted_not_raised(endpoint, publish_all):
    feed = open_feed(FeedSettings(listen=(endpoint,), max_rate_hz=0.0))
    feed._sink.close()                      # the session goes away under the feed
    publish_all(feed)
    assert feed.errors == len(TOPICS) and feed.published == 0
    feed.close()


def test_a_missing_or_broken_zenoh_config_file_is_said_once_and_the_feed_comes_up_when_it_is_fixed(
        tmp_path, endpoint, publish_all, wait_until, caplog):
    config = tmp_path / "zenoh-companion.json5"
    with caplog.at_level(logging.INFO, logger="companion.feed_publisher"):
        feed = open_feed(FeedSettings(zenoh_config=config, max_rate_hz=0.0), retry_s=0.05)
        try:
            assert feed.enabled and not feed.up
            publish_all(feed)                                       # nowhere to go: dropped, not an error
            config.write_text("{ mode: 'peer', scouting: { multicast: { enabled: 'maybe' } } }")
            time.sleep(0.2)                                         # tried again: broken now
            assert not feed.up and feed.errors == 0
            config.write_text(_peer_config(endpoint))
            assert wait_until(lambda: feed.up)
            session, received = _subscribe(endpoint, "m4/m4/**")
            try:
                assert _feed_until_received(feed, received, publish_all, wait_until)
            finally:
                session.close()
        finally:
            feed.close()
    said = [r.getMessage() for r in caplog.records]
    assert len([m for m in said if m.startswith("feed down")]) == 1, said
    assert "no such Zenoh config file" in said[0] and str(config) in said[0]
    assert any(m.startswith("feed up") for m in said)


def test_a_client_feed_without_its_router_waits_for_it_and_publishes_once_it_is_there(
        endpoint, publish_all, wait_until):
    feed = open_feed(FeedSettings(vehicle="test", mode="client", connect=(endpoint,), max_rate_hz=0.0), retry_s=0.05)
    router = None
    try:
        assert feed.enabled and not feed.up
        router = open_session(config_from_endpoints("peer", listen=(endpoint,)), endpoint)
        assert wait_until(lambda: feed.up)
        received: dict[str, dict] = {}
        router.declare_subscriber("m4/test/**", lambda s: received.__setitem__(str(s.key_expr), s))
        assert _feed_until_received(feed, received, publish_all, wait_until)
    finally:
        feed.close()
        if router is not None:
            router.close()
    assert not feed.enabled


def test_client_session_to_an_endpoint_that_is_down_fails_with_a_clear_error():
    with pytest.raises(FeedError, match="cannot open the Zenoh session"):
        open_session(config_from_endpoints("client", connect=("tcp/127.0.0.1:1",)), "tcp/127.0.0.1:1")


def test_explicit_peer_listens_only_where_told():
    cfg = config_from_endpoints("peer", listen=())
    assert json.loads(cfg.get_json("listen/endpoints")) == []
    assert json.loads(cfg.get_json("scouting/multicast/enabled")) is False
    assert isinstance(cfg, zenoh.Config)
