"""Mission items from a ground station turned into the mission flown (m4.mission_items), the home
that places them (m4.home), and the plan's landing and progress for such a mission."""

from __future__ import annotations

import pytest

from m4.airframe import load_airframe
from m4.mavlink import mavlink
from m4.mission import Landing, Waypoint
from m4.mission_items import MissionItem, to_mission
from m4.mission_plan import MissionPlan
from support.missions import HOME, MISSION, REL, global_item

m = mavlink
HOME_ITEM, LAND_HERE = MISSION[0], MISSION[4]


def test_home_places_a_local_point_and_takes_it_back_to_a_millimetre():
    lat, lon, alt = HOME.geodetic((120.0, -45.0, -3.0))
    north, east = HOME.north_east_m(lat, lon)
    assert (north, east, alt) == (pytest.approx(120.0, abs=1e-3), pytest.approx(-45.0, abs=1e-3),
                                  HOME.alt_amsl_m + 3.0)


def test_waypoints_holds_speed_changes_and_a_landing_become_the_mission():
    items = (*MISSION[:3], global_item(3, 3.0, 3.0, 2.5), LAND_HERE)
    flown = to_mission(items, HOME, "continue")
    (a, b) = flown.mission.waypoints
    assert a.ned_m == pytest.approx((3.0, 0.0, -2.0), abs=0.01) and (a.speed_m_s, a.hold_s) == (1.0, 1.0)
    assert b.ned_m == pytest.approx((3.0, 3.0, -2.5), abs=0.01) and (b.speed_m_s, b.hold_s) == (2.0, 0.0)
    assert flown.mission.land == Landing(at_s=None, descent_speed_m_s=0.5)
    assert flown.mission.on_fault == "continue"
    assert flown.seqs == (1, 3, 4)


def test_a_located_landing_flies_there_at_the_last_height_first():
    land = global_item(2, -1.0, 4.0, 0.0, command=m.MAV_CMD_NAV_LAND)
    flown = to_mission((HOME_ITEM, global_item(1, 3.0, 0.0, 2.0), land), HOME, "hold")
    assert flown.mission.waypoints[1].ned_m == pytest.approx((-1.0, 4.0, -2.0), abs=0.01)
    assert flown.seqs == (1, 2, 2)


def test_a_local_ned_item_is_in_metres_times_1e4():
    item = MissionItem(1, m.MAV_FRAME_LOCAL_NED, m.MAV_CMD_NAV_WAYPOINT, 0.0, 0, 0, 0, 25_000, -10_000, -1.5)
    assert to_mission((HOME_ITEM, item), HOME, "hold").mission.waypoints == (Waypoint((2.5, -1.0, -1.5), 1.0, 0.0),)


def test_an_unsupported_item_is_named():
    loiter = MissionItem(1, REL, m.MAV_CMD_NAV_LOITER_UNLIM, 0.0, 0, 0, 0, 0, 0, 2.0)
    with pytest.raises(ValueError, match="item 1: command 17 not supported"):
        to_mission((HOME_ITEM, loiter), HOME, "hold")


def test_the_plan_lands_when_the_last_hold_ends_and_reports_the_item_flown():
    items = (HOME_ITEM, global_item(1, 2.0, 0.0, 2.0, hold_s=1.0), global_item(2, 2.0, 2.0, 2.0), LAND_HERE)
    mission = to_mission(items, HOME, "hold").mission
    plan = MissionPlan(mission, (0.0, 0.0, -2.0), load_airframe(), t0_s=5.0)
    leg_s = 2.0 / 1.0 + 1.0 / 2.0           # 2 m at 1 m/s, accelerating and braking at 2 m/s^2
    assert plan.land_at_s == pytest.approx(5.0 + 2 * leg_s + 1.0, abs=0.02)
    assert [plan.item(t) for t in (5.0, 5.0 + leg_s + 0.5, 5.0 + leg_s + 1.1, plan.land_at_s)] == [0, 0, 1, 2]
    assert not plan.landing_started(plan.land_at_s - 0.01) and plan.landing_started(plan.land_at_s)
    plan.fault_detected(5.0 + leg_s + 1.5, (2.0, 1.0, -2.0))
    assert plan.item(plan.land_at_s - 0.1) == 1 and plan.item(plan.land_at_s) == 2
