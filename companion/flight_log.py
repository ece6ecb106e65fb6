"""The companion's flight log on the robot: one tlog per flight, with its own decisions in it.

Every MAVLink packet that crosses the link to the flight controller, in both directions (the
link hands each to `record()`, as to a TlogWriter), plus what the companion decided at each
control step as MAVLink messages of its own (system 1, component 191, never sent on the
link), so that any tlog tool (mavlogdump, MAVExplorer, `m4-companion plot`) reads one file:

- NAMED_VALUE_FLOAT at each answered telemetry instant (time_boot_ms: the FC's): `nmpc_ms`
  (solve time), `nmpc_iter`, `nmpc_cost`, `nmpc_ok` (1/0), `nmpc_fb` (fallback 1/0),
  `alt_first` (1/0: the plan gave the place up before the height, companion.core.altitude_first),
  `step_ms` (from the frame's arrival to the setpoint sent: the companion's latency),
  `com_n`/`com_e`/`com_d` (the centre of mass it planned from, NED m),
  `ref_n`/`ref_e`/`ref_d` (the mission reference there) and `dist_n`/`dist_e`/`dist_d` (the
  disturbance force it estimated and planned with, NED N: wind, mass and thrust errors).
- The detector's state is M4_FAULT_STATUS and the fault announcement STATUSTEXT: both go out
  on the link, so they are in the log already.

Files: `<dir>/flight-YYYYmmdd-HHMMSS.tlog` (UTC, the time the file was opened; the folder is
said at start: /var/log/m4 unless `[log] dir` says otherwise). One file a flight: a flight is
from process start, from the FC's HEARTBEAT turning armed after it was disarmed, or from the
FC's reboot (its clock going back after a silence: a new power-up starts armed in the
simulator) to the next such start or to the process's end. The new file begins with the
first packet of the poll that showed it (`position()` before the poll, `observe(..., since)`),
or with the next one when the writer has already passed it. A file larger than `max_file_mb`
is continued in a new one (`...-HHMMSS-2.tlog`). When a file is closed, the oldest logs of the folder go
until all of them fit in `max_total_mb` (the file being written is never removed).

Timing: while it reads and answers, the control loop only appends to a queue (a deque: no
lock, no I/O, no packing). At the end of each poll, its setpoint sent, it makes what it queued
into tlog records (`pack()`): each packet stamped as it crossed the link (never decoded nor
packed again), the decisions packed with precompiled structs (m4/mavlink/frame_packer.py:
pymavlink's packing is ten times slower). Then, at most every `FLUSH_S`, it wakes a thread of
its own, which writes those records in one call a file: the writer takes the interpreter's
lock as the loop goes to wait for its next frame. The loop's compiled calls (CasADi's, DAQP's)
give the lock up, and a writer on a timer of its own that packed its batch itself took it
there for 1-2 ms in the middle of an answer (25 control steps a batch in lockstep at 10x real
time): most of the answer's slowest 1 % (docs/performance.md). While the loop packs nothing,
the writer writes every `IDLE_FLUSH_S` on its own. If the folder cannot be written at start
the companion says so and flies without a log (a flight without a log beats no flight); so
too if packing fails (a defect: a value no record can hold): said once, the log queues nothing
more for the rest of the process, what was packed before is still written.

A write error later (a full disk: ENOSPC) pauses the log: what comes meanwhile is dropped,
and every RETRY_S the writer tries again in a new file (one file per gap), so the log resumes
when space returns. Both ends of a gap are said in the companion's log and queued as
`notices` for the control loop, which sends them as STATUSTEXT warnings (the link is the
control loop's alone); `gaps` and `paused` are on the feed. Closing never raises: a log
problem does not change how a flight ends.
"""

from __future__ import annotations

import collections
import logging
import math
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from companion.config import LogSettings
from m4.mavlink import COMPANION_COMPONENT_ID, FC_SYSTEM_ID, mavlink
from m4.mavlink.frame_packer import FramePacker
from m4.mavlink.tlog import TLOG_TIME

log = logging.getLogger("m4-companion")

