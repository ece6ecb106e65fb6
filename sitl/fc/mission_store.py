"""The flight controller's mission and its side of the MAVLink mission protocol, without sockets.

The FC keeps one mission (MAV_MISSION_TYPE_MISSION; fences and rally points it has none of)
and serves it; its companion downloads and flies it (docs/missions.md). Item 0 is always the
FC's fixed home (ArduPilot's convention: an uploaded item 0 is taken in its place).

- Upload: MISSION_COUNT -> MISSION_REQUEST_INT for each seq in turn -> MISSION_ITEM_INT -> ...
  -> MISSION_ACK ACCEPTED. Each item is checked as it comes (m4.mission_items.check_item): a
  refused one ends the upload with its MISSION_ACK error and the mission kept before stays. An
  item of another seq is answered by asking again for the one expected; without an item for
  TIMEOUT_MS the request is sent again, RETRIES times, then the upload is cancelled
  (MAV_MISSION_OPERATION_CANCELLED). A second ground station's MISSION_COUNT during an upload
  is DENIED; more than MAX_ITEMS items, MAV_MISSION_NO_SPACE. MISSION_COUNT 0 clears.
- Download: MISSION_REQUEST_LIST -> MISSION_COUNT (home included) -> MISSION_REQUEST_INT ->
  MISSION_ITEM_INT; served without state, so the downloader's retries are all it takes.
- MISSION_CLEAR_ALL: the mission is gone, MISSION_ACK ACCEPTED.
- Progress: a new mission is NOT_STARTED; the companion says which item it flies with
  MISSION_SET_CURRENT (it flies the mission, so it knows): the mission is ACTIVE, the FC sends
  MISSION_ITEM_REACHED for the navigation item it leaves (not for items skipped: DO items, or a
  jump) and MISSION_CURRENT. A waypoint a fault hold cut short counts as left when the landing
  starts. When the FC lands
  (disarms) while the current item is NAV_LAND, that item is reached and the mission COMPLETE.
  From anyone else MISSION_SET_CURRENT only brings MISSION_CURRENT back: a jump is not flown.
- MISSION_CURRENT goes out on every change and as a stream (sitl/fc/streams.py); its `total`
  excludes home (UINT16_MAX: no mission), as the message's definition asks.
Every reply is addressed to the sender; a message for another mission type is answered with
MAV_MISSION_UNSUPPORTED (a list request for one with MISSION_COUNT 0).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

from m4.home import Home
from m4.mavlink import mavlink
from m4.mission_items import MissionItem, check_item, home_item

m = mavlink
TIMEOUT_MS = 1500                 # the mission protocol's default timeout ...
RETRIES = 5                       # ... and retries
NO_MISSION_TOTAL = 0xFFFF
MAX_ITEMS = 500                   # home included; more: MAV_MISSION_NO_SPACE
_NAV = (m.MAV_CMD_NAV_WAYPOINT, m.MAV_CMD_NAV_LAND)
MISSION_IDS = frozenset({m.MAVLINK_MSG_ID_MISSION_COUNT, m.MAVLINK_MSG_ID_MISSION_ITEM_INT,
                         m.MAVLINK_MSG_ID_MISSION_REQUEST_LIST, m.MAVLINK_MSG_ID_MISSION_REQUEST_INT,
                         m.MAVLINK_MSG_ID_MISSION_CLEAR_ALL, m.MAVLINK_MSG_ID_MISSION_SET_CURRENT,
                         m.MAVLINK_MSG_ID_MISSION_ACK})


@dataclass
class _Upload:
    partner: tuple[int, int]
    count: int
    items: list[MissionItem] = field(default_factory=list)
    requested_ms: int = 0
    retries: int = 0


def _sender(msg) -> tuple[int, int]:
    return msg.get_srcSystem(), msg.get_srcComponent()


class MissionStore:
    def __init__(self, home: Home, log: Callable[[str], None] = lambda text: None):
        self.home = home
        self.log = log
        self.items: tuple[MissionItem, ...] = (home_item(home),)
        self.current = 0
        self.state = m.MISSION_STATE_NO_MISSION
        self._upload: _Upload | None = None

    # -- messages in -----------------------------------------------------------------------------
    def handle(self, msg, now_ms: int, from_companion: bool) -> list[m.MAVLink_message]:
        """The replies to one mission message addressed to the FC."""
        msg_id = msg.get_msgId()
        if msg_id == m.MAVLINK_MSG_ID_MISSION_SET_CURRENT:
            return self._set_current(msg.seq) if from_companion else [self.current_message()]
        if msg_id == m.MAVLINK_MSG_ID_MISSION_ACK:
            return []                                   # a downloader's end: nothing to do
        if msg.mission_type != m.MAV_MISSION_TYPE_MISSION:
            if msg_id == m.MAVLINK_MSG_ID_MISSION_REQUEST_LIST:
                return [m.MAVLink_mission_count_message(*_sender(msg), 0, msg.mission_type)]
            if msg_id == m.MAVLINK_MSG_ID_MISSION_CLEAR_ALL and msg.mission_type == m.MAV_MISSION_TYPE_ALL:
                return self._clear(msg)
            return [self._ack(_sender(msg), m.MAV_MISSION_UNSUPPORTED, msg.mission_type)]
        if msg_id == m.MAVLINK_MSG_ID_MISSION_COUNT:
            return self._on_count(msg, now_ms)
        if msg_id == m.MAVLINK_MSG_ID_MISSION_ITEM_INT:
            return self._on_item(msg, now_ms)
        if msg_id == m.MAVLINK_MSG_ID_MISSION_REQUEST_LIST:
            return [m.MAVLink_mission_count_message(*_sender(msg), len(self.items), m.MAV_MISSION_TYPE_MISSION)]
        if msg_id == m.MAVLINK_MSG_ID_MISSION_REQUEST_INT:
            if not 0 <= msg.seq < len(self.items):
                return [self._ack(_sender(msg), m.MAV_MISSION_INVALID_SEQUENCE)]
            return [self.items[msg.seq].message(*_sender(msg))]
        return self._clear(msg)                         # MISSION_CLEAR_ALL

    def _on_count(self, msg, now_ms: int) -> list[m.MAVLink_message]:
        partner = _sender(msg)
        if self._upload is not None and self._upload.partner != partner:
            return [self._ack(partner, m.MAV_MISSION_DENIED)]
        if msg.count == 0:
            self._upload = None
            return self._clear(msg)
        if msg.count > MAX_ITEMS:
            self.log(f"mission upload from {partner[0]}/{partner[1]} refused: {msg.count} items, at most {MAX_ITEMS}")
            return [self._ack(partner, m.MAV_MISSION_NO_SPACE)]
        self._upload = _Upload(partner, msg.count, requested_ms=now_ms)
        return [self._request(self._upload)]

    def _on_item(self, msg, now_ms: int) -> list[m.MAVLink_message]:
        up = self._upload
        if up is None or _sender(msg) != up.partner:
            return []
        if msg.seq != len(up.items):
            return [self._request(up)]
        item = MissionItem.from_message(msg)
        refused = check_item(item, up.items, self.home)
        if refused is not None:
            self._upload = None
            self.log(f"mission upload from {up.partner[0]}/{up.partner[1]} refused: {refused.text}")
            return [self._ack(up.partner, refused.result)]
        up.items.append(home_item(self.home) if item.seq == 0 else item)
        if len(up.items) < up.count:
            up.requested_ms, up.retries = now_ms, 0
            return [self._request(up)]
        self._upload = None
        self.items = tuple(up.items)
        started = len(self.items) > 1
        self.current, self.state = (1, m.MISSION_STATE_NOT_STARTED) if started else (0, m.MISSION_STATE_NO_MISSION)
        self.log(f"mission of {len(self.items) - 1} item(s) uploaded by {up.partner[0]}/{up.partner[1]}")
        return [self._ack(up.partner, m.MAV_MISSION_ACCEPTED), self.current_message()]

    def _clear(self, msg) -> list[m.MAVLink_message]:
        self.items, self.current, self.state = (home_item(self.home),), 0, m.MISSION_STATE_NO_MISSION
        return [self._ack(_sender(msg), m.MAV_MISSION_ACCEPTED, msg.mission_type), self.current_message()]

    def _set_current(self, seq: int) -> list[m.MAVLink_message]:
        if not 1 <= seq < len(self.items) or seq < self.current:
            return [self.current_message()]
        passed = self.current if seq > self.current and self.items[self.current].command in _NAV else None
        out = [] if passed is None else [m.MAVLink_mission_item_reached_message(passed)]
        self.current, self.state = seq, m.MISSION_STATE_ACTIVE
        return [*out, self.current_message()]

    def landed(self) -> list[m.MAVLink_message]:
        """The FC landed (disarmed): the NAV_LAND being flown is reached, the mission complete."""
        if self.state != m.MISSION_STATE_ACTIVE or self.items[self.current].command != m.MAV_CMD_NAV_LAND:
            return []
        self.state = m.MISSION_STATE_COMPLETE
        return [m.MAVLink_mission_item_reached_message(self.current), self.current_message()]

    # -- time --------------------------------------------------------------------------------------
    def tick(self, now_ms: int) -> list[m.MAVLink_message]:
        """The upload's request again after TIMEOUT_MS; cancelled after RETRIES."""
        up = self._upload
        if up is None or now_ms - up.requested_ms < TIMEOUT_MS:
            return []
        if up.retries >= RETRIES:
            self._upload = None
            self.log(f"mission upload from {up.partner[0]}/{up.partner[1]} cancelled: item {len(up.items)} "
                     f"never came")
            return [self._ack(up.partner, m.MAV_MISSION_OPERATION_CANCELLED)]
        up.requested_ms, up.retries = now_ms, up.retries + 1
        return [self._request(up)]

    # -- messages out ------------------------------------------------------------------------------
    def current_message(self) -> m.MAVLink_mission_current_message:
        total = NO_MISSION_TOTAL if len(self.items) < 2 else len(self.items) - 1
        mode = 1 if self.state == m.MISSION_STATE_ACTIVE else 0         # 1: flying the mission
        return m.MAVLink_mission_current_message(self.current, total, self.state, mode)

    @staticmethod
    def _request(up: _Upload) -> m.MAVLink_mission_request_int_message:
        return m.MAVLink_mission_request_int_message(*up.partner, len(up.items), m.MAV_MISSION_TYPE_MISSION)

    @staticmethod
    def _ack(to: tuple[int, int], result: int, mission_type: int = m.MAV_MISSION_TYPE_MISSION):
        return m.MAVLink_mission_ack_message(*to, result, mission_type)
