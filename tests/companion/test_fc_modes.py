"""The companion flies the mode selected at the flight controller (CURRENT_MODE's
intended_custom_mode, issue 22): a hold, a landing, its mission again; a mode it does not know
is its mission. Over a real loopback socket with a scripted FC."""

from __future__ import annotations

import logging
import time

from companion.app import CompanionApp
from companion.config import parse_config
from companion.controller import Controller, ControllerSettings
from companion.fc_link import FcLink
from m4.airframe import load_airframe
from m4.fc_mode import FcMode
from m4.mavlink import COMPANION_COMPONENT_ID, FC_SYSTEM_ID, mavlink
from m4.mavlink.link import UdpLink
from support.loopback_fc import LoopbackFc

AF = load_airframe()
CONFIG = parse_config({"control": {"rate_hz": 50.0}, "link": {"fc_url": "udpin:127.0.0.1:0"}}, "test")
_STANDARD = {FcMode.HOLD: mavlink.MAV_STANDARD_MODE_POSITION_HOLD, FcMode.LAND: mavlink.MAV_STANDARD_MODE_LAND}


def _fly(app, fc, t0_ms: int, frames: int) -> None:
    for k in range(frames):
        fc.frame(t0_ms + 20 * k)
        time.sleep(0.005)
        app.poll()
        fc.received()


def _select(fc, mode: int) -> None:
    standard = _STANDARD.get(mode, mavlink.MAV_STANDARD_MODE_NON_STANDARD)
    fc.link.send(mavlink.MAVLink_current_mode_message(standard, mode, mode))


def test_the_companion_flies_the_mode_selected_at_the_fc(caplog):
    link = UdpLink("udpin:127.0.0.1:0", FC_SYSTEM_ID, COMPANION_COMPONENT_ID)
    app = CompanionApp(CONFIG, FcLink(link), Controller(ControllerSettings.of(CONFIG)))
    fc = LoopbackFc(link.local_port, AF)
    followed = []
    try:
        fc.join(app)
        _fly(app, fc, 0, 5)
        with caplog.at_level(logging.INFO, logger="m4-companion"):
            for k, mode in enumerate((FcMode.HOLD, 3, FcMode.LAND)):      # 3: a mode we do not know
                _select(fc, mode)
                _fly(app, fc, 100 + 100 * k, 5)
                followed.append(app.controller.flight.mode)
        landing = app.controller.flight.reference.landing_started(app.controller.flight.mission_time_s(0.4))
    finally:
        fc.close()
        link.close()
    assert followed == [FcMode.HOLD, FcMode.COMPANION, FcMode.LAND] and landing
    said = [r.message for r in caplog.records if "mode is" in r.message]
    assert [s.split("mode is ")[1] for s in said] == ["HOLD: holding where the robot stops", "COMPANION: flying the mission",
                                                    "LAND: landing where it is"]
