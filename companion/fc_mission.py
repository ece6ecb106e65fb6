"""The flight controller's mission on the companion's side: downloaded when it changes, turned
into the mission flown, its progress reported (docs/missions.md).

Only without a mission file (`--mission`, or the configuration's `mission_file`, which take
precedence): then a mission a ground station uploaded to the FC is what the companion flies.

- Download (`MissionDownload`, the mission protocol's downloader without sockets):
  MISSION_REQUEST_LIST -> MISSION_COUNT -> MISSION_REQUEST_INT per seq -> MISSION_ITEM_INT ->
  MISSION_ACK ACCEPTED; a request unanswered for TIMEOUT_S is sent again, RETRIES times, then
  the download fails (said in the log; the mission flown stays). Replies for others (a ground
  station's upload goes past on the same link) are not ours and are left alone.
- When: at lock-on, and whenever the FC's MISSION_CURRENT says NOT_STARTED (a mission nobody
  flies yet: one just uploaded). pymavlink's common.xml (2.4.50) has no MISSION_CURRENT.mission_id
  nor opaque_id, so the mission's state says what changed. Items in a global frame need the FC's
  home: HOME_POSITION is asked for (MAV_CMD_REQUEST_MESSAGE) when they come. Until the first
  download has ended (home included), for FIRST_WAIT_S at most, the companion sends no
  setpoint: it starts on the FC's mission (and a restarted companion resumes it where the FC
  kept its progress), not on a hold it would leave a moment later.
- What is flown: `m4.mission_items.to_mission`, with the fault policy `on_fault` from the
  configuration (`fc_mission_on_fault`). The same items downloaded again change nothing; other
  items become the mission flown from where the robot is (`Controller.fly`).
- Progress: the companion flies the mission, so it knows where it is: it says which item it
  flies with MISSION_SET_CURRENT, each time that changes; the FC reports it (MISSION_CURRENT,
  MISSION_ITEM_REACHED) as an autopilot does.
"""

from __future__ import annotations

import logging

from m4.home import Home
from m4.mavlink import mavlink
from m4.mission_items import GLOBAL_FRAMES, FlownMission, MissionItem, to_mission

from companion.fc_commands import Command
from companion.fc_link import KEPT_STATE_RETRY_S, FcLink

m = mavlink
TIMEOUT_S = 1.5                   # the mission protocol's default timeout ...
RETRIES = 5                       # ... and retries
# The first setpoint waits for the first download at most this long (wall clock), as it waits
# for what the FC kept (companion.fc_link: 5 requests 0.2 s apart): a lockstep FC behind an
# emulated delay holds our requests until its clock moves, and it moves only with a setpoint.
FIRST_WAIT_S = 1.0
log = logging.getLogger("m4-companion")


class MissionDownload:
    """One download of the FC's mission; `outbox` holds what to send."""

    def __init__(self, own_ids: tuple[int, int], fc_ids: tuple[int, int], now_s: float):
        self.own_ids, self.fc_ids = own_ids, fc_ids
        self.count: int | None = None
        self.items: list[MissionItem] = []
        self.failed: str | None = None            # why it failed
        self.home_asked_s: float | None = None     # its items need the FC's home: when it was asked for
        self.home_asks = 0
        self.outbox: list[m.MAVLink_message] = []
        self._sent_s, self._retries = now_s, 0
        self._send(now_s)

    @property
    def done(self) -> bool:
        return self.count is not None and len(self.items) == self.count

    def _for_us(self, msg) -> bool:
        return (msg.target_system, msg.target_component) == self.own_ids \
            and msg.mission_type == m.MAV_MISSION_TYPE_MISSION

    def _send(self, now_s: float) -> None:
        self._sent_s = now_s
        if self.count is None:
            self.outbox.append(m.MAVLink_mission_request_list_message(*self.fc_ids, m.MAV_MISSION_TYPE_MISSION))
        else:
            self.outbox.append(m.MAVLink_mission_request_int_message(*self.fc_ids, len(self.items),
                                                                     m.MAV_MISSION_TYPE_MISSION))

    def on_message(self, msg, now_s: float) -> None:
        msg_id = msg.get_msgId()
        if self.done or self.failed or msg_id not in _REPLIES or not self._for_us(msg):
            return
        if msg_id == m.MAVLINK_MSG_ID_MISSION_ACK:
            self.failed = f"the flight controller answered MISSION_ACK {msg.type}"
            return
        if msg_id == m.MAVLINK_MSG_ID_MISSION_COUNT and self.count is None:
            self.count = msg.count
        elif msg_id == m.MAVLINK_MSG_ID_MISSION_ITEM_INT and self.count is not None and msg.seq == len(self.items):
            self.items.append(MissionItem.from_message(msg))
        else:
            return
        self._retries = 0
        if self.done:
            self.outbox.append(m.MAVLink_mission_ack_message(*self.fc_ids, m.MAV_MISSION_ACCEPTED,
                                                             m.MAV_MISSION_TYPE_MISSION))
        else:
            self._send(now_s)

    def tick(self, now_s: float) -> None:
        if self.done or self.failed or now_s - self._sent_s < TIMEOUT_S:
            return
        if self._retries >= RETRIES:
            self.failed = f"no answer to {RETRIES + 1} requests"
            return
        self._retries += 1
        self._send(now_s)


