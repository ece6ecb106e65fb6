"""Link delay and loss emulated in simulated time, on the flight controller's side of one link.

`m4-sitl serve --link-delay-ms D --link-loss P` impairs the companion's link (the first
`--mavlink` URL; the others, e.g. a ground station's, are not) without a proxy, so an
impaired flight is as deterministic as any lockstep flight and does not depend on the load
of the machine. With the FC's simulated clock at t:

- every datagram the FC sends on the link is lost with probability P, else sent at once (in
  lockstep the companion cannot tell that from "arrived at t + D"; a lost one is still in the
  FC's tlog: the FC sent it);
- every datagram that arrives from the link is lost with probability P, else held and handed
  to the FC (parsed, routed, handled, in its tlog) at t + 2 D on its clock, in arrival order.
  D covers the way down as well: the answer to the frame of instant t acts at t + 2 D, a
  TIMESYNC request sent with it is answered with tc1 = t + 2 D, so the companion measures a
  setpoint lead of 2 D as it would over a real link. In lockstep a datagram that answers
  frame t (an M4_SETPOINT or M4_FAULT_STATUS first in it, time_boot_ms t) counts as arrived
  at t even when the FC had moved on before it came (lockstep waits for the setpoint only);
  in real time everything counts as arrived when it came (the companion's time counts too).

The delays are on the FC's 1 ms clock (2 D rounded to whole milliseconds). A loss is decided
by a keyed hash of (seed, direction, instant, a message id of the datagram (the last one
going down: a frame's M4_THRUSTER_STATUS; the first one coming up), how many such datagrams
came at that instant before it): a counter-based generator of its own, apart from the
plant's noise, and independent of messages whose number follows the wall clock (heartbeats,
resent commands), so the same seed loses the same frames and setpoints. (When the
companion's commands land still follows the wall clock: it resends them on its own clock.)

For lockstep (sitl/serve.py) the link knows which frames it lost and which instants the
companion has answered (`answered_ms`, on arrival: delivered later or lost), so the FC
neither waits for the answer to a frame it lost nor for a setpoint lost on the way up
(`answered()`). A frame sent again while the FC waits (RESEND_S) and lost does not end the
wait: the first one got through.
"""

from __future__ import annotations

import collections
import hashlib
import heapq
from collections.abc import Callable
from dataclasses import dataclass

from m4.mavlink import mavlink, new_mav
from m4.mavlink.link import UdpLink, drop_cut_frame
from m4.mavlink.signing import setup_signing

DELAY_MAX_MS = 2000.0
SEEN_MAX = 4096                  # draws remembered (to number repeats) before the old ones are let go ...
SEEN_KEEP_MS = 5000              # ... all but the last 5 s of them
HELD_MAX = 10_000                # datagrams held at once (a flood beyond is lost, as by a full queue)
_ANSWERS = (mavlink.MAVLINK_MSG_ID_M4_SETPOINT, mavlink.MAVLINK_MSG_ID_M4_FAULT_STATUS)
_MAVLINK2_STX = 0xFD
_MAVLINK1_STX = 0xFE


class EmulationError(ValueError):
    """A delay or a loss out of range."""


@dataclass(frozen=True)
class LinkEmulation:
    delay_ms: float = 0.0          # each way
    loss: float = 0.0              # probability a datagram is lost, each way

    def __post_init__(self):
        if not 0.0 <= self.delay_ms <= DELAY_MAX_MS:
            raise EmulationError(f"link delay must be within 0..{DELAY_MAX_MS:g} ms, got {self.delay_ms:g}")
        if not 0.0 <= self.loss < 1.0:
            raise EmulationError(f"link loss must be within 0..1 (1 excluded), got {self.loss:g}")

    def describe(self) -> str:
        return f"{self.delay_ms:g} ms each way, loss {self.loss:g}"

    @property
    def round_trip_ms(self) -> int:
        """How long after its arrival a message acts on the FC's clock."""
        return round(2.0 * self.delay_ms)


def flights_note(link: LinkEmulation | None) -> str:
    """The first lines of a batch's summary naming the impaired link ("" when it was not)."""
    return "" if link is None else f"Every flight with the companion's link impaired: {link.describe()} (emulated in lockstep).\n\n"


@dataclass
class EmulationCounters:
    sent: int = 0                  # datagrams the FC sent on the link
    lost_down: int = 0             # ... of them lost
    received: int = 0              # datagrams that arrived from the link
    lost_up: int = 0               # ... of them lost
    setpoints: int = 0             # M4_SETPOINTs from the companion that arrived (held or lost)

    def summary(self) -> str:
        return (f"to the companion {self.lost_down} of {self.sent} datagrams lost, "
                f"from it {self.lost_up} of {self.received}")


def message_id(data: bytes) -> int:
    """The message id of the (first) packet in `data`, from its header (-1: not MAVLink)."""
    if len(data) >= 10 and data[0] == _MAVLINK2_STX:
        return data[7] | data[8] << 8 | data[9] << 16
    if len(data) >= 6 and data[0] == _MAVLINK1_STX:
        return data[5]
    return -1


