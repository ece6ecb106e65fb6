"""What a flight controller answers the companion's commands, as the SITL's FC does (for the
tests' scripted FCs): a COMMAND_ACK for every command, then the message a
MAV_CMD_REQUEST_MESSAGE asked for: the M4_FAULT_STATUS it kept (FAILED when none), its
CURRENT_MODE; and its mission, none (home alone), to a download (the mission protocol)."""

from __future__ import annotations

from m4.home import Home
from m4.mavlink import COMPANION_COMPONENT_ID, FC_SYSTEM_ID, mavlink
from m4.mission_items import home_item

m = mavlink


def ack(command: int, result: int) -> m.MAVLink_command_ack_message:
    return m.MAVLink_command_ack_message(command, result, 0, 0, FC_SYSTEM_ID, COMPANION_COMPONENT_ID)


def current_mode(standard_mode: int) -> m.MAVLink_current_mode_message:
    return m.MAVLink_current_mode_message(standard_mode, 1, 0)


def answers(msg, kept: m.MAVLink_m4_fault_status_message | None = None,
            standard_mode: int = m.MAV_STANDARD_MODE_POSITION_HOLD) -> list[m.MAVLink_message]:
    """The replies to one message the companion sent (none unless it is a command or a mission
    download's request)."""
    if msg.get_type() == "MISSION_REQUEST_LIST":
        return [m.MAVLink_mission_count_message(FC_SYSTEM_ID, COMPANION_COMPONENT_ID, 1, m.MAV_MISSION_TYPE_MISSION)]
    if msg.get_type() == "MISSION_REQUEST_INT":
        return [home_item(Home()).message(FC_SYSTEM_ID, COMPANION_COMPONENT_ID)]
    if msg.get_type() != "COMMAND_LONG":
        return []
    if msg.command == m.MAV_CMD_REQUEST_MESSAGE and msg.param1 == m.MAVLINK_MSG_ID_M4_FAULT_STATUS:
        return [ack(msg.command, m.MAV_RESULT_FAILED)] if kept is None else [ack(msg.command, m.MAV_RESULT_ACCEPTED), kept]
    if msg.command == m.MAV_CMD_REQUEST_MESSAGE and msg.param1 == m.MAVLINK_MSG_ID_CURRENT_MODE:
        return [ack(msg.command, m.MAV_RESULT_ACCEPTED), current_mode(standard_mode)]
    return [ack(msg.command, m.MAV_RESULT_ACCEPTED)]
