"""The flight controller's mission store alone (no sockets): the mission protocol's upload,
download, clear, timeouts and error acks, and the progress its companion reports."""

from __future__ import annotations

import pytest

from m4.mavlink import COMPANION_COMPONENT_ID, FC_SYSTEM_ID, mavlink
from m4.mission_items import MissionItem
from sitl.fc.mission_store import MAX_ITEMS, RETRIES, TIMEOUT_MS, MissionStore
from support.missions import GCS, HOME, MISSION, REL, global_item, sent_by, speed_item, upload

m = mavlink
OTHER_GCS = (254, 190)
COMPANION = (FC_SYSTEM_ID, COMPANION_COMPONENT_ID)


def acks(replies):
    return [r.type for r in replies if r.get_type() == "MISSION_ACK"]


def download(store, ids=GCS):
    count = store.handle(sent_by(ids, m.MAVLink_mission_request_list_message(1, 1, 0)), 0, False)[0]
    return [MissionItem.from_message(store.handle(sent_by(ids, m.MAVLink_mission_request_int_message(1, 1, s, 0)),
                                                  0, False)[0]) for s in range(count.count)]


def test_an_uploaded_mission_is_acked_kept_and_downloaded_with_the_fcs_home_as_item_0():
    store = MissionStore(HOME)
    replies = upload(store, MISSION)
    assert [r.seq for r in replies if r.get_type() == "MISSION_REQUEST_INT"] == [0, 1, 2, 3, 4]
    assert acks(replies) == [m.MAV_MISSION_ACCEPTED]
    current = replies[-1]
    assert current.get_type() == "MISSION_CURRENT"
    assert (current.seq, current.total, current.mission_state) == (1, 4, m.MISSION_STATE_NOT_STARTED)
    got = download(store)
    assert got[1:] == list(MISSION[1:])
    assert got[0].frame == m.MAV_FRAME_GLOBAL and got[0].x == round(HOME.lat_deg * 1e7)


@pytest.mark.parametrize("bad, result", [
    (MissionItem(2, REL, m.MAV_CMD_NAV_LOITER_UNLIM, 0, 0, 0, 0, 0, 0, 2.0), m.MAV_MISSION_UNSUPPORTED),
    (global_item(2, 1.0, 0.0, 2.0, frame=m.MAV_FRAME_GLOBAL), m.MAV_MISSION_UNSUPPORTED_FRAME),
    (global_item(2, 1.0, 0.0, 900.0), m.MAV_MISSION_INVALID_PARAM7),
    (global_item(2, 1.0, 0.0, 2.0, hold_s=-1.0), m.MAV_MISSION_INVALID_PARAM1),
    (global_item(2, 2e5, 0.0, 2.0), m.MAV_MISSION_INVALID_PARAM5_X),
    (speed_item(2, 40.0), m.MAV_MISSION_INVALID_PARAM2),
])
def test_a_bad_item_ends_the_upload_with_its_error_and_the_mission_before_stays(bad, result):
    store = MissionStore(HOME)
    upload(store, MISSION)
    replies = upload(store, (MISSION[0], MISSION[1], bad))
    assert acks(replies) == [result]
    assert download(store)[1:] == list(MISSION[1:])


def test_nothing_may_follow_a_landing():
    store = MissionStore(HOME)
    assert acks(upload(store, (*MISSION, global_item(5, 1.0, 1.0, 2.0)))) == [m.MAV_MISSION_INVALID_SEQUENCE]


def test_an_item_out_of_turn_is_answered_by_asking_again_for_the_one_expected():
    store = MissionStore(HOME)
    store.handle(sent_by(GCS, m.MAVLink_mission_count_message(1, 1, 3, 0)), 0, False)
    replies = store.handle(sent_by(GCS, MISSION[2].message(1, 1)), 0, False)
    assert [(r.get_type(), r.seq) for r in replies] == [("MISSION_REQUEST_INT", 0)]


