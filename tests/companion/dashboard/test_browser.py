"""The dashboard in a real headless Chromium: what a person sees, checked on the screenshot.

`M4_WRITE_FIGURES=1 python -m pytest tests/companion/dashboard/test_browser.py` also writes
the replay's screenshot to docs/figures/dashboard.png (the README's picture).
"""

import math
import os
import threading
import time
from pathlib import Path

import numpy as np

from companion.dashboard.events import ReplaySource, read_recorded_feed
from m4.airframe import load_airframe

from .conftest import FEED

FIGURE = Path(__file__).resolve().parents[3] / "docs" / "figures" / "dashboard.png"
FAULT_RED = (0xD3, 0x2F, 0x2F)
PANEL = (0x0B, 0x10, 0x15)            # the canvases' background


def _share(image, rect, colour, tolerance: int = 12) -> float:
    """Fraction of the pixels in rect (left, top, right, bottom) within tolerance of colour."""
    pixels = np.asarray(image.crop(rect), dtype=int)
    return float(np.mean(np.all(np.abs(pixels - colour) <= tolerance, axis=-1)))


def test_a_replayed_flight_shows_the_fault_the_posture_and_every_plot(chromium, serve, tmp_path):
    samples = read_recorded_feed(FEED)
    server = serve(ReplaySource(samples, load_airframe(), speed=10.0))
    chromium.open(server.url)
    chromium.wait_for("window.m4dash && window.m4dash.ended && window.m4dash.drawn > 0")
    png, image = chromium.screenshot()
    (tmp_path / "dashboard.png").write_bytes(png)
    if os.environ.get("M4_WRITE_FIGURES"):
        FIGURE.write_bytes(png)

    assert chromium.evaluate("window.m4dash.events") == len(samples)
    assert chromium.evaluate("document.body.dataset.status") == "ended"
    assert chromium.evaluate("document.getElementById('banner').className") == "confirmed"
    banner_text = chromium.evaluate("document.getElementById('banner').textContent")
    assert "FAULT: thrust loss rotor 4 (rear-right, motor), detected at t = 1.04 s" in banner_text
    hips = [float(v) for v in chromium.evaluate("document.getElementById('r-hip').textContent").split()]
    assert hips[0] > 80 and hips[1] < 10                   # the legs swung: rotor 1 out, rotor 2 folded
    assert chromium.evaluate("document.querySelectorAll('#plots canvas').length") == 9
    # the companion's disturbance estimate (the nmpc topic's disturbance_force_ned_n), every axis drawn
    assert chromium.evaluate("Math.min(...plots.disturbance.series.map((s) => s.data.length))") > 50

    assert _share(image, chromium.rect("#banner"), FAULT_RED) > 0.6
    view = chromium.rect("#view3d")
    assert 1 - _share(image, view, PANEL, tolerance=3) > 0.05    # the robot, its legs and the ground are drawn
    assert _share(image, view, FAULT_RED, tolerance=40) < 0.05   # the dead rotor is red, not the whole view
    for k in range(9):
        plot = chromium.rect(f"#plots canvas:nth-child({k + 1})")
        assert 1 - _share(image, plot, PANEL, tolerance=3) > 0.03, k   # axes, lines, labels


def test_the_banner_turns_red_when_a_live_fault_is_published(chromium, dashboard_process, topic_fields):
    feed, url = dashboard_process
    fault = {"state": "healthy", "rotor": None, "thrust_max_estimate_n": np.full(4, 30.0), "message": ""}
    stop = threading.Event()

    def publish():
        t_s = 0.0
        while not stop.wait(0.05):
            t_s += 0.05
            feed.state(t_s, **{**topic_fields["state"], "euler_rad": np.array([0.1, 0.0, math.sin(t_s)])})
            feed.fault(t_s, **fault)

    publisher = threading.Thread(target=publish, daemon=True)
    publisher.start()
    try:
        chromium.open(url)
        chromium.wait_for("document.getElementById('banner').className === 'healthy' && window.m4dash.drawn > 0")
        _, before = chromium.screenshot()
        fault.update(state="confirmed", rotor=2, thrust_max_estimate_n=np.array([30.0, 1.5, 30.0, 30.0]),
                     message="thrust loss rotor 2", detected_at_s=3.0)
        chromium.wait_for("document.getElementById('banner').className === 'confirmed'")
        _, after = chromium.screenshot()
        assert chromium.evaluate("document.body.dataset.status") == "live"
    finally:
        stop.set()
        publisher.join()
    banner = chromium.rect("#banner")
    assert _share(before, banner, FAULT_RED) < 0.01
    assert _share(after, banner, FAULT_RED) > 0.6
    assert "FAULT: thrust loss rotor 2 (rear-left), detected" in chromium.evaluate("document.getElementById('banner').textContent")
    assert 1 - _share(after, chromium.rect("#view3d"), PANEL, tolerance=3) > 0.05


def test_a_replay_is_paced_by_the_flight_clock_not_dumped(chromium, serve):
    samples = read_recorded_feed(FEED)[:200]            # the first 1.6 s of flight
    source = ReplaySource(samples, load_airframe(), speed=1.0)
    server = serve(source)
    started_s = time.monotonic()                       # the replay starts when the page connects, after this
    chromium.open(server.url)
    chromium.wait_for("window.m4dash.ended")
    assert time.monotonic() - started_s >= source.duration_s
    assert chromium.evaluate("window.m4dash.events") == len(samples)


def test_a_replay_pauses_and_seeks(chromium, serve):
    samples = read_recorded_feed(FEED)
    server = serve(ReplaySource(samples, load_airframe(), speed=1.0))
    chromium.open(server.url)
    chromium.wait_for("window.m4dash && window.m4dash.t > 0.5")
    chromium.evaluate("document.getElementById('pause').click()")
    assert chromium.evaluate("document.body.dataset.status") == "paused"
    paused_at = chromium.evaluate("window.m4dash.t")
    time.sleep(1.0)
    assert chromium.evaluate("window.m4dash.t") == paused_at                     # nothing moves while paused
    chromium.evaluate("window.m4dash.seek(4.0)")                                 # the slider's change
    chromium.wait_for("window.m4dash.t >= 4.0")
    time.sleep(0.5)
    assert 4.0 <= chromium.evaluate("window.m4dash.t") < 4.1                     # there, and still paused
    assert "FAULT" in chromium.evaluate("document.getElementById('banner').textContent")   # the fault before it
    chromium.evaluate("document.getElementById('pause').click()")
    chromium.wait_for("window.m4dash.ended")
    assert chromium.evaluate("document.body.dataset.status") == "ended"
