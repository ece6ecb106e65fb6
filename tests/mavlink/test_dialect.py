"""The dialect: generated code matches the XML, MAVLink 2 is on, our ids are our own."""

from __future__ import annotations

import os
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

from m4.mavlink import COMPANION_COMPONENT_ID, DIALECT, mavlink, mavutil, new_mav
from m4.mavlink.generate import GENERATED_PATH, PYMAVLINK_V20_DIR, XML_PATH, generate
from tests.support.packets import packed

OUR_IDS = range(48000, 48100)



def test_generated_module_is_what_the_xml_generates(tmp_path):
    out = tmp_path / "m4_generated.py"
    generate(out)
    assert out.read_bytes() == GENERATED_PATH.read_bytes(), \
        "m4/mavlink/m4_generated.py is stale: run python -m m4.mavlink.generate"


def test_mavlink2_is_set_before_pymavlink_chooses():
    assert os.environ.get("MAVLINK20") == "1"
    assert mavutil.mavlink20()
    assert mavlink.WIRE_PROTOCOL_VERSION == "2.0"
    assert mavutil.mavlink is mavlink and mavutil.current_dialect == DIALECT


def test_a_message_id_above_255_round_trips():
    (packet,) = packed([mavlink.MAVLink_m4_setpoint_message(1, 1, 1234, 20, [1.0, 2.0, 3.0, 4.0], [0.1, 0.2, 0.3, 0.4],
                                                           [0.0, 0.5, 0.0, -0.5], mavlink.M4_SETPOINT_FLAG_THRUST_CUT)],
                       1, COMPANION_COMPONENT_ID)
    assert packet[0] == mavlink.PROTOCOL_MARKER_V2
    (msg,) = new_mav(None, 1, 1).parse_buffer(packet)
    assert msg.get_msgId() == mavlink.MAVLINK_MSG_ID_M4_SETPOINT
    assert msg.get_msgId() > 255
    assert msg.time_boot_ms == 1234 and msg.period_ms == 20
    assert list(msg.thrust_n) == [1.0, 2.0, 3.0, 4.0]
    assert msg.get_srcComponent() == COMPANION_COMPONENT_ID
    assert msg.flags & mavlink.M4_SETPOINT_FLAG_THRUST_CUT


def test_mavutil_connections_use_the_projects_dialect_module(tmp_path):
    log = tmp_path / "x.tlog"
    (packet,) = packed([mavlink.MAVLink_m4_joint_state_message(5, [0.1] * 4, [0.0] * 4)])
    log.write_bytes(bytes(8) + packet)
    conn = mavutil.mavlink_connection(str(log), dialect=DIALECT)
    msg = conn.recv_match(blocking=False)
    assert msg.get_type() == "M4_JOINT_STATE"
    assert sys.modules[f"pymavlink.dialects.v20.{DIALECT}"] is mavlink     # ours, not a copy install_dialect wrote


def _ids(path: Path, tag: str) -> set[int]:
    root = ET.parse(path).getroot()
    if tag == "message":
        return {int(m.get("id")) for m in root.iter("message")}
    return {int(e.get("value")) for enum in root.iter("enum") if enum.get("name") == "MAV_CMD"
            for e in enum.iter("entry")}


def test_our_ids_are_used_by_no_bundled_dialect():
    ours_msgs, ours_cmds = _ids(XML_PATH, "message"), _ids(XML_PATH, "command")
    assert ours_msgs and ours_msgs <= set(OUR_IDS) and ours_cmds <= set(OUR_IDS)
    bundled = [xml for xml in PYMAVLINK_V20_DIR.glob("*.xml") if xml.name != f"{DIALECT}.xml"]  # not ours, installed
    assert bundled
    for xml in bundled:
        assert not ours_msgs & _ids(xml, "message"), xml.name
        assert not ours_cmds & _ids(xml, "command"), xml.name


def test_one_fault_kind_numbering_the_dialects_and_no_delivered_thrust_is_reported():
    from m4.fault_kind import FaultKind

    assert {k.name: k.value for k in FaultKind} == {
        name.removeprefix("M4_FAULT_KIND_"): value for name, value in vars(mavlink).items()
        if name.startswith("M4_FAULT_KIND_") and name != "M4_FAULT_KIND_ENUM_END"}
    kinds = [e.get("name") for e in ET.parse(XML_PATH).getroot().iter("enum") if "KIND" in e.get("name")]
    params = {p.get("enum") for p in ET.parse(XML_PATH).getroot().iter("param") if p.get("enum")}
    assert kinds == ["M4_FAULT_KIND"] and params == {"M4_FAULT_KIND"}
    assert mavlink.MAVLink_m4_thruster_status_message.fieldnames == ["time_boot_ms", "thrust_cmd_n", "thrust_limit_n"]
