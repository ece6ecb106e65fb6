"""A mission as a ground station uploads it (for tests): its items around the SITL's home, and
the upload and download exchanges with the FC's mission store (sitl/fc/mission_store.py)."""

from __future__ import annotations

from m4.home import Home
from m4.mavlink import FC_COMPONENT_ID, FC_SYSTEM_ID, mavlink, new_mav
from m4.mission_items import MissionItem

m = mavlink
HOME = Home()
GCS = (255, 190)
REL = m.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT


def sent_by(ids, msg):
    """`msg` as its receiver parses it from `ids` (packed and parsed: the sender in its header)."""
    return new_mav(None, 1, 0).parse_buffer(msg.pack(new_mav(None, *ids)))[0]


def global_item(seq, north_m, east_m, height_m, command=m.MAV_CMD_NAV_WAYPOINT, hold_s=0.0, frame=REL):
    lat, lon, _ = HOME.geodetic((north_m, east_m, 0.0))
    return MissionItem(seq, frame, command, hold_s, 0.0, 0.0, 0.0, round(lat * 1e7), round(lon * 1e7), height_m)


def speed_item(seq, speed_m_s):
    return MissionItem(seq, m.MAV_FRAME_MISSION, m.MAV_CMD_DO_CHANGE_SPEED, 1.0, speed_m_s, -1.0, 0.0, 0, 0, 0.0)


# Home, 3 m north holding 1 s, 2 m/s from there, 3 m east, land where it is.
MISSION = (global_item(0, 0.0, 0.0, 0.0), global_item(1, 3.0, 0.0, 2.0, hold_s=1.0), speed_item(2, 2.0),
           global_item(3, 3.0, 3.0, 2.0), MissionItem(4, REL, m.MAV_CMD_NAV_LAND, 0.0, 0.0, 0.0, 0.0, 0, 0, 0.0))


def upload(store, items, ids=GCS, now_ms=0):
    """Answer the store's requests with `items` until it acks; every reply it gave, in order."""
    replies = store.handle(sent_by(ids, m.MAVLink_mission_count_message(1, 1, len(items), 0)), now_ms, False)
    out = list(replies)
    while replies and replies[0].get_type() == "MISSION_REQUEST_INT":
        assert (replies[0].target_system, replies[0].target_component) == ids
        replies = store.handle(sent_by(ids, items[replies[0].seq].message(FC_SYSTEM_ID, FC_COMPONENT_ID)), now_ms,
                               False)
        out += replies
    return out
