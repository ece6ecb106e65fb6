"""How late our setpoints act at the flight controller, measured with TIMESYNC.

With a setpoint (at most every TIMESYNC_PERIOD_MS of the FC's clock, so that a lockstep
flight sends the same requests however fast the machine runs) goes a TIMESYNC request in the
same datagram, its ts1 the FC instant the setpoint answers (time_boot_ms, in ns). The FC answers
with tc1 = its own clock in ns since boot when it handled the request (ArduPilot and PX4 do
so, echoing ts1), which is when the setpoint reached it: tc1 - ts1 is the setpoint's lead,
the age of the answered telemetry instant when our answer acts (the telemetry's way down,
our step, the setpoint's way up, on the FC's clock; 0 in lockstep, where the FC waits for
us, unless the SITL emulates a delayed link: then 2 D). The round trip on our own clock is measured as well. Each is the median of the last
WINDOW samples (lost replies just leave fewer); a reply to a request we did not send is
ignored.
"""

from __future__ import annotations

import statistics
from collections import deque

TIMESYNC_PERIOD_MS = 100
WINDOW = 15
PENDING_MAX_MS = 5000            # a request unanswered this long on the FC's clock is forgotten
_NS_PER_MS = 1_000_000


class LinkDelay:
    def __init__(self):
        self._pending: dict[int, float] = {}            # ts1 (ns) -> our clock when sent
        self._leads_s: deque[float] = deque(maxlen=WINDOW)
        self._rtts_s: deque[float] = deque(maxlen=WINDOW)
        self._last_request_ms: int | None = None        # the FC instant of our last request
        self.samples = 0
        self.lead_s: float | None = None                # median lead of the last replies (None: none yet)

    def request_due(self, time_ms: int) -> bool:
        """Whether the setpoint answering FC instant time_ms should carry a request."""
        last = self._last_request_ms
        return last is None or not 0 <= time_ms - last < TIMESYNC_PERIOD_MS

    def requested(self, time_ms: int, now_s: float) -> int:
        """Note a request for the setpoint answering FC instant time_ms; its ts1 (ns)."""
        ts1 = int(time_ms) * _NS_PER_MS
        self._pending = {k: t for k, t in self._pending.items() if ts1 - k < PENDING_MAX_MS * _NS_PER_MS}
        self._pending[ts1] = now_s
        self._last_request_ms = int(time_ms)
        return ts1

    def answered(self, tc1_ns: int, ts1_ns: int, now_s: float) -> bool:
        """A TIMESYNC reply; True when it answered one of our requests."""
        sent_s = self._pending.pop(int(ts1_ns), None)
        if sent_s is None:
            return False
        self._leads_s.append(max(0.0, (int(tc1_ns) - int(ts1_ns)) / 1e9))
        self._rtts_s.append(now_s - sent_s)
        self.samples += 1
        self.lead_s = statistics.median(self._leads_s)      # read every step: kept, not recomputed
        return True

    def reset(self) -> None:
        """The FC rebooted: its clock, and the requests in flight, are of another boot."""
        self._pending.clear()
        self._leads_s.clear()
        self._rtts_s.clear()
        self.lead_s = None

    @property
    def round_trip_s(self) -> float | None:
        return statistics.median(self._rtts_s) if self._rtts_s else None
