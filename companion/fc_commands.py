"""Commands to the flight controller, one at a time, each resent until it is acknowledged.

A COMMAND_LONG goes out, and again every COMMAND_RETRY_S (or the command's own retry_s; its
confirmation field counting the attempts) until the COMMAND_ACK for that command comes back
from the target to us, whatever its result (DENIED and FAILED are answers too); after
COMMAND_ATTEMPTS unanswered sends it is given up and the next one goes. `waiting(command,
param1)` says whether one is still to be answered. Pure logic: the caller sends what `next_message(now_s)` gives.
"""

from __future__ import annotations

from dataclasses import dataclass

from m4.mavlink import mavlink

COMMAND_RETRY_S = 0.5
COMMAND_ATTEMPTS = 5


@dataclass(frozen=True)
class Command:
    command: int                          # MAV_CMD_*
    params: tuple[float, ...]             # param1.. (the rest 0)
    retry_s: float = COMMAND_RETRY_S

    @property
    def key(self) -> tuple[int, float]:
        """Commands with the same key ask the same thing (e.g. one message's interval)."""
        return self.command, self.params[0]


class CommandQueue:
    def __init__(self, target: tuple[int, int], own: tuple[int, int]):
        self._target, self._own = target, own
        self._pending: list[Command] = []
        self._sent_at_s: float | None = None
        self._attempts = 0
        self.acked = 0
        self.given_up = 0

    @property
    def pending(self) -> int:
        return len(self._pending)

    def replace(self, commands: list[Command]) -> None:
        """Drop every pending command that asks what one of `commands` asks (the head too: it
        is sent afresh) and queue `commands`."""
        keys = {c.key for c in commands}
        if self._pending and self._pending[0].key in keys:
            self._restart_head()
        self._pending = [c for c in self._pending if c.key not in keys] + commands

    def waiting(self, command: int, param1: float) -> bool:
        """Is a command asking this still pending (not yet answered nor given up)?"""
        return any(c.key == (command, param1) for c in self._pending)

    def answers(self, msg) -> bool:
        """Is this COMMAND_ACK the answer to the command sent? Its command, from the target, to
        us (a target of 0: a sender that does not fill it in), as ArduPilot and MAVSDK match an
        ack: the FC answers a ground station's command of the same number as well."""
        if not self._pending or self._sent_at_s is None or msg.command != self._pending[0].command:
            return False
        return ((msg.get_srcSystem(), msg.get_srcComponent()) == self._target
                and msg.target_system in (0, self._own[0]) and msg.target_component in (0, self._own[1]))

    def on_ack(self, msg) -> None:
        if self.answers(msg):
            self._pending.pop(0)
            self._restart_head()
            self.acked += 1

    def next_due_s(self, now_s: float) -> float:
        if not self._pending:
            return float("inf")
        return now_s if self._sent_at_s is None else self._sent_at_s + self._pending[0].retry_s

    def next_message(self, now_s: float) -> mavlink.MAVLink_command_long_message | None:
        """The COMMAND_LONG to send now (None: nothing due)."""
        if not self._pending or now_s < self.next_due_s(now_s):
            return None
        if self._attempts >= COMMAND_ATTEMPTS:
            self._pending.pop(0)              # the FC does not answer this one: go on with the others
            self._restart_head()
            self.given_up += 1
            if not self._pending:
                return None
        c = self._pending[0]
        params = (list(c.params) + [0.0] * 7)[:7]
        self._sent_at_s = now_s
        self._attempts += 1
        return mavlink.MAVLink_command_long_message(*self._target, c.command, self._attempts - 1, *params)

    def _restart_head(self) -> None:
        self._sent_at_s = None
        self._attempts = 0
