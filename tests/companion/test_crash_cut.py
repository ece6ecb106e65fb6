"""A crash the companion recognises, over real loopback sockets: the thrust is cut and stays
cut, the crash is announced once, and no re-arm is ever sent."""

from __future__ import annotations

import math
import time

from companion.app import CompanionApp
from companion.config import parse_config
from companion.controller import Controller, ControllerSettings
from companion.fc_link import FcLink
from m4.airframe import load_airframe
from m4.mavlink import COMPANION_COMPONENT_ID, FC_SYSTEM_ID, mavlink
from m4.mavlink.link import UdpLink
from support.loopback_fc import LoopbackFc

AF = load_airframe()


def test_upside_down_cuts_the_thrust_for_good_and_never_re_arms():
    config = parse_config({"control": {"rate_hz": 50.0}, "link": {"fc_url": "udpin:127.0.0.1:0"}}, "test")
    link = UdpLink("udpin:127.0.0.1:0", FC_SYSTEM_ID, COMPANION_COMPONENT_ID)
    fc = LoopbackFc(link.local_port, AF)
    app = CompanionApp(config, FcLink(link), Controller(ControllerSettings.of(config)))
    sent = []
    try:
        fc.join(app)
        for k in range(80):                 # 0.4 s level, 0.8 s upside down, then level again
            fc.frame(20 * k, roll_rad=math.pi if 20 <= k < 60 else 0.0)
            time.sleep(0.003)
            app.poll()
            sent += fc.received()
    finally:
        fc.close()
        link.close()
    cut = [bool(m.flags & mavlink.M4_SETPOINT_FLAG_THRUST_CUT) for m in sent if m.get_type() == "M4_SETPOINT"]
    assert len(cut) == 80
    first = cut.index(True)
    assert 20 + 24 <= first <= 20 + 26 and all(cut[first:])          # 0.5 s upside down, then cut for good
    texts = [(m.severity, m.text) for m in sent if m.get_type() == "STATUSTEXT"
             and m.severity < mavlink.MAV_SEVERITY_WARNING]       # a loaded machine's overruns are warnings
    assert texts == [(mavlink.MAV_SEVERITY_EMERGENCY, "companion: crash (upside down), thrust cut")]
    commands = [m.command for m in sent if m.get_type() in ("COMMAND_LONG", "COMMAND_INT")]
    assert mavlink.MAV_CMD_COMPONENT_ARM_DISARM not in commands
