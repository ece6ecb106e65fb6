"""A second sender claiming a paired identity: counted and reported, the same way at both ends.

The flight controller knows its companion (system 1, component 191) and the companion its flight
controller (1/1), and where each speaks from. Anyone else using that identity is an attacker
(a spoof from another UDP port, a replay of captured signed packets) or a mistake (a second
companion running, a flight controller without the key); either way the operator must hear of
it. `SecondSender` counts every such packet and reports, in one log line and one STATUSTEXT
WARNING, at most once per REPORT_PERIOD_S (the log line says how many were held back).

What counts is the receiver's to say; both ends count
- a packet claiming the identity that signing refused: unsigned, badly signed, or replayed (a
  good signature on a timestamp not newer than its stream's; m4.mavlink.signing.refusal);
- one claiming it from another place than the paired one while that one is live: the
  companion knows its flight controller's address (it locks on to it); for a receiver without
  a lock of its own (the simulated FC), `PairedPlace` keeps the place, a link and an address.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Hashable
from typing import Any

from m4.log_limit import RepeatLimiter

REPORT_PERIOD_S = 10.0
LIVE_S = 1.0                 # the paired place, silent this long, may be taken over (a restarted peer)
OTHER_ADDRESS = "other address"


def address_text(sender: Any) -> str:
    """A sender as people write it: HOST:PORT for a UDP or TCP peer, else as it is (a serial device)."""
    if isinstance(sender, tuple) and len(sender) == 2:
        return f"{sender[0]}:{sender[1]}"
    return str(sender)


class SecondSender:
    """Reports packets claiming `identity` (system, component), `claimed` in words ("the
    companion"), that are not from it: `log(line)` and `status(text)` (a STATUSTEXT WARNING of
    at most 50 characters, beginning with `prefix`)."""

    def __init__(self, claimed: str, identity: tuple[int, int], prefix: str, log: Callable[[str], None],
                 status: Callable[[str], None], clock: Callable[[], float] = time.monotonic):
        self.claimed = claimed
        self.identity = identity
        self.prefix = prefix
        self.count = 0
        self._log = log
        self._status = status
        self._limiter = RepeatLimiter(REPORT_PERIOD_S, clock)

    def __call__(self, where: str, why: str, detail: str = "") -> None:
        """One packet from `where` claiming the identity: `why` in a word or two ("replayed",
        OTHER_ADDRESS), `detail` for the log line only."""
        self.count += 1
        held = self._limiter.admit(self.identity)
        if held is None:
            return
        system, component = self.identity
        more = f"; {held} more since the last report" if held else ""
        self._log(f"a second sender claims to be {self.claimed} {system}/{component}, from {where}: {why}"
                  f"{f' ({detail})' if detail else ''}{more}; {self.count} so far")
        self._status(f"{self.prefix}: second sender as {system}/{component} ({why})")


class PairedPlace:
    """Where the paired identity speaks from: the first place heard, kept while it is live
    (heard within LIVE_S); after that long a place heard takes over (a restarted peer)."""

    def __init__(self, clock: Callable[[], float] = time.monotonic):
        self.place: Hashable | None = None
        self._heard_s = 0.0
        self._clock = clock

    def other(self, place: Hashable) -> bool:
        """`place` was heard claiming the identity: True when it is not the paired place and that
        one is live (a second sender), else it is (now) the paired place."""
        now = self._clock()
        if self.place is not None and place != self.place and now - self._heard_s < LIVE_S:
            return True
        self.place, self._heard_s = place, now
        return False
