"""The companion's side of the FC's mission without sockets: the download against the SITL's
mission store over a lossy exchange, the mission made of it, and the progress it reports."""

from __future__ import annotations

from types import SimpleNamespace

from companion.fc_commands import CommandQueue
from companion.fc_mission import FIRST_WAIT_S, RETRIES, TIMEOUT_S, FcMission, MissionDownload
from m4.mavlink import COMPANION_COMPONENT_ID, FC_COMPONENT_ID, FC_SYSTEM_ID, mavlink
from sitl.fc.mission_store import MissionStore
from support.fc_answers import ack
from support.missions import GCS, HOME, MISSION, global_item, sent_by, upload

m = mavlink
OWN = (FC_SYSTEM_ID, COMPANION_COMPONENT_ID)
FC = (FC_SYSTEM_ID, FC_COMPONENT_ID)
HOME_ID = float(m.MAVLINK_MSG_ID_HOME_POSITION)


def test_the_download_gets_every_item_through_lost_replies_and_acks_it():
    store = MissionStore(HOME)
    upload(store, MISSION)
    download, now_s, replies = MissionDownload(OWN, FC, 0.0), 0.0, 0
    while not (download.done or download.failed):
        outbox, download.outbox = download.outbox, []
        for request in outbox:
            for reply in store.handle(sent_by(OWN, request), 0, True):
                replies += 1
                if replies % 3:                       # every third reply is lost
                    download.on_message(sent_by(FC, reply), now_s)
        if not download.outbox:
            now_s += TIMEOUT_S
            download.tick(now_s)
    assert download.done and download.items[1:] == list(MISSION[1:])
    assert download.outbox[-1].get_type() == "MISSION_ACK" and download.outbox[-1].type == m.MAV_MISSION_ACCEPTED


def test_a_silent_fc_fails_the_download_after_the_retries():
    download = MissionDownload(OWN, FC, 0.0)
    for k in range(1, RETRIES + 2):
        download.tick(k * TIMEOUT_S)
    assert [msg.get_type() for msg in download.outbox] == ["MISSION_REQUEST_LIST"] * (RETRIES + 1)
    assert download.failed == f"no answer to {RETRIES + 1} requests"


def test_replies_to_a_ground_station_are_not_the_downloads():
    download = MissionDownload(OWN, FC, 0.0)
    download.on_message(sent_by(FC, m.MAVLink_mission_count_message(*GCS, 5, 0)), 0.0)
    assert download.count is None


class Fc:
    """What FcMission uses of the FC's link: the SITL's mission store answers the mission
    protocol, a HOME_POSITION request is acked and answered."""

    def __init__(self, store):
        self.store, self.fc_ids, self.replies, self.sent = store, FC, [], []
        self.commands = CommandQueue(FC, OWN)
        self.link = SimpleNamespace(send=self._send, send_all=lambda msgs: [self._send(msg) for msg in msgs])

    def _send(self, msg):
        self.sent.append(msg)
        self.replies += [sent_by(FC, r) for r in self.store.handle(sent_by(OWN, msg), 0, True)]

    def run(self, mission):
        """Carry replies until none is left; the missions `mission` says to fly."""
        flown = []
        while self.replies or self.commands.pending:
            if (cmd := self.commands.next_message(0.0)) is not None:
                assert (cmd.command, cmd.param1) == (m.MAV_CMD_REQUEST_MESSAGE, HOME_ID)
                self.commands.on_ack(sent_by(FC, ack(cmd.command, m.MAV_RESULT_ACCEPTED)))
                self.replies.append(sent_by(FC, m.MAVLink_home_position_message(
                    round(HOME.lat_deg * 1e7), round(HOME.lon_deg * 1e7), round(HOME.alt_amsl_m * 1e3), 0, 0, 0,
                    [1, 0, 0, 0], 0, 0, 0, 0)))
            if self.replies and (got := mission.on_message(self.replies.pop(0), 0.0)) is not None:
                flown.append(got)
        return flown


def test_the_fcs_mission_is_flown_once_and_a_new_upload_again():
    store = MissionStore(HOME)
    upload(store, MISSION)
    fc = Fc(store)
    mission = FcMission(fc, OWN, "hold")
    mission.on_locked(0.0)
    assert mission.pending(0.0) and not mission.pending(FIRST_WAIT_S)
    (flown,) = fc.run(mission)
    assert not mission.pending(0.0) and flown.seqs == (1, 3, 4) and flown.mission.on_fault == "hold"
    mission.report(0)
    mission.report(0)
    mission.report(2)
    assert [msg.seq for msg in fc.sent if msg.get_type() == "MISSION_SET_CURRENT"] == [1, 4]
    assert store.current == 4
    upload(store, MISSION)                             # the same again: NOT_STARTED, nothing new to fly
    assert fc.run(mission) == [] and mission.on_message(sent_by(FC, store.current_message()), 0.0) is None
    assert fc.run(mission) == [] and store.current == 4
    upload(store, (*MISSION[:3], global_item(3, 5.0, 5.0, 2.0)))
    mission.on_message(sent_by(FC, store.current_message()), 0.0)
    (again,) = fc.run(mission)
    assert again.mission.land is None and again.mission.waypoints[1].ned_m[0] > 4.9
