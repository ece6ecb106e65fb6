import json
import re
import threading

import pytest

from companion import watch
from companion.feed_publisher import open_feed
from m4.feed.payloads import TOPICS
from m4.feed.settings import FeedSettings
from m4.feed import payloads


@pytest.fixture
def publishing_feed(endpoint, publish_all):
    """A feed listening on loopback that publishes every topic every 20 ms."""
    feed = open_feed(FeedSettings(vehicle="test", listen=(endpoint,), max_rate_hz=0.0))
    stop = threading.Event()

    def loop():
        while not stop.wait(0.02):
            publish_all(feed)

    thread = threading.Thread(target=loop, daemon=True)
    thread.start()
    yield endpoint
    stop.set()
    thread.join()
    feed.close()


def test_once_shows_the_fault_banner_and_every_topic(publishing_feed, capsys):
    code = watch.main(["--connect", publishing_feed, "--vehicle", "test", "--once", "--timeout", "10"])
    out = capsys.readouterr().out
    assert code == 0
    assert "FAULT CONFIRMED: thrust loss rotor 4" in out
    assert "(waiting)" not in out
    assert "\x1b[" not in out                               # --once is plain text
    assert "solve   3.2 ms" in out and "connected" in out


def test_once_without_a_feed_times_out_and_says_which_topics_are_missing(endpoint, capsys):
    listener = open_feed(FeedSettings(vehicle="other", listen=(endpoint,)))   # something to connect to
    try:
        code = watch.main(["--connect", endpoint, "--once", "--timeout", "0.2"])
    finally:
        listener.close()
    captured = capsys.readouterr()
    assert code == 1
    assert captured.out.count("(waiting)") == len(TOPICS)
    assert "no state, setpoint, fault, nmpc, link" in captured.err


def test_unreachable_endpoint_exits_2_with_a_message(capsys):
    assert watch.main(["--connect", "tcp/127.0.0.1:1", "--once"]) == 2
    assert "cannot open the Zenoh session" in capsys.readouterr().err


def _payloads(topic_fields):
    built = {t: getattr(payloads, f"{t}_payload")(5.0, 0.0, **topic_fields[t])
             for t in ("state", "setpoint", "fault", "nmpc")}
    built["link"] = payloads.link_payload(5.0, 0.0, feed_errors=0, **topic_fields["link"])
    return built


def test_render_shows_attitude_in_degrees_and_unknown_thrust_as_a_dash(topic_fields):
    lines = watch.render("test", _payloads(topic_fields), {})
    text = "\n".join(lines)
    assert "pitch  +10.0" in text and "yaw  +180.0" in text
    thrust_line = next(line for line in lines if line.startswith("thrust N"))
    assert thrust_line.split("hip deg")[0].split()[-1] == "-"   # rotor 4 thrust unknown (NaN)


def test_render_colours_the_fault_banner_only_when_asked(topic_fields):
    built = _payloads(topic_fields)
    assert "\x1b[" not in "".join(watch.render("test", built, {}))
    banner = watch.render("test", built, {}, colour=True)[1]
    assert banner.startswith("\x1b[") and banner.endswith("\x1b[0m") and "thrust loss rotor 4" in banner


def test_render_cuts_lines_to_the_terminal_width_and_still_resets_the_colour(topic_fields):
    lines = watch.render("test", _payloads(topic_fields), {}, colour=True, width=40)
    assert all(len(line) <= 40 for i, line in enumerate(lines) if i != 1)
    assert lines[1].endswith("\x1b[0m") and len(re.sub(r"\x1b\[[0-9;]*m", "", lines[1])) == 40


def test_render_flags_topics_that_stopped_arriving(topic_fields):
    lines = watch.render("test", _payloads(topic_fields), {"state": 0.1, "link": 7.5})
    assert lines[-1] == "stale: link 7.5 s"


def test_unreadable_samples_are_counted_not_fatal():
    latest = watch.Latest()
    latest.take("m4/test/state", b"not json", 0.0)
    latest.take("m4/test/unknown", json.dumps({"t_s": 1.0}).encode(), 0.0)
    latest.take("m4/test/link", json.dumps({"t_s": 1.0, "connected": False}).encode(), 0.0)
    snapshot, _, bad = latest.snapshot()
    assert bad == 2 and set(snapshot) == {"link"}
    assert "LOST" in "\n".join(watch.render("test", snapshot, {}, bad))
