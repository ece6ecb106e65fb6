"""The MAVLink parameter protocol over a component's ParamTable (m4/params.py), without sockets.

As an ArduPilot autopilot answers it (https://mavlink.io/en/services/parameter.html):
- PARAM_REQUEST_LIST: every parameter as PARAM_VALUE, in index order, each with
  param_count and param_index;
- PARAM_REQUEST_READ: the one named (param_index -1) or at param_index;
- PARAM_SET: applied when the table takes it, kept in the ParamFile (when there is one), and
  answered with PARAM_VALUE holding the value in force: the new one, or the unchanged one on a
  refusal, which a STATUSTEXT WARNING explains ("FC: FS_SP_TIMEOUT refused: out of range
  [0.1, 1]"). A value that could not be written to the file stays in force for this run, and a
  STATUSTEXT WARNING says it was not kept.
PARAM_VALUE is a broadcast (no target): every ground station sees it. Values go out cast to
float (ArduPilot's encoding: MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST), whatever their type.
A request for component 0 (every component of the system) is answered too, but a name this
component does not have is then left to the others in silence; addressed to this component,
it is refused.

`handle(msg)` returns the replies to send, or None when the message is no parameter message
for this component: the caller says who may send one (authority is not decided here).
"""

from __future__ import annotations

from collections.abc import Callable

from m4.mavlink.dialect import mavlink
from m4.params import ParamTable, Refusal
from m4.params_file import ParamFile

m = mavlink
PARAM_IDS = frozenset({m.MAVLINK_MSG_ID_PARAM_REQUEST_LIST, m.MAVLINK_MSG_ID_PARAM_REQUEST_READ,
                       m.MAVLINK_MSG_ID_PARAM_SET})
STATUSTEXT_MAX = 50


class ParamService:
    def __init__(self, table: ParamTable, system: int, component: int, label: str, file: ParamFile | None = None,
                 log: Callable[[str], None] = lambda text: None):
        """label: how the STATUSTEXTs begin ("FC", "companion"); file: where sets are kept
        (None: for this run only); log: one line per set and refusal."""
        self.table = table
        self.ids = (system, component)
        self.label = label
        self.file = file
        self.log = log
        self.sets = 0
        self.refused = 0

    def addressed_to_me(self, msg) -> bool:
        return msg.target_system in (0, self.ids[0]) and msg.target_component in (0, self.ids[1])

    def handle(self, msg) -> list[m.MAVLink_message] | None:
        msg_id = msg.get_msgId()
        if msg_id not in PARAM_IDS or not self.addressed_to_me(msg):
            return None
        if msg_id == m.MAVLINK_MSG_ID_PARAM_REQUEST_LIST:
            return [self.param_value(i) for i in range(len(self.table))]
        if msg_id == m.MAVLINK_MSG_ID_PARAM_REQUEST_READ:
            i = self.table.index(msg.param_id) if msg.param_index < 0 else msg.param_index
            if i is None or not 0 <= i < len(self.table):
                return self._unknown(msg, msg.param_id if msg.param_index < 0 else f"index {msg.param_index}")
            return [self.param_value(i)]
        return self._set(msg)

    def param_value(self, i: int) -> m.MAVLink_param_value_message:
        p = self.table.params[i]
        return m.MAVLink_param_value_message(p.name.encode("ascii"), self.table.value(p), int(p.type),
                                             len(self.table), i)

    def _set(self, msg) -> list[m.MAVLink_message]:
        i = self.table.index(msg.param_id)
        if i is None:
            return self._unknown(msg, msg.param_id)
        p = self.table.params[i]
        refusal = (Refusal(p.name, f"wrong type (MAV_PARAM_TYPE {msg.param_type})")
                   if msg.param_type not in _CARRIED_TYPES else self.table.set(p.name, msg.param_value))
        if refusal is not None:
            self.refused += 1
            why = f" ({p.read_only_why})" if refusal.reason == "read-only" and p.read_only_why else ""
            self.log(f"PARAM_SET {p.name} = {msg.param_value:g} from {msg.get_srcSystem()}/{msg.get_srcComponent()} "
                     f"refused: {refusal.reason}{why}")
            return [self.param_value(i), self.statustext(m.MAV_SEVERITY_WARNING, refusal.text)]
        self.sets += 1
        value = self.table.value(p)
        kept = int(value) if p.type.whole else value
        self.log(f"{p.name} set to {kept:g} by {msg.get_srcSystem()}/{msg.get_srcComponent()}")
        replies = [self.param_value(i)]
        if self.file is not None and (error := self.file.record(p.name, kept)) is not None:
            self.log(f"{p.name} is in force but not kept: {error}")
            replies.append(self.statustext(m.MAV_SEVERITY_WARNING, f"{p.name} set, not saved"))
        return replies

    def _unknown(self, msg, what: str) -> list[m.MAVLink_message]:
        """A name or index this component does not have: refused when addressed to it alone."""
        if msg.target_component == 0:
            return []
        self.refused += 1
        return [self.statustext(m.MAV_SEVERITY_WARNING, f"{what}: no such parameter")]

    def statustext(self, severity: int, text: str) -> m.MAVLink_statustext_message:
        text = f"{self.label}: {text}".encode("ascii", "replace")[:STATUSTEXT_MAX]
        return m.MAVLink_statustext_message(severity, text)


_CARRIED_TYPES = frozenset({m.MAV_PARAM_TYPE_UINT8, m.MAV_PARAM_TYPE_INT8, m.MAV_PARAM_TYPE_UINT16,
                            m.MAV_PARAM_TYPE_INT16, m.MAV_PARAM_TYPE_UINT32, m.MAV_PARAM_TYPE_INT32,
                            m.MAV_PARAM_TYPE_REAL32})
