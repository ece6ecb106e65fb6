"""Telemetry logs (tlog): every MAVLink packet, in both directions, as pymavlink reads them.

A tlog is a sequence of records: an 8-byte big-endian unsigned Unix time in microseconds,
then the raw packet. pymavlink reads the low two bits of the time as a link id, so they are
cleared (one link). `setup_logfile()` of a pymavlink UDP connection logs nothing, hence
this writer: call `record()` for each packet sent and each packet received.
"""

from __future__ import annotations

import struct
import threading
import time
from pathlib import Path
from typing import Self

TLOG_TIME = struct.Struct(">Q")          # each record's Unix time in microseconds, before the packet


class TlogWriter:
    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file = self.path.open("wb")
        self._lock = threading.Lock()
        self.records = 0

    def record(self, packet: bytes, unix_time_us: int | None = None) -> None:
        self.record_all([packet], unix_time_us)

    def record_all(self, packets: list[bytes], unix_time_us: int | None = None) -> None:
        """record() of each packet, all at one time (a datagram's: one clock read and one write)."""
        if unix_time_us is None:
            unix_time_us = time.time_ns() // 1000
        stamp = TLOG_TIME.pack(unix_time_us & ~0x3)
        with self._lock:
            self._file.write(b"".join(stamp + bytes(packet) for packet in packets))
            self.records += len(packets)

    def close(self) -> None:
        with self._lock:
            self._file.close()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
