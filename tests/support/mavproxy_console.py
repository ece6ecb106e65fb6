"""MAVProxy, a real ground station, as a test drives it: mavproxy.py on a MAVLink URL, its
console lines kept, commands written to its stdin."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time


class MavProxy:
    """mavproxy.py on `master` (a MAVLink URL) with `modules`, run in `cwd` (its mav.tlog is there)."""

    def __init__(self, master: str, cwd, modules: str = "link,mode"):
        self.lines: list[str] = []
        self.process = subprocess.Popen(
            [sys.executable, "-m", "MAVProxy.mavproxy", f"--master={master}", "--nodtr",
             f"--default-modules={modules}"], cwd=cwd, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT, text=True, env={**os.environ, "PYTHONUNBUFFERED": "1"})
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        for line in self.process.stdout:
            self.lines.append(line)

    def command(self, text: str) -> None:
        self.process.stdin.write(text + "\n")
        self.process.stdin.flush()

    def wait_for(self, text: str, timeout_s: float) -> bool:
        deadline = time.monotonic() + timeout_s
        while not any(text in line for line in list(self.lines)):
            if time.monotonic() > deadline:
                return False
            time.sleep(0.05)
        return True

    def close(self) -> str:
        self.process.stdin.close()          # MAVProxy ends at the end of its input
        try:
            self.process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()
        return "".join(self.lines)
