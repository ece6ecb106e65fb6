"""A stand-in companion for tests and benchmarks: it answers every frame.

It listens on a UDP port, keeps every message it receives, and answers each new
M4_THRUSTER_STATUS (the last message of a lockstep frame) with an M4_SETPOINT for that
instant: by default the hover thrust per rotor at the nominal posture (open loop).
`python -m benchmarks.lockstep` times `m4-sitl serve` in lockstep against it. With other
`ids` and `until_ms=0` it answers nothing: a ground station that listens and sends what it is
told.
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Callable
from dataclasses import replace

import numpy as np

from m4.airframe import ROTOR_COUNT, load_airframe
from m4.mavlink import COMPANION_COMPONENT_ID, FC_COMPONENT_ID, FC_SYSTEM_ID, mavlink
from m4.mavlink.link import UdpLink, wait_readable
from sitl.serve import Server

Answer = Callable[[int], tuple]      # time_boot_ms -> (thrust_n, hip_rad, hip_rate_rad_s, flags)


def _hover_answer() -> Answer:
    """The hover thrust per rotor at the nominal posture, whatever the instant (open loop)."""
    af = load_airframe()
    hover = (np.full(ROTOR_COUNT, af.hover_thrust_per_rotor_n), np.full(ROTOR_COUNT, af.nominal_hip_rad),
             np.zeros(ROTOR_COUNT), 0)
    return lambda t_ms: hover


class StandInCompanion:
    def __init__(self, period_ms: int = 20, key: bytes | None = None, answer: Answer | None = None,
                 until_ms: int | None = None, port: int = 0,
                 ids: tuple[int, int] = (FC_SYSTEM_ID, COMPANION_COMPONENT_ID)):
        self.period_ms = period_ms
        self.answer = answer or _hover_answer()
        self.link = UdpLink(f"udpin:127.0.0.1:{port}", *ids, key=key)
        self.received: list[mavlink.MAVLink_message] = []
        self.until_ms = until_ms          # stop answering frames from this instant on (None: never)
        self.answered = 0
        self._last_ms = -1
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._send_lock = threading.Lock()

    @property
    def url(self) -> str:
        """Where the SITL should send: `--mavlink` for `m4-sitl serve`."""
        return f"udpout:127.0.0.1:{self.link.local_port}"

    def setpoint(self, t_ms: int) -> mavlink.MAVLink_m4_setpoint_message:
        thrust, hip, rate, flags = self.answer(t_ms)
        return mavlink.MAVLink_m4_setpoint_message(FC_SYSTEM_ID, FC_COMPONENT_ID, t_ms, self.period_ms,
                                                   [float(x) for x in thrust], [float(x) for x in hip],
                                                   [float(x) for x in rate], flags)

    def send(self, msg: mavlink.MAVLink_message) -> None:
        """Thread-safe: the answering thread and a test may both send."""
        with self._send_lock:
            self.link.send(msg)

    def poll(self, timeout_s: float = 0.05) -> None:
        if wait_readable([self.link], timeout_s):
            for msg in self.link.receive():
                self.received.append(msg)
                if (msg.get_msgId() == mavlink.MAVLINK_MSG_ID_M4_THRUSTER_STATUS and msg.time_boot_ms > self._last_ms
                        and (self.until_ms is None or msg.time_boot_ms < self.until_ms)):
                    self._last_ms = msg.time_boot_ms
                    self.send(self.setpoint(msg.time_boot_ms))
                    self.answered += 1

    def start(self) -> StandInCompanion:
        self._thread = threading.Thread(target=self._loop, daemon=True)
        self._thread.start()
        return self

    def _loop(self) -> None:
        while not self._stop.is_set():
            self.poll()

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
        self.link.close()

    def of_type(self, name: str) -> list[mavlink.MAVLink_message]:
        return [m for m in list(self.received) if m.get_type() == name]

    def wait_for(self, name: str, match=lambda msg: True, timeout_s: float = 10.0):
        """The first received message of type `name` that `match`es (waiting up to timeout_s), or None."""
        deadline = time.monotonic() + timeout_s
        while True:
            found = next((m for m in self.of_type(name) if match(m)), None)
            if found is not None or time.monotonic() > deadline:
                return found
            time.sleep(0.01)


@contextlib.contextmanager
def served(companion: StandInCompanion, options, more_urls: tuple[str, ...] = (),
           prepare: Callable[[Server], None] = lambda server: None):
    """`sitl.serve.Server` with `options` (its links: the companion's URL, then `more_urls`) in
    a thread of this process, the companion answering in another; both stopped on exit.
    `prepare(server)` is called before it runs. Entered once the companion has heard the FC
    (so it knows where to send)."""
    server = Server(replace(options, mavlink_urls=(companion.url, *more_urls)))
    prepare(server)
    thread = threading.Thread(target=server.run, daemon=True)
    companion.start()
    thread.start()
    try:
        companion.wait_for("HEARTBEAT", timeout_s=10.0)
        yield server
    finally:
        server.stop()
        thread.join()
        server.close()
        companion.close()
