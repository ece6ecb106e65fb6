"""The feed the control loop calls: one method per topic, never blocking, never raising.

    feed = open_feed(settings)              # a disabled feed when settings.enabled is false
    feed.state(t_s, pos_ned_m=..., ...)     # keyword arguments of payloads.state_payload
    feed.fault(t_s, state="confirmed", rotor=4, thrust_max_estimate_n=..., message=text)
    feed.close()

The feed never decides whether the robot flies: when its Zenoh side cannot be set up (client
mode with no router reachable, a Zenoh config file missing or broken) that is said in one
line and tried again every RETRY_S on a thread of its own; until it opens, every call returns
at once and nothing is published.

Each topic is published at most as often as a viewer needs it (TOPIC_RATE_HZ: the state and
the setpoint 20 times a second, the NMPC 10, the fault and the link's health 2; wall clock),
and never more than `max_rate_hz` (0: every call, every topic, as `m4-sitl fly` records
them); a call in between returns at once without building anything, and `wants(topic)`
lets the caller skip gathering a payload's fields too. The fault topic also goes out at
once whenever its state or rotor changes. A payload that cannot be built or sent is counted
(`errors`, reported in the link topic as feed_errors) and logged once per kind, never
raised: the feed must not stop the control loop.
"""

from __future__ import annotations

import logging
import threading
import time
from typing import Any, Callable, Protocol

from m4.feed import payloads
from m4.feed.settings import FeedSettings
from m4.feed.transport import FeedError, ZenohSink, describe
from m4.toml_fields import ConfigError

log = logging.getLogger(__name__)

RETRY_S = 5.0                   # a feed that could not be set up is tried again this often
# What a viewer (m4-companion watch, the dashboard's 20 s plots) needs of each topic, at most.
TOPIC_RATE_HZ = {"state": 20.0, "setpoint": 20.0, "nmpc": 10.0, "fault": 2.0, "link": 2.0}


class Sink(Protocol):
    def put(self, topic: str, payload: dict[str, Any]) -> None: ...
    def close(self) -> None: ...


class Feed:
    def __init__(self, sink: Sink | None, *, max_rate_hz: float = 0.0,
                 clock: Callable[[], float] = time.monotonic,
                 wall_clock: Callable[[], float] = time.time):
        self._sink = sink
        self._min_interval_s = {topic: 1.0 / min(rate_hz, max_rate_hz) if max_rate_hz > 0 else 0.0
                                for topic, rate_hz in TOPIC_RATE_HZ.items()}
        self._clock = clock
        self._wall_clock = wall_clock
        self._last_sent_s: dict[str, float] = {}
        self._last_fault: tuple[Any, Any] | None = None
        self._logged_kinds: set[str] = set()
        self._closed = threading.Event()
        self._sink_lock = threading.Lock()            # the connecting thread's sink against close()
        self._connecting = False
        self.published = 0
        self.errors = 0

    @classmethod
    def disabled(cls) -> "Feed":
        """A feed that accepts every call and does nothing."""
        return cls(None)

    @property
    def enabled(self) -> bool:
        """Publishing, or trying to set up its sink."""
        return not self._closed.is_set() and (self._sink is not None or self._connecting)

    @property
    def up(self) -> bool:
        """Its sink is open: calls publish."""
        return self._sink is not None

    def connect(self, open_sink: Callable[[], Sink], what: str, retry_s: float = RETRY_S) -> "Feed":
        """Open the sink now or, when that raises FeedError, say so once and try again every
        retry_s on a thread of its own until it opens or the feed is closed."""
        try:
            self._sink = open_sink()
            return self
        except FeedError as e:
            log.warning("feed down: %s; the companion flies without it and tries again every %g s", e, retry_s)
        self._connecting = True
        threading.Thread(target=self._keep_trying, args=(open_sink, what, retry_s), name="feed-connect",
                         daemon=True).start()
        return self

    def _keep_trying(self, open_sink: Callable[[], Sink], what: str, retry_s: float) -> None:
        while not self._closed.wait(retry_s):
            try:
                sink = open_sink()
            except FeedError:
                continue
            with self._sink_lock:
                if not self._closed.is_set():
                    self._sink, sink = sink, None
            if sink is not None:                      # closed meanwhile
                self._guarded("close", sink.close)
            else:
                log.info("feed up: publishing (%s)", what)
            return

    def wants(self, topic: str) -> bool:
        """A call for `topic` now would publish (its sink is up and its interval has passed);
        the fault topic's changes go out whatever this says."""
        return self._sink is not None and self._due(topic, self._clock())

    def _due(self, topic: str, now_s: float) -> bool:
        last_s = self._last_sent_s.get(topic)
        return last_s is None or now_s - last_s >= self._min_interval_s[topic]

    def state(self, t_s: float | None, **fields) -> None:
        self._publish("state", payloads.state_payload, t_s, fields)

    def setpoint(self, t_s: float | None, **fields) -> None:
        self._publish("setpoint", payloads.setpoint_payload, t_s, fields)

    def nmpc(self, t_s: float | None, **fields) -> None:
        self._publish("nmpc", payloads.nmpc_payload, t_s, fields)

    def fault(self, t_s: float | None, **fields) -> None:
        change = (fields.get("state"), fields.get("rotor"))
        if self._publish("fault", payloads.fault_payload, t_s, fields, urgent=change != self._last_fault):
            self._last_fault = change

    def link(self, t_s: float | None, **fields) -> None:
        self._publish("link", payloads.link_payload, t_s, {**fields, "feed_errors": self.errors})

    def close(self) -> None:
        with self._sink_lock:
            self._closed.set()
            sink, self._sink = self._sink, None
        if sink is not None:
            self._guarded("close", sink.close)

    def __enter__(self) -> "Feed":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _publish(self, topic: str, build: Callable[..., dict], t_s: float | None,
                 fields: dict[str, Any], urgent: bool = False) -> bool:
        """True when the payload went out."""
        sink, now_s = self._sink, self._clock()
        if sink is None or not (urgent or self._due(topic, now_s)):
            return False
        if not self._guarded(topic, lambda: sink.put(topic, build(t_s, self._wall_clock(), **fields))):
            return False
        self._last_sent_s[topic] = now_s
        self.published += 1
        return True

    def _guarded(self, kind: str, action: Callable[[], None]) -> bool:
        try:
            action()
            return True
        except Exception as e:  # the feed must never raise into the control loop
            self.errors += 1
            if kind not in self._logged_kinds:
                self._logged_kinds.add(kind)
                log.warning("feed %s failed (counted, further %s failures not logged): %s: %s",
                            kind, kind, type(e).__name__, e)
            return False


def open_feed(settings: FeedSettings, retry_s: float = RETRY_S) -> Feed:
    """A feed on Zenoh, live or trying to be (Feed.connect), or a disabled one; a bad setting
    raises ConfigError now."""
    if not settings.enabled:
        return Feed.disabled()
    try:
        settings.validate()
    except ConfigError as e:
        raise ConfigError(f"feed: {e}") from None
    feed = Feed(None, max_rate_hz=settings.max_rate_hz)
    return feed.connect(lambda: ZenohSink.open(settings), describe(settings), retry_s)
