"""MAVLink 2 over a byte stream: TCP (client `tcp:HOST:PORT`, server `tcpin:HOST:PORT`) or a
serial port (`/dev/NAME,BAUD`), with the same small interface as UdpLink.

A stream has one peer, so `lock_peer()` only matters to a TCP server: once locked, a second
connection is refused (closed at once and counted in `foreign_datagrams`) instead of taking
over. A TCP client whose server goes away tries again at most once a second; a server waits
for the next connection. Nothing here blocks for long: reads take what has arrived, writes
to a full or broken stream are dropped (as UDP would).
"""

from __future__ import annotations

import contextlib
import select
import socket
import time

from m4.mavlink.dialect import mavlink
from m4.mavlink.link import LinkError, MavlinkLink
from m4.mavlink.tlog import TlogWriter

SERIAL_DEFAULT_BAUD = 115200
RECONNECT_S = 1.0
_READ_MAX = 65536
_WRITE_TIMEOUT_S = 0.05


class _TcpStream:
    """A TCP client (mode "tcp") or a one-peer server (mode "tcpin")."""

    def __init__(self, mode: str, host: str, port: int):
        self.mode, self.address = mode, (host, port)
        self.conn: socket.socket | None = None
        self.listener: socket.socket | None = None
        self.peer = None
        self.locked = None
        self.refused = 0
        self._retry_at = 0.0
        try:
            if mode == "tcpin":
                self.listener = socket.create_server(self.address)
                self.listener.setblocking(False)
            else:
                self._connect(timeout_s=5.0)
        except OSError as e:
            self.close()
            raise LinkError(f"{self.label}: cannot open ({e.strerror or e})") from None

    @property
    def label(self) -> str:
        return f"{self.mode}:{self.address[0]}:{self.address[1]}"

    @property
    def local_port(self) -> int:
        sock = self.listener or self.conn
        return sock.getsockname()[1]

    def _connect(self, timeout_s: float) -> None:
        conn = socket.create_connection(self.address, timeout=timeout_s)
        conn.setblocking(False)
        self.conn, self.peer = conn, conn.getpeername()

    def fileno(self) -> int:
        return (self.conn or self.listener).fileno() if (self.conn or self.listener) else -1

    def read(self) -> bytes:
        if self.listener is not None:
            self._accept()
        if self.conn is None:
            if self.mode == "tcp" and time.monotonic() >= self._retry_at:
                self._retry_at = time.monotonic() + RECONNECT_S
                with contextlib.suppress(OSError):
                    self._connect(timeout_s=0.2)
            return b""
        try:
            data = self.conn.recv(_READ_MAX)
        except (BlockingIOError, InterruptedError):
            return b""
        except OSError:
            data = b""
        if not data:                    # closed by the peer
            self.conn.close()
            self.conn = None
        return data

    def _accept(self) -> None:
        while True:
            try:
                conn, peer = self.listener.accept()
            except (BlockingIOError, InterruptedError, OSError):
                return
            if self.conn is not None or (self.locked is not None and peer[0] != self.locked[0]):
                conn.close()
                self.refused += 1
                continue
            conn.setblocking(False)
            self.conn, self.peer = conn, peer

    def write(self, packet: bytes) -> bool:
        if self.conn is None:
            return False
        try:
            _, ready, _ = select.select([], [self.conn], [], _WRITE_TIMEOUT_S)
            if not ready:
                return False
            self.conn.sendall(packet)
            return True
        except OSError:
            return False

    def close(self) -> None:
        for sock in (self.conn, self.listener):
            if sock is not None:
                sock.close()
        self.conn = self.listener = None


class _SerialStream:
    def __init__(self, device: str, baud: int):
        import serial               # pyserial: only when a serial link is asked for

        self.label = f"{device},{baud}"
        self.refused = 0
        self.peer = device
        try:
            self.port = serial.Serial(device, baud, timeout=0, write_timeout=_WRITE_TIMEOUT_S)
        except (serial.SerialException, ValueError) as e:
            raise LinkError(f"{self.label}: cannot open ({e})") from None
        self._error = serial.SerialException

    @property
    def local_port(self) -> None:
        return None

    def fileno(self) -> int:
        return self.port.fileno()

    def read(self) -> bytes:
        try:
            return self.port.read(max(self.port.in_waiting, 1))
        except (self._error, OSError):
            return b""

    def write(self, packet: bytes) -> bool:
        try:
            self.port.write(packet)
            return True
        except (self._error, OSError):
            return False

    def close(self) -> None:
        self.port.close()


class StreamLink(MavlinkLink):
    def __init__(self, stream, source_system: int, source_component: int, *, tlog: TlogWriter | None = None,
                 key: bytes | None = None, link_id: int = 0):
        self.stream = stream
        super().__init__(source_system, source_component, tlog, key, link_id)

    @property
    def foreign_datagrams(self) -> int:
        return self.stream.refused

    @property
    def local_port(self):
        return self.stream.local_port

    def fileno(self) -> int:
        return self.stream.fileno()

    def write(self, packet: bytes) -> None:
        """Called by the protocol object with each packed packet."""
        if self.stream.write(bytes(packet)) and self.tlog is not None:
            self.tlog.record(packet)

    def receive_from(self) -> list[tuple[object, list[mavlink.MAVLink_message]]]:
        out = []
        while data := self.stream.read():
            out.append((self.stream.peer, self.parse(data, self.stream.peer)))
        return out

    def lock_peer(self, address, hear_others: bool = False) -> None:
        """A TCP server refuses other connections from now on; a client or serial port has one
        peer (a stream has nobody else to hear)."""
        self.stream.locked = address

    def close(self) -> None:
        self.stream.close()


def open_tcp(mode: str, host: str, port: int, *args, **kwargs) -> StreamLink:
    return StreamLink(_TcpStream(mode, host, port), *args, **kwargs)


def open_serial(device: str, baud: int, *args, **kwargs) -> StreamLink:
    return StreamLink(_SerialStream(device, baud), *args, **kwargs)
