"""Records the companion's Zenoh feed during a flight into a JSON-lines file.

A Zenoh peer listening on one loopback endpoint (scouting off); the companion's [feed]
connects to it. Each sample becomes one line {"key": ..., "payload": {...}}; the newest
simulated time seen (`t_s` of the payloads) is kept for a progress display.
"""

from __future__ import annotations

import json
import threading
from pathlib import Path

from m4.feed.payloads import KEY_PREFIX
from m4.feed.transport import config_from_endpoints, open_session


class FeedRecorder:
    def __init__(self, path: str | Path, endpoint: str, vehicle: str):
        self._file = Path(path).open("w")  # noqa: SIM115 - open while recording, closed by close()
        self._lock = threading.Lock()
        self.latest_t_s: float | None = None
        self.samples = 0
        self._session = open_session(config_from_endpoints("peer", listen=(endpoint,)), f"feed recorder {endpoint}")
        self._session.declare_subscriber(f"{KEY_PREFIX}/{vehicle}/**", self._take)

    def _take(self, sample) -> None:
        try:
            payload = json.loads(sample.payload.to_bytes())
        except ValueError:
            return
        line = json.dumps({"key": str(sample.key_expr), "payload": payload}, separators=(",", ":"))
        with self._lock:
            if self._file.closed:
                return
            self._file.write(line + "\n")
            self.samples += 1
            t_s = payload.get("t_s") if isinstance(payload, dict) else None
            if isinstance(t_s, (int, float)):
                self.latest_t_s = max(t_s, self.latest_t_s or 0.0)

    def close(self) -> None:
        self._session.close()
        with self._lock:
            self._file.close()