class LossDraw:
    """Whether a datagram is lost: a keyed hash of (seed, direction, instant, message id, how
    many such datagrams came before it), so the draw depends on what is sent when and not on
    how many other draws came before it."""

    def __init__(self, seed: int, loss: float):
        self.seed = seed
        self.loss = loss
        self._seen: collections.Counter = collections.Counter()

    def lost(self, direction: str, t_ms: int, msg_id: int) -> bool:
        key = (direction, t_ms, msg_id)
        n = self._seen[key]
        self._seen[key] += 1
        if len(self._seen) > SEEN_MAX:
            self._seen = collections.Counter({k: v for k, v in self._seen.items() if k[1] >= t_ms - SEEN_KEEP_MS})
        if self.loss == 0.0:
            return False
        digest = hashlib.blake2b(f"{self.seed}/{direction}/{t_ms}/{msg_id}/{n}".encode(), digest_size=8).digest()
        return int.from_bytes(digest, "little") / 2.0**64 < self.loss


class EmulatedLink(UdpLink):
    """A UdpLink whose wire is delayed and lossy in simulated time; `clock()` is the FC's
    clock in ms. `receive_from()` returns what is due at the current instant;
    `next_delivery_ms()` says when the next held datagram is due."""

    def __init__(self, url: str, source_system: int, source_component: int, *, emulation: LinkEmulation,
                 seed: int, clock: Callable[[], int], lockstep: bool = True, key: bytes | None = None,
                 link_id: int = 0, **kwargs):
        super().__init__(url, source_system, source_component, key=key, link_id=link_id, **kwargs)
        self.emulation = emulation
        self.lockstep = lockstep
        self.clock = clock
        self.counters = EmulationCounters()
        self.answered_ms: int | None = None      # the newest instant an arrived M4_SETPOINT answers
        self._frame_sent_ms: int | None = None   # the newest instant whose M4_THRUSTER_STATUS got through
        self._frame_lost_ms: int | None = None   # ... was lost
        self._draw = LossDraw(seed, emulation.loss)
        self._held: list[tuple[int, int, bytes, tuple[str, int]]] = []     # heap: (due, arrival count, datagram, sender)
        self._reader = new_mav(None, source_system, source_component)    # reads arrivals (the link parses them later)
        if key is not None:
            setup_signing(self._reader, key, link_id)

    # -- down: the FC's datagrams ----------------------------------------------------------------
    def send_datagram(self, packets: list[bytes]) -> None:
        if self.peer is None:
            return
        now_ms = self.clock()
        self.counters.sent += 1
        lost = self._draw.lost("down", now_ms, message_id(packets[-1]))       # a frame: its M4_THRUSTER_STATUS
        if any(message_id(p) == mavlink.MAVLINK_MSG_ID_M4_THRUSTER_STATUS for p in packets):
            if lost:
                self._frame_lost_ms = now_ms
            else:
                self._frame_sent_ms = now_ms
        if not lost:
            super().send_datagram(packets)
            return
        self.counters.lost_down += 1
        if self.tlog is not None:
            self.tlog.record_all(packets)

    # -- up: what arrives --------------------------------------------------------------------------
    def receive_from(self, max_datagrams: int | None = None
                     ) -> list[tuple[tuple[str, int], list[mavlink.MAVLink_message]]]:
        """Read what has arrived (at most `max_datagrams`), hold it or lose it; then hand over
        what is due now."""
        now_ms, read = self.clock(), 0
        while max_datagrams is None or read < max_datagrams:
            datagram = self.read_datagram()
            if datagram is None:
                break
            read += 1
            self._arrived(now_ms, *datagram)
        return self.deliver()

    def _arrived(self, now_ms: int, data: bytes, sender: tuple[str, int]) -> None:
        """Lose or hold one datagram. In lockstep the answer to frame t (the setpoint, or an
        M4_FAULT_STATUS in a datagram of its own, which may come in after the FC has moved on)
        is drawn and held by its instant t; anything else by the instant it came."""
        self.counters.received += 1
        msgs = [m for m in self._reader.parse_buffer(data) or () if m.get_type() != "BAD_DATA"]
        drop_cut_frame(self._reader)
        at_ms = now_ms
        if self.lockstep and msgs and msgs[0].get_msgId() in _ANSWERS and self.peer_filter(msgs[0]):
            at_ms = min(int(msgs[0].time_boot_ms), now_ms)
        for msg in msgs:
            if msg.get_msgId() == mavlink.MAVLINK_MSG_ID_M4_SETPOINT and self.peer_filter(msg):
                self.answered_ms = max(self.answered_ms or 0, int(msg.time_boot_ms))
                self.counters.setpoints += 1
        if self._draw.lost("up", at_ms, msgs[0].get_msgId() if msgs else -1) or len(self._held) >= HELD_MAX:
            self.counters.lost_up += 1
            return
        due_ms = max(now_ms, at_ms + self.emulation.round_trip_ms)
        heapq.heappush(self._held, (due_ms, self.counters.received, data, sender))

    def next_delivery_ms(self) -> int | None:
        return self._held[0][0] if self._held else None

    def deliver(self) -> list[tuple[tuple[str, int], list[mavlink.MAVLink_message]]]:
        """The held datagrams due at the current instant, parsed (into the tlog), in order of due
        instant, then of arrival."""
        now_ms = self.clock()
        out = []
        while self._held and self._held[0][0] <= now_ms:
            _, _, data, sender = heapq.heappop(self._held)
            out.append((sender, self.ingest(data, sender)))
        return out

    def answered(self, t_ms: int) -> bool:
        """Lockstep: nothing more to wait for at instant t_ms: the companion's answer arrived
        (held or lost), or the frame it would answer was lost."""
        frame_lost = self._frame_lost_ms == t_ms and self._frame_sent_ms != t_ms
        return frame_lost or (self.answered_ms is not None and self.answered_ms >= t_ms)
