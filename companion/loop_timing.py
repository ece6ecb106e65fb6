"""How well the control loop keeps its period: each answer's duration (telemetry read to
setpoint sent), the overruns (answers that took longer than the control period), and the rate
achieved (answers in the last second), the mean answer time, and the process's CPU time per step between the first
and the last answer (`cpu_ms_per_step`, time.process_time: what the loop costs, whatever else
runs on the machine), and the answer's quantiles (`answer_quantile_ms`: median, p99) from a
histogram of fixed size (ANSWER_BIN_S wide, up to ANSWER_RANGE_S; slower answers in its last
bin, said as the slowest), so a flight of any length keeps the same memory. `report(now_s)` gives an OverrunReport at most every REPORT_S
when something overran since the last one, so a slow computer is said (in the log, and to the
ground station as a STATUSTEXT warning), not flooded.
"""

from __future__ import annotations

import bisect
import time
from collections import deque
from dataclasses import dataclass

import numpy as np

REPORT_S = 5.0
RATE_WINDOW_S = 1.0
ANSWER_BIN_S = 1e-5              # the answer's histogram: 10 us bins
ANSWER_RANGE_S = 0.1             # up to 100 ms; slower answers in the last bin


@dataclass(frozen=True)
class OverrunReport:
    count: int                    # control steps over the period since the last report
    slowest_s: float              # the slowest of them
    total: int                    # overruns since the start
    period_s: float
    rate_hz: float                # control steps in the last second

    @property
    def text(self) -> str:
        """For the companion's log."""
        return (f"{self.count} control steps took longer than the {1e3 * self.period_s:.0f} ms period "
                f"(slowest {1e3 * self.slowest_s:.0f} ms; {self.total} in all); {self.rate_hz:.0f} Hz achieved")

    @property
    def statustext(self) -> str:
        """For the ground station: within a STATUSTEXT's 50 characters."""
        return f"companion: {self.count} overruns, {self.rate_hz:.0f} Hz, max {1e3 * self.slowest_s:.0f} ms"


class LoopTiming:
    def __init__(self, period_s: float):
        self.period_s = period_s
        self.overruns = 0
        self.slowest_s = 0.0
        self._answers: deque[float] = deque()           # when each answer went out (last RATE_WINDOW_S), in order
        self._since_report = 0
        self._slowest_since_report_s = 0.0
        self._last_report_s = -float("inf")
        self._cpu_first_s: float | None = None          # process CPU time at the first answer
        self._cpu_last_s = 0.0
        self._cpu_steps = 0                             # answers after the first
        self._answers_total = 0
        self._took_total_s = 0.0
        self._took_bins = np.zeros(round(ANSWER_RANGE_S / ANSWER_BIN_S), dtype=np.int64)

    def answered(self, started_s: float, now_s: float) -> None:
        """An answer to telemetry read at started_s went out at now_s."""
        cpu_s = time.process_time()
        if self._cpu_first_s is None:
            self._cpu_first_s = cpu_s
        else:
            self._cpu_last_s, self._cpu_steps = cpu_s, self._cpu_steps + 1
        took_s = now_s - started_s
        self._answers_total += 1
        self._took_total_s += took_s
        self._took_bins[min(max(int(took_s / ANSWER_BIN_S), 0), len(self._took_bins) - 1)] += 1
        self.slowest_s = max(self.slowest_s, took_s)
        if took_s > self.period_s:
            self.overruns += 1
            self._since_report += 1
            self._slowest_since_report_s = max(self._slowest_since_report_s, took_s)
        self._answers.append(now_s)
        while self._answers[0] <= now_s - RATE_WINDOW_S:
            self._answers.popleft()

    @property
    def mean_answer_ms(self) -> float | None:
        """Mean time from telemetry read to setpoint sent (None: no answer yet)."""
        return 1e3 * self._took_total_s / self._answers_total if self._answers_total else None

    def answer_quantile_ms(self, q: float) -> float | None:
        """The q-quantile (0 < q <= 1) of the time from telemetry read to setpoint sent, to a bin's
        width: the upper edge of the bin it falls in (the slowest answer when that is the last
        bin); None: no answer yet."""
        if not self._answers_total:
            return None
        i = int(np.searchsorted(np.cumsum(self._took_bins), q * self._answers_total))
        if i >= len(self._took_bins) - 1:
            return 1e3 * self.slowest_s
        return 1e3 * (i + 1) * ANSWER_BIN_S

    @property
    def cpu_ms_per_step(self) -> float | None:
        """The process's CPU time from the first answer to the last, per step (None: fewer than two)."""
        if self._cpu_steps == 0:
            return None
        return 1e3 * (self._cpu_last_s - self._cpu_first_s) / self._cpu_steps

    def rate_hz(self, now_s: float) -> float:
        """Answers per second over the last RATE_WINDOW_S."""
        return (len(self._answers) - bisect.bisect_right(self._answers, now_s - RATE_WINDOW_S)) / RATE_WINDOW_S

    def report(self, now_s: float) -> OverrunReport | None:
        """The overruns since the last report, if any and if that was REPORT_S ago."""
        if self._since_report == 0 or now_s - self._last_report_s < REPORT_S:
            return None
        report = OverrunReport(self._since_report, self._slowest_since_report_s, self.overruns, self.period_s,
                               self.rate_hz(now_s))
        self._since_report, self._slowest_since_report_s, self._last_report_s = 0, 0.0, now_s
        return report