FLUSH_S = 0.05                    # a batch: ~2.5 control steps in real time, ~25 in lockstep
IDLE_FLUSH_S = 2 * FLUSH_S        # the writer on its own, when the loop has not woken it
RETRY_S = 1.0                     # a paused log tries a new file this often
PATTERN = "flight-*.tlog"
_FLOAT32_MAX = 3.4028234663852886e38


@dataclass(frozen=True)
class Decision:
    time_ms: int
    values: tuple[tuple[bytes, float], ...]       # (NAMED_VALUE_FLOAT name, value)


class FlightLog:
    """Open with `open_flight_log()`; `FlightLog.disabled()` records nothing."""

    def __init__(self, settings: LogSettings, clock_ns=time.time_ns):
        self.settings = settings
        self.dir = Path(settings.dir)
        self.files: list[Path] = []                   # written by this process, in order
        self.records = 0
        self.gaps = 0                                 # times a write failed and the log paused
        self.notices: collections.deque[str] = collections.deque()   # for the ground station, oldest first
        self._paused_s: float | None = None           # monotonic time the current gap began
        self._tried_s = 0.0                           # monotonic time of the last try at a new file
        self._clock_ns = clock_ns
        self._queue: collections.deque = collections.deque()
        self._appended = 0                            # queue entries ever appended (the control loop's count)
        self._taken = 0                               # ... and packed (the control loop's too)
        self._flights: collections.deque[int] = collections.deque()   # entry numbers at which a new flight starts
        self._packed: collections.deque[list[bytes] | None] = collections.deque()  # records for the writer; None: a new flight
        self._armed: bool | None = None
        self._file = None
        self._size = 0
        self._max_file_bytes = settings.max_file_mb * 1e6
        self._stop = threading.Event()
        self._wake = threading.Event()                # set by the loop's pack: records to write
        self._wake_due_s = 0.0                        # monotonic time from which pack wakes the writer again
        self._decision_frames = FramePacker(mavlink.MAVLink_named_value_float_message, FC_SYSTEM_ID,
                                            COMPANION_COMPONENT_ID)
        self._seq = 0                                 # of the decision frames
        self._thread: threading.Thread | None = None
        self._queueing = False                        # started, and no packing failed

    @classmethod
    def disabled(cls) -> FlightLog:
        return cls(LogSettings(enabled=False))

    @property
    def enabled(self) -> bool:
        return self._thread is not None

    @property
    def paused(self) -> bool:
        """A write failed and no new file could be written since."""
        return self._paused_s is not None

    def start(self) -> FlightLog:
        self.dir.mkdir(parents=True, exist_ok=True)
        self._open()                                  # fails here, at start, if the folder is not writable
        self._thread = threading.Thread(target=self._run, name="flight-log", daemon=True)
        self._thread.start()
        self._queueing = True
        return self

    # -- the control loop's side: appends, and packs after its send ----------------------------
    def position(self) -> int:
        """The number the next entry will have: where a flight found in the coming poll starts."""
        return self._appended

    def record(self, packet: bytes, unix_time_us: int | None = None) -> None:
        """One packet sent or received (the link's tlog interface, m4/mavlink/tlog.py)."""
        self.record_all([packet], unix_time_us)

    def record_all(self, packets: list[bytes], unix_time_us: int | None = None) -> None:
        """A datagram's packets, sent or received, at one time (the link's tlog interface)."""
        if self._queueing:
            t_us = self._clock_ns() // 1000 if unix_time_us is None else unix_time_us
            self._queue.extend((t_us, bytes(packet)) for packet in packets)
            self._appended += len(packets)

    def observe(self, msgs, since: int, fc_rebooted: bool = False) -> None:
        """The FC's messages of one poll, which began at entry `since`: its reboot, or its HEARTBEAT
        turning armed after disarmed, starts a new flight there."""
        for msg in msgs:
            if msg.get_msgId() == mavlink.MAVLINK_MSG_ID_HEARTBEAT:
                armed = bool(msg.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
                fc_rebooted |= armed and self._armed is False
                self._armed = armed
        if fc_rebooted and self._queueing and (not self._flights or self._flights[-1] != since):
            self._flights.append(since)

    def decision(self, time_ms: int, step, latency_s: float) -> None:
        """What the controller decided for the telemetry instant `time_ms` (a ControlStep)."""
        if not self._queueing:
            return
        values = [(b"step_ms", latency_s * 1e3), (b"com_n", step.state[0]), (b"com_e", step.state[1]),
                  (b"com_d", step.state[2]), (b"dist_n", step.disturbance[0]), (b"dist_e", step.disturbance[1]),
                  (b"dist_d", step.disturbance[2])]
        if step.reference is not None:
            values += [(b"ref_n", step.reference[0, 0]), (b"ref_e", step.reference[0, 1]),
                       (b"ref_d", step.reference[0, 2])]
        if step.nmpc is not None:
            r = step.nmpc
            values += [(b"nmpc_ms", r.solve_ms), (b"nmpc_iter", r.iterations), (b"nmpc_cost", r.cost),
                       (b"nmpc_ok", r.ok), (b"nmpc_fb", r.fallback), (b"alt_first", r.altitude_first)]
        self._queue.append((self._clock_ns() // 1000, Decision(int(time_ms), tuple(values))))
        self._appended += 1

    def pack(self) -> None:
        """What was queued since the last call made into tlog records for the writer, on the
        caller's thread (the control loop's, at the end of its poll); a new flight's first entry
        starts a new batch. The writer is woken to write them at most every FLUSH_S. A failure
        stops the log, never the loop (`_stop_queueing`)."""
        try:
            self._pack()
        except Exception as e:  # noqa: BLE001 - a defect in what was queued: a flight without a log beats no flight
            self._stop_queueing(e)

    def _pack(self) -> None:
        records: list[bytes] = []
        while self._queue:
            if self._flights and self._taken >= self._flights[0]:
                self._flights.popleft()
                if records:
                    self._packed.append(records)
                    records = []
                self._packed.append(None)
                continue
            entry = self._queue.popleft()
            self._taken += 1
            records += self._records(*entry)
        if records:
            self._packed.append(records)
        if self._packed and (now_s := time.monotonic()) >= self._wake_due_s:
            self._wake_due_s = now_s + FLUSH_S
            self._wake.set()

    def _stop_queueing(self, error: Exception) -> None:
        """Packing failed: said once, what is queued dropped, nothing queued from now on; the
        records packed before are still written."""
        log.error("flight log stopped for the rest of the process: cannot pack its records (%s: %s); the flight "
                  "goes on", type(error).__name__, error)
        self._queueing = False
        self._queue.clear()
        self._flights.clear()

    def _records(self, time_us: int, payload) -> list[bytes]:
        """The tlog records of one queue entry: a packet as it crossed the link, or a decision's
        NAMED_VALUE_FLOATs."""
        stamp = TLOG_TIME.pack(time_us & ~0x3)
        if not isinstance(payload, Decision):
            return [stamp + payload]
        records = []
        for name, value in payload.values:
            records.append(stamp + self._decision_frames.pack(self._seq, payload.time_ms, _float32(value), name))
            self._seq += 1
        return records

    # -- the writer thread -------------------------------------------------------------------
    def _run(self) -> None:
        while not self._stop.is_set():
            self._wake.wait(IDLE_FLUSH_S)
            self._wake.clear()
            self._flush()
        self._flush()

    def _flush(self) -> None:
        """Write what is queued; while paused, try a new file with it every RETRY_S, else drop it."""
        if self._paused_s is None:
            try:
                self._drain()
            except OSError as e:
                self._pause(e)
        elif self._packed and time.monotonic() - self._tried_s >= RETRY_S:
            self._resume()
        else:
            self._drop_queued()

    def _drop_queued(self) -> None:
        while self._packed:
            self._packed.popleft()

    def _pause(self, error: OSError) -> None:
        reason = error.strerror or str(error)
        log.error("flight log paused: cannot write %s (%s); trying a new file every %g s", self.files[-1], reason,
                  RETRY_S)
        self._let_go()
        self._drop_queued()
        self._paused_s = self._tried_s = time.monotonic()
        self.gaps += 1
        self.notices.append(f"companion: log paused: {reason}")

    def _resume(self) -> None:
        """A new file for what is queued now; the gap ends when it is written."""
        self._tried_s = time.monotonic()
        while self._packed and self._packed[0] is None:     # the new file starts them anyway
            self._packed.popleft()
        try:
            self._open()
            self._drain()
        except OSError:                               # still failing: the gap goes on (said when it began)
            self._let_go()
            self._drop_queued()
            return
        gap_s = self._tried_s - self._paused_s
        self._paused_s = None
        log.warning("flight log resumed in %s after a %.1f s gap", self.files[-1], gap_s)
        self.notices.append(f"companion: log resumed after a {gap_s:.1f} s gap")

    def _let_go(self) -> None:
        """Drop the file a write failed on: closing it may fail the same way (already said); a
        file left empty is removed."""
        file, self._file = self._file, None
        if file is None:
            return
        try:
            file.close()
        except OSError:
            pass
        try:
            if self.files[-1].stat().st_size == 0:
                self.files.pop().unlink()
        except OSError:
            pass

    def _drain(self) -> None:
        """Write what was packed, one write a file; a batch that fits the file goes whole, record
        by record only where the file fills."""
        chunk: list[bytes] = []                       # tlog records for the current file
        while self._packed:
            records = self._packed.popleft()
            if records is None:
                chunk = self._next_file(chunk)
                continue
            size = sum(map(len, records))
            if self._size + size < self._max_file_bytes:
                chunk += records
                self._size += size
                continue
            for record in records:
                if self._size >= self._max_file_bytes:
                    chunk = self._next_file(chunk)
                chunk.append(record)
                self._size += len(record)
        self._write(chunk)

    def _write(self, chunk: list[bytes]) -> None:
        if chunk:
            self._file.write(b"".join(chunk))
            self._file.flush()
            self.records += len(chunk)

    def _next_file(self, chunk: list[bytes]) -> list[bytes]:
        """Write the current file's last records, close it and open the next; the new chunk."""
        self._write(chunk)
        self._close_file()
        self._open()
        return []

    def _open(self) -> None:
        stamp = time.strftime("%Y%m%d-%H%M%S", time.gmtime(self._clock_ns() / 1e9))
        path, n = self.dir / f"flight-{stamp}.tlog", 1
        while path.exists() or path in self.files:
            n += 1
            path = self.dir / f"flight-{stamp}-{n}.tlog"
        self._file = path.open("wb")
        self._size = 0
        self.files.append(path)

    def _close_file(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None
            self._trim()

    def _trim(self) -> None:
        """Remove the oldest logs until the folder's fit in max_total_mb (never the newest file)."""
        logs = sorted(self.dir.glob(PATTERN), key=lambda p: (p.stat().st_mtime, p.name))
        total = sum(p.stat().st_size for p in logs)
        for old in logs[:-1]:
            if total <= self.settings.max_total_mb * 1e6:
                break
            total -= old.stat().st_size
            old.unlink()

    def close(self) -> None:
        """Write everything queued and close the file; a failure is said, never raised. Called
        by the control loop's thread (it packs what is left)."""
        self.pack()
        thread, self._thread = self._thread, None
        if thread is not None:
            self._stop.set()
            self._wake.set()
            thread.join()
        try:
            self._close_file()
        except OSError as e:
            log.error("flight log: cannot close %s (%s); its last records may be missing", self.files[-1],
                      e.strerror or e)


def _float32(value) -> float:
    """A NAMED_VALUE_FLOAT's value: beyond float32's range an infinity of its sign (struct would
    raise, ending the log), NaN as it is."""
    v = float(value)
    return math.copysign(math.inf, v) if abs(v) > _FLOAT32_MAX else v


def open_flight_log(settings: LogSettings) -> FlightLog:
    """The flight log as the settings ask; a folder that cannot be written is said, not fatal."""
    if not settings.enabled:
        return FlightLog.disabled()
    flight_log = FlightLog(settings)
    try:
        return flight_log.start()
    except OSError as e:
        log.error("flight log off: cannot write %s (%s); set [log] dir, or enabled = false", settings.dir,
                  e.strerror or e)
        return FlightLog.disabled()