_REPLIES = frozenset({m.MAVLINK_MSG_ID_MISSION_COUNT, m.MAVLINK_MSG_ID_MISSION_ITEM_INT, m.MAVLINK_MSG_ID_MISSION_ACK})
# What `FcMission.on_message` reads: it may be handed these alone (another message changes nothing
# it keeps, and what `tick` does with the time, in the same poll, is done there).
MISSION_MESSAGES = _REPLIES | {m.MAVLINK_MSG_ID_HOME_POSITION, m.MAVLINK_MSG_ID_MISSION_CURRENT}
_HOME_REQUEST = Command(m.MAV_CMD_REQUEST_MESSAGE, (float(m.MAVLINK_MSG_ID_HOME_POSITION),), KEPT_STATE_RETRY_S)


class FcMission:
    """The FC's mission as the companion flies it: `on_message` returns a mission to fly (new
    items), `report` tells the FC the item flown."""

    def __init__(self, fc: FcLink, own_ids: tuple[int, int], on_fault: str):
        self.fc, self.own_ids, self.on_fault = fc, own_ids, on_fault
        self.download: MissionDownload | None = None
        self.home: Home | None = None
        self.flown: FlownMission | None = None
        self._items: tuple[MissionItem, ...] | None = None     # what `flown` was made of
        self._first_until_s: float | None = None               # the first setpoint waits for the download till then
        self._reported: int | None = None

    def on_locked(self, now_s: float) -> None:
        self._first_until_s = now_s + FIRST_WAIT_S
        self.home = None
        self._start(now_s)

    def pending(self, now_s: float) -> bool:
        """The first download since lock-on (and the home its items need) is still awaited, and
        for less than FIRST_WAIT_S."""
        return self.download is not None and self._first_until_s is not None and now_s < self._first_until_s

    def _start(self, now_s: float) -> None:
        self.download = MissionDownload(self.own_ids, self.fc.fc_ids, now_s)
        self._flush()

    def _flush(self) -> None:
        if self.download is not None and self.download.outbox:
            self.fc.link.send_all(self.download.outbox)
            self.download.outbox = []

    def on_message(self, msg, now_s: float) -> FlownMission | None:
        """A message from the FC; the mission to fly when it brings new items (and the home)."""
        msg_id = msg.get_msgId()
        if msg_id == m.MAVLINK_MSG_ID_HOME_POSITION:
            self.home = Home(msg.latitude / 1e7, msg.longitude / 1e7, msg.altitude / 1000.0)
        elif msg_id == m.MAVLINK_MSG_ID_MISSION_CURRENT:
            if msg.mission_state == m.MISSION_STATE_NOT_STARTED and self.download is None:
                self._start(now_s)
        elif self.download is not None:
            self.download.on_message(msg, now_s)
            self._flush()
        return self._finish(now_s)

    def tick(self, now_s: float) -> FlownMission | None:
        """Retries; the mission to fly when the last answer (the home) came earlier."""
        if self.download is not None:
            self.download.tick(now_s)
            self._flush()
        return self._finish(now_s)

    def _ask_home(self, d: MissionDownload, now_s: float) -> bool:
        """Ask for HOME_POSITION (again after TIMEOUT_S: an answer to another request may have
        been taken for its ack); True once RETRIES more requests went unanswered."""
        if d.home_asked_s is not None and (self.fc.commands.waiting(*_HOME_REQUEST.key)
                                           or now_s - d.home_asked_s < TIMEOUT_S):
            return False
        if d.home_asks > RETRIES:
            return True
        d.home_asked_s, d.home_asks = now_s, d.home_asks + 1
        self.fc.commands.replace([_HOME_REQUEST])
        return False

    def _finish(self, now_s: float) -> FlownMission | None:
        d = self.download
        if d is None or not (d.done or d.failed):
            return None
        if d.failed:
            log.error("the flight controller's mission could not be downloaded: %s; flying on as before", d.failed)
            self.download, self._first_until_s = None, None
            return None
        if self.home is None and any(item.frame in GLOBAL_FRAMES for item in d.items[1:]):
            if not self._ask_home(d, now_s):
                return None
            log.error("the flight controller sent no HOME_POSITION: its mission cannot be placed; flying on as before")
            self.download, self._first_until_s = None, None
            return None
        self.download, self._first_until_s = None, None
        items = tuple(d.items)
        if items == self._items:
            self._report_again()
            return None
        self._items, self._reported = items, None
        if len(items) < 2:
            log.info("the flight controller has no mission")
            self.flown = None
            return None
        try:
            self.flown = to_mission(items, self.home, self.on_fault)
        except ValueError as e:
            log.error("the flight controller's mission cannot be flown: %s; flying on as before", e)
            self.flown = None
            return None
        log.info("flying the flight controller's mission: %d item(s), %d waypoint(s)%s, on a fault: %s",
                 len(items) - 1, len(self.flown.mission.waypoints), ", then land" if self.flown.mission.land else "",
                 self.on_fault)
        return self.flown

    def _report_again(self) -> None:
        """The FC says its mission is not started, but it is ours: say again where we are."""
        if self._reported is not None:
            seq, self._reported = self._reported, None
            self.report_seq(seq)

    def report(self, item: int) -> None:
        """The mission's item `item` (m4.mission_plan.MissionPlan.item) is flown now."""
        if self.flown is None:
            return
        seqs = self.flown.seqs
        self.report_seq(seqs[min(item, len(seqs) - 1)] if seqs else 1)

    def report_seq(self, seq: int) -> None:
        if seq != self._reported:
            self._reported = seq
            self.fc.link.send(m.MAVLink_mission_set_current_message(*self.fc.fc_ids, seq))