def test_a_silent_uploader_is_asked_again_then_the_upload_is_cancelled():
    store = MissionStore(HOME)
    store.handle(sent_by(GCS, m.MAVLink_mission_count_message(1, 1, 3, 0)), 0, False)
    assert store.tick(TIMEOUT_MS - 1) == []
    resent = [store.tick(TIMEOUT_MS * k) for k in range(1, RETRIES + 1)]
    assert all(r[0].get_type() == "MISSION_REQUEST_INT" and r[0].seq == 0 for r in resent)
    assert acks(store.tick(TIMEOUT_MS * (RETRIES + 1))) == [m.MAV_MISSION_OPERATION_CANCELLED]
    assert store.tick(TIMEOUT_MS * (RETRIES + 3)) == []


def test_a_second_ground_station_is_denied_during_an_upload():
    store = MissionStore(HOME)
    store.handle(sent_by(GCS, m.MAVLink_mission_count_message(1, 1, 3, 0)), 0, False)
    replies = store.handle(sent_by(OTHER_GCS, m.MAVLink_mission_count_message(1, 1, 2, 0)), 0, False)
    assert acks(replies) == [m.MAV_MISSION_DENIED] and replies[0].target_system == OTHER_GCS[0]


def test_a_mission_too_long_is_refused_for_space():
    store = MissionStore(HOME)
    count = m.MAVLink_mission_count_message(1, 1, MAX_ITEMS + 1, 0)
    assert acks(store.handle(sent_by(GCS, count), 0, False)) == [m.MAV_MISSION_NO_SPACE]


def test_clear_all_leaves_home_alone():
    store = MissionStore(HOME)
    upload(store, MISSION)
    replies = store.handle(sent_by(GCS, m.MAVLink_mission_clear_all_message(1, 1, 0)), 0, False)
    assert acks(replies) == [m.MAV_MISSION_ACCEPTED]
    assert (replies[-1].total, replies[-1].mission_state) == (0xFFFF, m.MISSION_STATE_NO_MISSION)
    assert len(download(store)) == 1


def test_fences_and_rally_points_are_none_and_cannot_be_uploaded():
    store = MissionStore(HOME)
    listed = store.handle(sent_by(GCS, m.MAVLink_mission_request_list_message(1, 1, m.MAV_MISSION_TYPE_FENCE)), 0,
                          False)
    assert listed[0].get_type() == "MISSION_COUNT" and listed[0].count == 0
    count = m.MAVLink_mission_count_message(1, 1, 2, m.MAV_MISSION_TYPE_RALLY)
    assert acks(store.handle(sent_by(GCS, count), 0, False)) == [m.MAV_MISSION_UNSUPPORTED]


def test_the_companions_progress_is_reported_as_reached_items_and_the_landing_completes_it():
    store = MissionStore(HOME)
    upload(store, MISSION)
    first = store.handle(sent_by(COMPANION, m.MAVLink_mission_set_current_message(1, 1, 1)), 0, True)
    assert [r.get_type() for r in first] == ["MISSION_CURRENT"] and first[0].mission_state == m.MISSION_STATE_ACTIVE
    on = [(r.get_type(), r.seq) for seq in (3, 4)
          for r in store.handle(sent_by(COMPANION, m.MAVLink_mission_set_current_message(1, 1, seq)), 0, True)]
    assert on == [("MISSION_ITEM_REACHED", 1), ("MISSION_CURRENT", 3), ("MISSION_ITEM_REACHED", 3),
                  ("MISSION_CURRENT", 4)]
    done = store.landed()
    assert [(r.get_type(), r.seq) for r in done] == [("MISSION_ITEM_REACHED", 4), ("MISSION_CURRENT", 4)]
    assert done[-1].mission_state == m.MISSION_STATE_COMPLETE


def test_a_ground_stations_jump_is_not_flown():
    store = MissionStore(HOME)
    upload(store, MISSION)
    replies = store.handle(sent_by(GCS, m.MAVLink_mission_set_current_message(1, 1, 3)), 0, False)
    assert [(r.get_type(), r.seq, r.mission_state) for r in replies] == [
        ("MISSION_CURRENT", 1, m.MISSION_STATE_NOT_STARTED)]
