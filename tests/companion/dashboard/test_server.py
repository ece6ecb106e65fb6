"""The dashboard's HTTP side and its command line, over real sockets on 127.0.0.1."""

import http.client
import json
import re
import time
from urllib.parse import urlsplit

import pytest

from companion.dashboard import command
from companion.dashboard.events import ReplaySource, read_recorded_feed
from companion.dashboard.server import STATIC, static_file
from m4.airframe import load_airframe
from m4.feed.payloads import TOPICS

from .conftest import FEED


def _get(url: str, path: str) -> tuple[int, str, bytes]:
    parts = urlsplit(url)
    conn = http.client.HTTPConnection(parts.hostname, parts.port, timeout=10)
    try:
        conn.request("GET", path)
        reply = conn.getresponse()
        return reply.status, reply.getheader("Content-Type"), reply.read()
    finally:
        conn.close()


def read_events(url: str, wanted, timeout_s: float = 10.0, path: str = "/events") -> list[dict]:
    """Events from /events (or `path`) until wanted(events) is true, the stream ends, or the timeout."""
    parts = urlsplit(url)
    conn = http.client.HTTPConnection(parts.hostname, parts.port, timeout=timeout_s)
    events: list[dict] = []
    deadline = time.monotonic() + timeout_s
    try:
        conn.request("GET", path)
        reply = conn.getresponse()
        assert reply.getheader("Content-Type") == "text/event-stream"
        name = None
        while not wanted(events) and time.monotonic() < deadline:
            line = reply.readline().decode()
            if not line:
                break
            if line.startswith("event: "):
                name = line[7:].strip()
            elif line.startswith("data: "):
                events.append({"end": True} if name == "end" else json.loads(line[6:]))
                name = None
    finally:
        conn.close()
    return events


def test_the_page_is_self_contained():
    for name, _ in STATIC.values():
        text = static_file(name).decode()
        assert not re.search(r"(src|href)=\"(https?:)?//", text), name
        assert "http://" not in text and "https://" not in text, name


def test_config_static_files_and_unknown_paths(serve):
    server = serve(ReplaySource(read_recorded_feed(FEED), load_airframe()))
    status, content_type, body = _get(server.url, "/config.json")
    config = json.loads(body)
    assert status == 200 and content_type == "application/json"
    assert config["mode"] == "replay" and config["airframe"]["thrust_max_n"] == 30.0
    assert len(config["airframe"]["nominal_hub_frd_m"]) == 4
    status, content_type, body = _get(server.url, "/")
    assert status == 200 and content_type.startswith("text/html") and b"dashboard.js" in body
    assert _get(server.url, "/dashboard.js")[0] == 200
    assert _get(server.url, "/../pyproject.toml")[0] == 404
    assert _get(server.url, "/latest.json")[0] == 404      # a replay has no "latest"


def test_a_replay_streams_every_sample_in_order_then_ends(serve):
    samples = read_recorded_feed(FEED)
    server = serve(ReplaySource(samples, load_airframe(), speed=50.0))
    events = read_events(server.url, lambda evs: evs and evs[-1].get("end"))
    assert events[-1] == {"end": True}
    assert [(e["topic"], e["payload"]["t_s"]) for e in events[:-1]] == [
        (k.rsplit("/", 1)[-1], p["t_s"]) for k, p in samples]
    states = [e for e in events if e.get("topic") == "state"]
    assert all(len(e["hub_frd_m"]) == 4 for e in states)


def test_a_replay_seeks_to_an_instant_and_refuses_a_bad_one(serve):
    """From 0.1 s before the end of a 5 s flight at half speed: the history at once, then 0.2 s paced."""
    samples = read_recorded_feed(FEED)
    server = serve(ReplaySource(samples, load_airframe(), speed=0.5))
    times = [p["t_s"] for _, p in samples if p.get("t_s") is not None]
    start = time.monotonic()
    events = read_events(server.url, lambda evs: evs and evs[-1].get("end"), timeout_s=5.0,
                         path=f"/events?from_s={times[-1] - 0.1}")
    assert events[-1] == {"end": True} and time.monotonic() - start < 5.0       # not the 10 s from the start
    assert [e["payload"]["t_s"] for e in events[:-1]] == [p["t_s"] for _, p in samples]   # a 20 s window: all of it
    assert _get(server.url, "/events?from_s=later")[0] == 400


def test_live_feed_reaches_the_page_with_the_posture(dashboard_process, publish_all, wait_until):
    feed, url = dashboard_process

    def every_topic_arrived() -> bool:
        publish_all(feed, 5.0)
        return json.loads(_get(url, "/latest.json")[2]).keys() >= set(TOPICS)

    assert wait_until(every_topic_arrived, timeout_s=10.0)
    events = read_events(url, lambda evs: len(evs) >= 5)
    latest = {e["topic"]: e for e in events}
    assert latest["fault"]["payload"]["message"] == "thrust loss rotor 4"
    assert latest["state"]["hub_frd_m"][0][0] == pytest.approx(0.15 + 0.22 * 0.8660254, abs=1e-4)  # hip 30 deg


@pytest.mark.parametrize("argv, message", [
    (["--replay", "no/such/feed.jsonl"], "no/such/feed.jsonl: cannot read the recorded feed"),
    (["--connect", "tcp/127.0.0.1:1"], "cannot open the Zenoh session"),
    (["--vehicle", "a/b"], "vehicle name must be"),
])
def test_bad_input_is_one_line_and_exit_2(argv, message, capsys):
    assert command.main(argv + ["--port", "0"]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1 and "Traceback" not in err


def test_a_port_in_use_is_one_line_and_exit_2(serve, capsys):
    server = serve(ReplaySource(read_recorded_feed(FEED), load_airframe()))
    port = server.server_address[1]
    assert command.main(["--replay", str(FEED), "--port", str(port)]) == 2
    assert f"cannot serve on 127.0.0.1:{port}" in capsys.readouterr().err
