"""Which telemetry streams the controller needs have gone stale, and what to do about it.

A stream that brought nothing for STREAM_STALE_PERIODS control periods while the others came
(companion.telemetry: on the FC's clock and on ours) is stale: 0.1 s at 50 Hz. A frame lost
on the link loses all its streams at once and ages none; one stream starved alone for five
periods is not a link's loss: something stopped it (a MAV_CMD_SET_MESSAGE_INTERVAL from a
third party, a flood). While the attitude, position, joints or thrusters are stale no
setpoint goes out (`blocking`): the FC flies our last setpoint, then its own failsafe, rather
than the controller flying blind. Stale ESC telemetry is not blocking: the detector works
without ESC evidence, and the controller is handed none.

Each poll `update()` says what to do: the stale streams' messages to ask for again
(MAV_CMD_SET_MESSAGE_INTERVAL; again every STALE_REREQUEST_S while stale; a stale attitude both
ATTITUDE and ATTITUDE_QUATERNION, though the companion asks for the first alone while it is
fresh: an FC that sends only the quaternion is heard again), whether control
resumes (the last blocking stream is fresh), and what to report: each change, at most every
STALE_REPORT_MIN_S; a change within that is reported once that has passed, if it still holds,
so the last state is always said. Pure logic.
"""

from __future__ import annotations

from dataclasses import dataclass

from companion.telemetry import ATTITUDE, ATTITUDE_QUATERNION, ESC_TELEMETRY, LABELS

STREAM_STALE_PERIODS = 5
STALE_REREQUEST_S = 1.0           # a stale stream is asked for again this often
STALE_REPORT_MIN_S = 1.0          # a change is reported at most this often


def blocking(stale: tuple[int, ...]) -> bool:
    """A stale stream the controller cannot fly without (all but the ESC telemetry)."""
    return any(i != ESC_TELEMETRY for i in stale)


def labels(stale: tuple[int, ...]) -> tuple[str, ...]:
    return tuple(LABELS[i] for i in stale)


@dataclass(frozen=True)
class Report:
    was: tuple[int, ...]          # stale as last reported
    now: tuple[int, ...]          # stale now
    since_ms: int                 # the FC's clock when it became so


@dataclass(frozen=True)
class StreamNews:
    ask: tuple[int, ...] = ()     # messages to ask for again
    resumed: bool = False         # the last blocking stream is fresh again
    report: Report | None = None


_QUIET = StreamNews()


class StreamWatch:
    def __init__(self, period_s: float):
        self.limit_s = STREAM_STALE_PERIODS * period_s
        self.stale: tuple[int, ...] = ()
        self._since_ms = 0
        self._reported: tuple[int, ...] = ()
        self._report_s = 0.0               # when a change may be reported again
        self._ask_s = 0.0                  # when stale streams may be asked for again

    def update(self, stale: tuple[int, ...], now_s: float, fc_time_ms: int) -> StreamNews:
        if not stale and not self.stale and not self._reported:
            return _QUIET                  # every poll in a healthy flight
        ask = ()
        if stale and now_s >= self._ask_s:
            ask = tuple(j for i in stale for j in ((ATTITUDE, ATTITUDE_QUATERNION) if i == ATTITUDE else (i,)))
            self._ask_s = now_s + STALE_REREQUEST_S
        resumed = blocking(self.stale) and not blocking(stale)
        if stale != self.stale:
            self.stale, self._since_ms = stale, fc_time_ms
        report = None
        if stale != self._reported and now_s >= self._report_s:
            report = Report(self._reported, stale, self._since_ms)
            self._reported, self._report_s = stale, now_s + STALE_REPORT_MIN_S
        return StreamNews(ask, resumed, report)
