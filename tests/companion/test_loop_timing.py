"""The control loop's own timing: overruns counted, the achieved rate, and a report that does
not flood the log; and through the app on real loopback sockets with a slow control step."""

from __future__ import annotations

import logging
import time

import pytest

from companion.app import CompanionApp
from companion.config import parse_config
from companion.controller import Controller, ControllerSettings
from companion.fc_link import FcLink
from companion.loop_timing import REPORT_S, LoopTiming
from m4.airframe import load_airframe
from m4.mavlink import COMPANION_COMPONENT_ID, FC_SYSTEM_ID
from m4.mavlink.link import UdpLink
from support.loopback_fc import LoopbackFc

AF = load_airframe()


def test_overruns_are_counted_and_reported_at_most_every_few_seconds():
    timing = LoopTiming(0.02)
    for k in range(100):                       # 100 answers in 2 s, every other one 30 ms long
        start = 0.02 * k
        timing.answered(start, start + (0.03 if k % 2 else 0.005))
    assert timing.overruns == 50 and timing.slowest_s == pytest.approx(0.03)
    assert timing.rate_hz(2.0) == pytest.approx(50.0, abs=1.0)
    first = timing.report(2.0)
    assert first.text.startswith("50 control steps took longer than the 20 ms period (slowest 30 ms")
    assert first.text.endswith(f"{timing.rate_hz(2.0):.0f} Hz achieved")
    assert first.statustext == f"companion: 50 overruns, {timing.rate_hz(2.0):.0f} Hz, max 30 ms"
    timing.answered(2.0, 2.05)
    assert timing.report(2.05) is None                          # within REPORT_S of the last one
    assert "1 control steps" in timing.report(2.0 + REPORT_S).text
    assert timing.report(4.0 + REPORT_S) is None                # nothing overran since


def test_the_mean_answer_time_and_the_cpu_time_per_step_between_the_first_and_last_answer():
    timing = LoopTiming(0.02)
    assert timing.mean_answer_ms is None and timing.cpu_ms_per_step is None
    timing.answered(0.0, 0.002)
    assert timing.cpu_ms_per_step is None                       # one answer: no step between two yet
    busy_until = time.process_time() + 0.05
    while time.process_time() < busy_until:                    # 50 ms of this process's CPU
        pass
    timing.answered(0.02, 0.026)
    assert timing.mean_answer_ms == pytest.approx(4.0)
    assert timing.cpu_ms_per_step >= 50.0


def test_a_slow_control_step_over_real_sockets_is_counted_logged_once_and_published(caplog):
    config = parse_config({"control": {"rate_hz": 50.0}, "link": {"fc_url": "udpin:127.0.0.1:0"}}, "test")
    controller = Controller(ControllerSettings.of(config))
    real_step = controller.step
    controller.step = lambda *a, **k: (time.sleep(0.03), real_step(*a, **k))[1]     # 30 ms: over the 20 ms period
    link = UdpLink("udpin:127.0.0.1:0", FC_SYSTEM_ID, COMPANION_COMPONENT_ID)
    fc = LoopbackFc(link.local_port, AF)
    app = CompanionApp(config, FcLink(link), controller)
    try:
        fc.join(app)
        with caplog.at_level(logging.WARNING, logger="m4-companion"):
            for k in range(10):
                fc.frame(20 * k)
                time.sleep(0.01)
                app.poll()
        setpoints = [m for m in fc.received() if m.get_type() == "M4_SETPOINT"]
        assert len(setpoints) == 10 and app.timing.overruns == 10
        reports = [r.message for r in caplog.records if "took longer than the 20 ms period" in r.message]
        assert len(reports) == 1
    finally:
        fc.close()
        link.close()


def test_the_answers_median_and_p99_to_a_bin_and_the_slowest_beyond_the_histogram():
    timing = LoopTiming(0.02)
    assert timing.answer_quantile_ms(0.5) is None
    for k in range(100):                       # 1.00, 1.01, ..., 1.99 ms
        timing.answered(float(k), k + 1e-3 + k * 1e-5 + 1e-7)
    assert timing.answer_quantile_ms(0.5) == pytest.approx(1.50, abs=0.011)
    assert timing.answer_quantile_ms(0.99) == pytest.approx(1.99, abs=0.011)
    timing.answered(200.0, 200.5)              # 500 ms: beyond the histogram
    timing.answered(201.0, 201.3)
    assert timing.answer_quantile_ms(1.0) == pytest.approx(500.0)
    assert timing.answer_quantile_ms(0.5) == pytest.approx(1.51, abs=0.011)
