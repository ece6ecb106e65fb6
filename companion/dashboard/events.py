"""The feed's samples as the dashboard's events, live (fanned out to every page) or replayed.

An event is {"topic": ..., "payload": {...}} with the payload as the feed published it; a
state event also carries "hub_frd_m", the four thruster hubs in the body frame computed
from the measured hips by the airframe (m4.airframe), so the page draws the posture
without a second copy of the leg geometry. A source gives each page an iterator of events;
None in it means "nothing new for a while" (the server sends a keep-alive then).

- LiveSource: a Hub that the Zenoh subscriber publishes into; a page that connects gets
  the newest event of each topic first, then everything that follows.
- ReplaySource: a recorded feed (feed.jsonl, as `m4-sitl fly` writes it), paced by the
  payloads' t_s at `speed` times real time; every page watches it from the start, or from
  the instant it seeks to (`from_s`: the newest event of each topic and the HISTORY_S before
  it come at once, so the plots have their window; then the flight paced from there).
"""

from __future__ import annotations

import json
import math
import queue
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from m4.airframe import Airframe
from m4.feed.payloads import TOPICS

KEEPALIVE_S = 1.0
HISTORY_S = 20.0               # a seek sends this much flight before its instant at once (the page's plot window)
QUEUE_EVENTS = 2000            # per page: about 8 s of every topic at 50 Hz; the oldest go first


class ReplayError(ValueError):
    """A recorded feed that cannot be replayed (the message says which file and why)."""


def strict_json(text: str | bytes) -> Any:
    """json.loads that refuses NaN and Infinity (a browser's JSON.parse would refuse the event)."""
    return json.loads(text, parse_constant=_refuse_constant)


def _refuse_constant(name: str) -> Any:
    raise ValueError(f"{name} is not JSON")


def dashboard_event(key: str, payload: Any, af: Airframe) -> dict[str, Any] | None:
    """The event of one feed sample; None for a key outside the feed's topics or a payload
    that is not a JSON object."""
    topic = key.rsplit("/", 1)[-1]
    if topic not in TOPICS or not isinstance(payload, dict):
        return None
    event: dict[str, Any] = {"topic": topic, "payload": payload}
    if topic == "state":
        event["hub_frd_m"] = hub_positions(af, payload.get("hip_deg"))
    return event


def hub_positions(af: Airframe, hip_deg: Any) -> list[list[float]] | None:
    """The thruster hubs (4 x 3, body FRD, m) for the hips in degrees; None if any is unknown."""
    if not isinstance(hip_deg, list) or len(hip_deg) != len(af.hip_frd_m) or not all(
            isinstance(q, (int, float)) and not isinstance(q, bool) and math.isfinite(q) for q in hip_deg):
        return None
    hubs = af.thruster_positions_frd_m([math.radians(q) for q in hip_deg])
    return [[round(float(v), 5) for v in hub] for hub in hubs]


def airframe_view(af: Airframe) -> dict[str, Any]:
    """What the page needs of the airframe to draw it."""
    return {
        "name": af.name,
        "body_box_size_m": list(af.body_box_size_m),
        "hip_frd_m": [list(h) for h in af.hip_frd_m],
        "wheel_radius_m": af.wheel_radius_m,
        "rotor_names": list(af.rotor_names),
        "thrust_max_n": af.thrust_max_n,
        "hover_thrust_per_rotor_n": af.hover_thrust_per_rotor_n,
        "hip_min_deg": math.degrees(af.hip_min_rad),
        "hip_max_deg": math.degrees(af.hip_max_rad),
        "nominal_hip_rad": af.nominal_hip_rad,
        "nominal_hub_frd_m": hub_positions(af, [math.degrees(af.nominal_hip_rad)] * len(af.hip_frd_m)),
    }


class Hub:
    """Fans live events out to every connected page; keeps the newest of each topic."""

    def __init__(self, af: Airframe, max_events: int = QUEUE_EVENTS):
        self._af = af
        self._max_events = max_events
        self._lock = threading.Lock()
        self._latest: dict[str, dict[str, Any]] = {}
        self._pages: list[queue.Queue] = []
        self.bad_samples = 0

    def take(self, key: str, data: bytes) -> None:
        """One sample as Zenoh delivered it (key expression, JSON bytes)."""
        try:
            payload = strict_json(data)
        except ValueError:
            payload = None
        event = dashboard_event(key, payload, self._af)
        with self._lock:
            if event is None:
                self.bad_samples += 1
                return
            self._latest[event["topic"]] = event
            for page in self._pages:
                _put_dropping_oldest(page, event)

    def latest(self) -> dict[str, dict[str, Any]]:
        with self._lock:
            return dict(self._latest)

    def events(self, stop: threading.Event) -> Iterator[dict[str, Any] | None]:
        page: queue.Queue = queue.Queue(self._max_events)
        with self._lock:
            for event in self._latest.values():
                page.put_nowait(event)
            self._pages.append(page)
        try:
            while not stop.is_set():
                try:
                    yield page.get(timeout=KEEPALIVE_S)
                except queue.Empty:
                    yield None
        finally:
            with self._lock:
                self._pages.remove(page)


