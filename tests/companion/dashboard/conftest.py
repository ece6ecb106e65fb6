"""A real headless Chromium driven over the DevTools protocol (on a pipe: no port, no library),
and a dashboard server on 127.0.0.1 in this process."""

from __future__ import annotations

import base64
import io
import json
import os
import re
import select
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import pytest
from PIL import Image

from companion.dashboard.events import airframe_view
from companion.dashboard.server import DashboardServer
from companion.feed_publisher import open_feed
from m4.airframe import load_airframe
from m4.feed.settings import FeedSettings

# 0-5 s of `m4-sitl fly hover-rotor-loss --out DIR`'s DIR/feed.jsonl at 25 Hz, numbers to 4 decimals:
#   python -c 'import json, sys
#   for line in open(sys.argv[1]):
#       e = json.loads(line, parse_float=lambda s: round(float(s), 4))
#       t = e["payload"]["t_s"]
#       if t is not None and t <= 5.0 and round(t * 50) % 2 == 0:
#           print(json.dumps(e, separators=(",", ":")))' DIR/feed.jsonl > hover-rotor-loss-feed.jsonl
FEED = Path(__file__).with_name("hover-rotor-loss-feed.jsonl")
WINDOW = (1280, 800)
FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--disable-dev-shm-usage", "--hide-scrollbars", "--mute-audio", "--remote-debugging-pipe",
         f"--window-size={WINDOW[0]},{WINDOW[1]}")


class Chromium:
    """One browser, one tab; commands as the DevTools protocol names them (fd 3 in, fd 4 out,
    one JSON message per NUL-terminated chunk)."""

    def __init__(self, executable: str, timeout_s: float = 30.0):
        self._profile = tempfile.TemporaryDirectory(prefix="m4-chromium-")
        self._log = Path(self._profile.name) / "chromium.log"
        self._log_file = self._log.open("wb")
        # The shell hands our stdin and stdout to Chromium as fds 3 and 4, as --remote-debugging-pipe wants.
        self._proc = subprocess.Popen(
            ["sh", "-c", 'exec "$@" 3<&0 4>&1 </dev/null >/dev/null', "chromium", executable, *FLAGS,
             f"--user-data-dir={self._profile.name}", "about:blank"],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=self._log_file)
        self._buffer = b""
        self._next_id = 0
        self.timeout_s = timeout_s
        target = self.send("Target.createTarget", url="about:blank")["targetId"]
        self._session = self.send("Target.attachToTarget", targetId=target, flatten=True)["sessionId"]
        self.command("Emulation.setDeviceMetricsOverride", width=WINDOW[0], height=WINDOW[1],
                     deviceScaleFactor=1, mobile=False)

    def send(self, method: str, session: str | None = None, **params) -> dict:
        self._next_id += 1
        message = {"id": self._next_id, "method": method, "params": params}
        if session:
            message["sessionId"] = session
        try:
            self._proc.stdin.write(json.dumps(message).encode() + b"\0")
            self._proc.stdin.flush()
        except BrokenPipeError:
            raise RuntimeError(f"{method}: Chromium has gone: {self._log_tail()}") from None
        deadline = time.monotonic() + self.timeout_s
        while True:
            reply = self._read(deadline)
            if reply.get("id") == self._next_id:
                if "error" in reply:
                    raise RuntimeError(f"{method}: {reply['error']}")
                return reply["result"]

    def command(self, method: str, **params) -> dict:
        return self.send(method, self._session, **params)

    def _read(self, deadline: float) -> dict:
        fd = self._proc.stdout.fileno()
        while b"\0" not in self._buffer:
            if not select.select([fd], [], [], max(deadline - time.monotonic(), 0))[0]:
                raise TimeoutError("Chromium did not answer in time")
            chunk = os.read(fd, 1 << 20)
            if not chunk:
                raise RuntimeError(f"Chromium closed its DevTools pipe: {self._log_tail()}")
            self._buffer += chunk
        message, self._buffer = self._buffer.split(b"\0", 1)
        return json.loads(message)

    def _log_tail(self) -> str:
        lines = [ln for ln in self._log.read_text(errors="replace").splitlines() if "dbus" not in ln]
        return " | ".join(lines[-3:]) or "(it said nothing)"

    def open(self, url: str) -> None:
        """Navigate to url and wait until its document has loaded."""
        self.command("Page.navigate", url=url)
        self.wait_for(f"location.href === {json.dumps(url)} && document.readyState === 'complete'")

    def evaluate(self, expression: str):
        result = self.command("Runtime.evaluate", expression=expression, returnByValue=True, awaitPromise=True)
        if "exceptionDetails" in result:
            raise RuntimeError(f"{expression}: {result['exceptionDetails']}")
        return result["result"].get("value")

    def wait_for(self, expression: str, timeout_s: float = 20.0) -> None:
        deadline = time.monotonic() + timeout_s
        while not self.evaluate(expression):
            if time.monotonic() > deadline:
                raise TimeoutError(f"the page never made {expression} true")
            time.sleep(0.05)

    def screenshot(self) -> tuple[bytes, Image.Image]:
        """The page as PNG bytes and as an RGB image, after the next two animation frames."""
        self.evaluate("new Promise(r => requestAnimationFrame(() => requestAnimationFrame(r)))")
        png = base64.b64decode(self.command("Page.captureScreenshot", format="png")["data"])
        return png, Image.open(io.BytesIO(png)).convert("RGB")

    def rect(self, selector: str) -> tuple[int, int, int, int]:
        """(left, top, right, bottom) of an element in screenshot pixels."""
        r = self.evaluate(f"(() => {{ const r = document.querySelector({selector!r}).getBoundingClientRect();"
                          " return [r.left, r.top, r.right, r.bottom]; })()")
        return tuple(round(v) for v in r)

    def close(self) -> None:
        try:
            self.send("Browser.close")
        except (RuntimeError, TimeoutError, OSError):
            pass
        try:
            self._proc.wait(10)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            self._proc.wait()
        self._log_file.close()
        self._profile.cleanup()


@pytest.fixture(scope="module")
def chromium():
    executable = shutil.which("chromium") or shutil.which("chromium-browser")
    if executable is None:
        pytest.fail("no chromium on PATH: run scripts/install.sh (it installs Debian's chromium)")
    browser = Chromium(executable)
    yield browser
    browser.close()


@pytest.fixture
def serve():
    """serve(source) -> a running DashboardServer of a replay on 127.0.0.1 (closed after the test)."""
    servers = []

    def start(source) -> DashboardServer:
        config = {"vehicle": "m4", "mode": "replay", "source": f"{FEED.name} at {source.speed:g}x",
                  "airframe": airframe_view(load_airframe()), "replay": source.span()}
        server = DashboardServer(source, config, "127.0.0.1", 0)
        threading.Thread(target=server.serve_forever, daemon=True).start()
        servers.append(server)
        return server

    yield start
    for server in servers:
        server.close()


@pytest.fixture
def dashboard_process(endpoint):
    """`m4-companion dashboard --connect ENDPOINT --port 0` against a companion feed listening
    on ENDPOINT; yields (feed, url)."""
    feed = open_feed(FeedSettings(vehicle="m4", listen=(endpoint,), max_rate_hz=0.0))
    proc = subprocess.Popen([sys.executable, "-m", "companion.cli", "dashboard", "--connect", endpoint, "--port", "0"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        line = proc.stderr.readline()
        match = re.search(r"on (http://127\.0\.0\.1:\d+/)", line)
        assert match, line
        yield feed, match.group(1)
    finally:
        proc.terminate()
        proc.wait(10)
        proc.stderr.close()
        feed.close()
