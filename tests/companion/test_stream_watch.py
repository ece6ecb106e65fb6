"""What the companion does about stale streams: ask again, resume, report without flooding."""

from __future__ import annotations

from companion.stream_watch import STALE_REPORT_MIN_S, StreamWatch, blocking
from companion.telemetry import ATTITUDE, ATTITUDE_QUATERNION, ESC_TELEMETRY, LOCAL_POSITION


def test_a_stale_attitude_is_asked_for_by_both_messages_again_each_second_until_it_comes():
    watch = StreamWatch(0.02)
    assert watch.update((ATTITUDE,), 10.0, 3000).ask == (ATTITUDE, ATTITUDE_QUATERNION)
    assert watch.update((ATTITUDE,), 10.5, 3500).ask == ()
    assert watch.update((ATTITUDE, LOCAL_POSITION), 11.0, 4000).ask == (ATTITUDE, ATTITUDE_QUATERNION, LOCAL_POSITION)
    news = watch.update((), 11.1, 4100)
    assert news.resumed and news.ask == ()


def test_a_flapping_stream_is_reported_at_most_once_a_second_and_the_last_state_is_always_said():
    watch = StreamWatch(0.02)
    reports = []
    for k in range(99):                              # stale and fresh by turns every 20 ms for 2 s, stale last
        news = watch.update((LOCAL_POSITION,) if k % 2 == 0 else (), 10.0 + 0.02 * k, 20 * k)
        if news.report is not None:
            reports.append((round(0.02 * k, 2), news.report.now))
    assert reports == [(0.0, (LOCAL_POSITION,)), (1.02, ())]
    late = watch.update((LOCAL_POSITION,), 10.0 + 1.02 + STALE_REPORT_MIN_S, 2020).report
    assert late.now == (LOCAL_POSITION,) and late.since_ms == 1960


def test_stale_esc_telemetry_does_not_stop_the_setpoints():
    assert not blocking((ESC_TELEMETRY,)) and blocking((ESC_TELEMETRY, ATTITUDE))
