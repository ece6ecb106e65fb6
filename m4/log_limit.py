"""Repeated identical log lines, rate-limited: the first is said, the repeats are counted.

A hostile or broken peer (a wrong signing key, a flood of garbage) can make the same error
happen thousands of times a second; a log must stay readable and small. `RepeatLimiter`
lets a key through at most once per `interval_s` and reports how many were held back since;
`RepeatFilter` does the same for a `logging` logger (keyed by the unformatted message, so
"sig mismatch %s" with changing arguments is one key).
"""

from __future__ import annotations

import logging
import time
from collections import OrderedDict
from collections.abc import Callable, Hashable

DEFAULT_INTERVAL_S = 10.0
MAX_KEYS = 256                 # keys remembered; the oldest is forgotten first


class RepeatLimiter:
    def __init__(self, interval_s: float = DEFAULT_INTERVAL_S, clock: Callable[[], float] = time.monotonic):
        self.interval_s = interval_s
        self.clock = clock
        self._keys: OrderedDict[Hashable, list] = OrderedDict()     # key -> [last said at, held back since]

    def admit(self, key: Hashable) -> int | None:
        """None: hold this one back. Else it may be said, and the int is how many were held back."""
        now = self.clock()
        entry = self._keys.get(key)
        if entry is not None and now - entry[0] < self.interval_s:
            entry[1] += 1
            return None
        held = 0 if entry is None else entry[1]
        self._keys[key] = [now, 0]
        self._keys.move_to_end(key)
        while len(self._keys) > MAX_KEYS:
            self._keys.popitem(last=False)
        return held

    def say(self, key: Hashable, text: str, emit: Callable[[str], None]) -> None:
        """`emit(text)` unless held back; with the count of held-back repeats when there were some."""
        held = self.admit(key)
        if held is not None:
            emit(text if held == 0 else f"{text} (and {held} more like it in the last {self.interval_s:g} s)")


class RepeatFilter(logging.Filter):
    def __init__(self, interval_s: float = DEFAULT_INTERVAL_S):
        super().__init__()
        self.limiter = RepeatLimiter(interval_s)

    def filter(self, record: logging.LogRecord) -> bool:
        held = self.limiter.admit((record.name, record.levelno, str(record.msg)))
        if held is None:
            return False
        if held:
            record.msg = f"{record.getMessage()} (and {held} more like it in the last {self.limiter.interval_s:g} s)"
            record.args = None
        return True
