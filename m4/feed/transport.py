"""Zenoh at the edge: a config from a file or explicit endpoints, a session, JSON publishers.

Opening a session in peer mode never waits for the other side (it retries in the
background; about half a second at start when a connect endpoint is down); client mode
needs its router or peer reachable at open and fails with a clear FeedError otherwise.
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import zenoh

from m4.feed.payloads import TOPICS, key_for
from m4.feed.settings import FeedSettings

_RUST_LOCATION = re.compile(r"\s+at \S+\.rs:\d+\.?\s*$")


class FeedError(RuntimeError):
    """The feed's Zenoh side could not be set up; the message says what and why."""


def zenoh_error_text(error: Exception) -> str:
    """Zenoh's message without the Rust source location it appends."""
    return _RUST_LOCATION.sub("", str(error)).strip()


def config_from_file(path: str | Path) -> zenoh.Config:
    """A Zenoh config file (json5), used as written."""
    path = Path(path)
    if not path.is_file():
        raise FeedError(f"{path}: no such Zenoh config file")
    try:
        return zenoh.Config.from_file(str(path))
    except zenoh.ZError as e:
        raise FeedError(f"{path}: not a valid Zenoh config: {zenoh_error_text(e)}") from None


def config_from_endpoints(mode: str, connect: tuple[str, ...] = (), listen: tuple[str, ...] = ()) -> zenoh.Config:
    """Peer or client with explicit endpoints only: no scouting, no listening but `listen`."""
    cfg = zenoh.Config()
    entries = {
        "mode": mode,
        "scouting/multicast/enabled": False,
        "scouting/gossip/enabled": False,
        "connect/endpoints": list(connect),
        "listen/endpoints": list(listen),
    }
    for key, value in entries.items():
        try:
            cfg.insert_json5(key, json.dumps(value))
        except zenoh.ZError as e:
            raise FeedError(f"Zenoh {key} = {value!r}: {zenoh_error_text(e)}") from None
    return cfg


def config_for(settings: FeedSettings) -> zenoh.Config:
    if settings.zenoh_config is not None:
        return config_from_file(settings.zenoh_config)
    return config_from_endpoints(settings.mode, settings.connect, settings.listen)


def open_session(cfg: zenoh.Config, what: str) -> zenoh.Session:
    try:
        return zenoh.open(cfg)
    except zenoh.ZError as e:
        raise FeedError(f"cannot open the Zenoh session ({what}): {zenoh_error_text(e)}") from None


def describe(settings: FeedSettings) -> str:
    if settings.zenoh_config is not None:
        return f"config {settings.zenoh_config}"
    ends = [f"connect {e}" for e in settings.connect] + [f"listen {e}" for e in settings.listen]
    return f"{settings.mode}, {', '.join(ends)}"


class ZenohSink:
    """One JSON publisher per topic on an open session; `put` drops rather than waits."""

    def __init__(self, session: zenoh.Session, vehicle: str):
        self._session = session
        self._encoder = json.JSONEncoder(allow_nan=False, separators=(",", ":"))    # json.dumps builds one a call
        self._publishers = {
            topic: session.declare_publisher(
                key_for(vehicle, topic),
                encoding=zenoh.Encoding.APPLICATION_JSON,
                congestion_control=zenoh.CongestionControl.DROP,
            )
            for topic in TOPICS
        }

    @classmethod
    def open(cls, settings: FeedSettings) -> "ZenohSink":
        session = open_session(config_for(settings), describe(settings))
        try:
            return cls(session, settings.vehicle)
        except zenoh.ZError as e:
            session.close()
            raise FeedError(f"cannot declare the feed's publishers: {zenoh_error_text(e)}") from None

    def put(self, topic: str, payload: dict[str, Any]) -> None:
        self._publishers[topic].put(self._encoder.encode(payload).encode())

    def close(self) -> None:
        self._session.close()
