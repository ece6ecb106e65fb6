"""The dashboard's HTTP server: the page, its settings, and the events as Server-Sent Events.

Routes:
    /                   the page (static/index.html), /dashboard.js, /dashboard.css
    /config.json        {"vehicle", "mode": "live" | "replay", "source", "airframe": {...}};
                        a replay's "replay": {"start_s", "end_s"} (flight time)
    /events             text/event-stream: one `data: {event}` per feed sample (events.py);
                        `: keep-alive` comments while nothing comes; a replay ends with
                        `event: end` and closes. A replay's /events?from_s=T starts at
                        flight time T (a seek; the page pauses by closing the stream)
    /latest.json        live only: the newest event of each topic

Standard library only (http.server, one thread per connection): a page on the robot's
network needs nothing fetched from anywhere else.
"""

from __future__ import annotations

import json
import math
import threading
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from typing import Any, Protocol
from urllib.parse import parse_qs
from collections.abc import Iterator

STATIC = {"/": ("index.html", "text/html; charset=utf-8"),
          "/dashboard.js": ("dashboard.js", "text/javascript; charset=utf-8"),
          "/dashboard.css": ("dashboard.css", "text/css; charset=utf-8")}


class EventSource(Protocol):
    def events(self, stop: threading.Event, **seek: float) -> Iterator[dict[str, Any] | None]: ...


def static_file(name: str) -> bytes:
    return (resources.files("companion.dashboard") / "static" / name).read_bytes()


class DashboardServer(ThreadingHTTPServer):
    """Serves one source of events to any number of pages until close()."""

    daemon_threads = True

    def __init__(self, source: EventSource, config: dict[str, Any], host: str = "127.0.0.1", port: int = 8080):
        self.source = source
        self.config_bytes = json.dumps(config).encode()
        self.seekable = config.get("mode") == "replay"
        self.stopping = threading.Event()
        super().__init__((host, port), _Handler)

    @property
    def url(self) -> str:
        host, port = self.server_address[:2]
        return f"http://{host}:{port}/"

    def close(self) -> None:
        self.stopping.set()
        self.shutdown()
        self.server_close()


def _seek(query: str) -> dict[str, float] | None:
    """{"from_s": T} of a replay's ?from_s=T, {} without one; None when T is not a finite number."""
    values = parse_qs(query).get("from_s")
    if not values:
        return {}
    try:
        from_s = float(values[0])
    except ValueError:
        return None
    return {"from_s": from_s} if math.isfinite(from_s) else None


class _Handler(BaseHTTPRequestHandler):
    server: DashboardServer
    protocol_version = "HTTP/1.1"

    def do_GET(self) -> None:  # noqa: N802 - http.server's name
        path, _, query = self.path.partition("?")
        if path in STATIC:
            name, content_type = STATIC[path]
            self._send(HTTPStatus.OK, content_type, static_file(name))
        elif path == "/config.json":
            self._send(HTTPStatus.OK, "application/json", self.server.config_bytes)
        elif path == "/latest.json" and hasattr(self.server.source, "latest"):
            self._send(HTTPStatus.OK, "application/json", json.dumps(self.server.source.latest()).encode())
        elif path == "/events":
            seek = _seek(query)
            if seek is None or (seek and not self.server.seekable):
                self._send(HTTPStatus.BAD_REQUEST, "text/plain; charset=utf-8",
                           b"from_s: a number, and only for a replay\n")
            else:
                self._stream(seek)
        else:
            self._send(HTTPStatus.NOT_FOUND, "text/plain; charset=utf-8", b"not found\n")

    def _send(self, status: HTTPStatus, content_type: str, body: bytes) -> None:
        self.send_response(status)
        self.send_header("Content-Type", content_type)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        self.end_headers()
        self.wfile.write(body)

    def _stream(self, seek: dict[str, float]) -> None:
        self.send_response(HTTPStatus.OK)
        self.send_header("Content-Type", "text/event-stream")
        self.send_header("Cache-Control", "no-store")
        self.send_header("Connection", "close")
        self.end_headers()
        self.close_connection = True
        try:
            for event in self.server.source.events(self.server.stopping, **seek):
                chunk = ": keep-alive\n\n" if event is None else f"data: {json.dumps(event, separators=(',', ':'))}\n\n"
                self.wfile.write(chunk.encode())
                self.wfile.flush()
            if not self.server.stopping.is_set():
                self.wfile.write(b"event: end\ndata: {}\n\n")
                self.wfile.flush()
        except (BrokenPipeError, ConnectionResetError):
            return                         # the page went away

    def log_message(self, format: str, *args: Any) -> None:  # noqa: A002 - http.server's signature
        return                             # one line per request would drown the terminal