def _put_dropping_oldest(page: queue.Queue, event: dict[str, Any]) -> None:
    while True:
        try:
            page.put_nowait(event)
            return
        except queue.Full:
            try:
                page.get_nowait()
            except queue.Empty:
                pass


def read_recorded_feed(path: str | Path) -> list[tuple[str, dict[str, Any]]]:
    """(key, payload) of every line of a recorded feed ({"key": ..., "payload": {...}} a line),
    in order; lines that are not such an object (a line cut short) are skipped."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as e:
        raise ReplayError(f"{path}: cannot read the recorded feed: {e.strerror}") from None
    except UnicodeDecodeError as e:
        raise ReplayError(f"{path}: not a recorded feed (feed.jsonl) nor a .tlog: not UTF-8 text (byte "
                          f"{e.object[e.start]:#04x} at offset {e.start})") from None
    samples = []
    for line in text.splitlines():
        try:
            entry = strict_json(line)
        except ValueError:
            continue
        if isinstance(entry, dict) and isinstance(entry.get("key"), str) and isinstance(entry.get("payload"), dict):
            samples.append((entry["key"], entry["payload"]))
    if not samples:
        raise ReplayError(f"{path}: no feed samples in it (expected one {{\"key\": ..., \"payload\": {{...}}}} a line)")
    return samples


class ReplaySource:
    """A recorded feed replayed to each page from its start, at `speed` times real time."""

    def __init__(self, samples: list[tuple[str, dict[str, Any]]], af: Airframe, speed: float = 1.0):
        if not speed > 0 or math.isinf(speed):
            raise ReplayError(f"replay speed must be a finite number > 0, got {speed!r}")
        self._events = [e for e in (dashboard_event(k, p, af) for k, p in samples) if e is not None]
        if not self._events:
            raise ReplayError("the recorded feed has no sample of the topics " + ", ".join(TOPICS))
        self.speed = speed

    @property
    def start_s(self) -> float:
        """The flight time (t_s) the replay starts at, seconds."""
        return min((t for t in map(_t_s, self._events) if t is not None), default=0.0)

    @property
    def duration_s(self) -> float:
        """Flight time the replay spans (the payloads' t_s), seconds."""
        times = [t for t in map(_t_s, self._events) if t is not None]
        return max(times) - min(times) if times else 0.0

    def span(self) -> dict[str, float]:
        """The page's replay controls: {"start_s", "end_s"} of flight time."""
        return {"start_s": self.start_s, "end_s": self.start_s + self.duration_s}

    def _seek(self, from_s: float) -> tuple[list[dict[str, Any]], int]:
        """(what a page seeking to from_s gets at once, the index the paced replay goes on from)."""
        newest, k, history = None, 0, len(self._events)
        for k, event in enumerate(self._events):
            t_s = _t_s(event)
            newest = t_s if newest is None or (t_s is not None and t_s > newest) else newest
            if history == len(self._events) and newest is not None and newest >= from_s - HISTORY_S:
                history = k
            if newest is not None and newest >= from_s:
                break
        else:
            k = len(self._events)
        before = {e["topic"]: e for e in self._events[:history]}
        return [*before.values(), *self._events[history:k]], k

    def events(self, stop: threading.Event, clock=time.monotonic,
               from_s: float | None = None) -> Iterator[dict[str, Any] | None]:
        """Every event at its time: t_s since the first stamped event, divided by the speed,
        after the page connected (with from_s: the seek's history at once, then from there).
        Ends after the last one."""
        at_once, k = self._seek(from_s) if from_s is not None else ([], 0)
        yield from at_once
        start_s = clock()
        first_t_s = None
        newest_t_s = None
        for event in self._events[k:]:
            t_s = _t_s(event)
            if t_s is not None:
                first_t_s = t_s if first_t_s is None else first_t_s
                newest_t_s = t_s if newest_t_s is None else max(newest_t_s, t_s)
                while (wait_s := start_s + (newest_t_s - first_t_s) / self.speed - clock()) > 0:
                    if stop.wait(min(wait_s, KEEPALIVE_S)):
                        return
                    if wait_s > KEEPALIVE_S:
                        yield None
            if stop.is_set():
                return
            yield event


def _t_s(event: dict[str, Any]) -> float | None:
    t_s = event["payload"].get("t_s")
    return float(t_s) if isinstance(t_s, (int, float)) and not isinstance(t_s, bool) else None
