"""The M4 applet (deploy/ardupilot/scripts/m4_fc.lua) in Lua 5.3, ArduPilot's Lua, with the
ArduPilot bindings it uses faked: M4_SETPOINT frames packed by the project's dialect and handed
over as ArduPilot hands a frame it has no CRC extra for (the raw mavlink_message_t), the
contract's refusals, the outputs it drives, the failsafe, and the telemetry frame it sends."""

from __future__ import annotations

import math
import struct
from pathlib import Path

import numpy as np
import pytest

from companion.autopilot_profile import ARDUPILOT
from m4.airframe import load_airframe
from m4.mavlink import COMPANION_COMPONENT_ID, mavlink, new_mav
from m4.mission_plan import ground_com_height_m
from m4.setpoint import ShortfallCover
from sitl.fc.gyro_shortfall import GyroShortfallMeter
from sitl.plant.thrusters import Thrusters

lua53 = pytest.importorskip("lupa.lua53")

APPLET = Path(__file__).resolve().parents[3] / "deploy" / "ardupilot" / "scripts" / "m4_fc.lua"
AF = load_airframe()
VOLTAGE_V = 16.0
COMPANION_CHANNEL = 1

FAKE_ARDUPILOT = """
NOW, ARMED, MODE, VOLTAGE, GYRO = 1000, true, 4, %r, {0.1, 0.2, 0.3}
INBOX, SENT, TEXTS, SEVERITIES, OVERRIDES, OUTPUTS, PARAMS = {}, {}, {}, {}, {}, {}, {}
function millis() return {toint = function() return NOW end} end
param = {add_table = function() return true end,
         add_param = function(_, _, _, name, value) PARAMS["M4_" .. name] = value; return true end}
function Parameter(name) return {get = function() return PARAMS[name] end} end
mavlink = {init = function() end, register_rx_msgid = function() return true end,
           receive_chan = function() local m = table.remove(INBOX, 1); if m then return m[1], m[2] end end,
           send_chan = function(_, chan, id, bytes) SENT[#SENT + 1] = {chan, id, bytes}; return true end}
SRV_Channels = {set_output_pwm_chan_timeout = function(_, ch, pwm, ms) OVERRIDES[ch] = {pwm, ms} end,
                set_output_pwm = function(_, fn, pwm) OUTPUTS[fn] = pwm end,
                get_output_pwm_chan = function(_, ch) local o = OVERRIDES[ch]; return o and o[1] or 1000 end}
arming = {is_armed = function() return ARMED end, disarm = function() ARMED = false; return true end}
vehicle = {set_mode = function(_, mode) MODE = mode; return true end}
battery = {voltage = function() return VOLTAGE end}
local function v3(x, y, z) return {x = function() return x end, y = function() return y end,
                                  z = function() return z end} end
ahrs = {get_roll = function() return 0.01 end, get_pitch = function() return -0.02 end,
        get_yaw = function() return 1.5 end, get_gyro = function() return v3(GYRO[1], GYRO[2], GYRO[3]) end,
        get_relative_position_NED_origin = function() return v3(1.0, 2.0, -2.0) end,
        get_velocity_NED = function() return v3(0.5, 0.0, -0.1) end}
gcs = {send_text = function(_, severity, text) TEXTS[#TEXTS + 1] = text; SEVERITIES[#TEXTS] = severity end}
""" % VOLTAGE_V


def raw_message(msg, sys_id: int = 1, comp_id: int = COMPANION_COMPONENT_ID, corrupt: bool = False) -> bytes:
    """A message as ArduPilot gives it to a script: its mavlink_message_t (checksum, the wire
    header from magic to msgid, the payload in 264 bytes, the received CRC, the signature)."""
    wire = bytearray(msg.pack(new_mav(None, sys_id, comp_id)))
    if corrupt:
        wire[12] ^= 0x40
    length = wire[1]
    payload = bytes(wire[10:10 + length]).ljust(264, b"\0")
    return b"\0\0" + bytes(wire[:10]) + payload + bytes(wire[10 + length:12 + length]) + bytes(13)


class Applet:
    def __init__(self):
        self.lua = lua53.LuaRuntime(encoding="latin-1")          # Lua's strings are bytes: all of them round-trip
        self.lua.execute(FAKE_ARDUPILOT)
        self.g = self.lua.globals()
        self.update = self.lua.execute(APPLET.read_text())[0]
        self.g.PARAMS["M4_ENABLE"] = 1

    def run(self, now_ms: int, *raw: bytes) -> None:
        self.g.NOW = now_ms
        for r in raw:
            self.g.INBOX[len(self.g.INBOX) + 1] = self.lua.table(r, COMPANION_CHANNEL)
        self.update()

    def hear_companion(self, now_ms: int) -> None:
        hb = mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_ONBOARD_CONTROLLER, 8, 0, 0, 4, 3)
        self.run(now_ms, raw_message(hb))

    def override(self, channel: int) -> tuple[int, int] | None:
        o = self.g.OVERRIDES[channel]
        return None if o is None else (o[1], o[2])

    def texts(self) -> list[str]:
        return list(self.g.TEXTS.values())

    def sent(self) -> list[tuple[int, int, bytes]]:
        return [(s[1], s[2], s[3].encode("latin-1")) for s in self.g.SENT.values()]


def setpoint(t_ms: int, thrust_n=(14.7,) * 4, hip_rad=(0.7,) * 4, period_ms: int = 20, flags: int = 0, **feedback):
    return mavlink.MAVLink_m4_setpoint_message(1, 1, t_ms, period_ms, list(thrust_n), list(hip_rad), [0.0] * 4, flags,
                                               **feedback)


def thrusts_driven_n(applet) -> list[float]:
    """What the plant's rotors give on the throttles the applet drives (at VOLTAGE_V)."""
    rotors = Thrusters(AF, AF.hover_thrust_per_rotor_n, VOLTAGE_V)
    rotors.command_duty([(applet.override(c)[0] - 1000) / 1000 for c in range(4)])
    return rotors.duty_thrust_n(VOLTAGE_V)


def pwm_us(fraction: float) -> int:
    return 1000 + math.floor(fraction * 1000 + 0.5)


@pytest.fixture
def applet():
    a = Applet()
    a.hear_companion(1000)
    return a


def test_a_fresh_setpoint_drives_motors_and_hips_until_it_goes_stale(applet):
    thrusts, hips = (10.0, 14.7, 20.0, 0.0), (0.2, 0.7853981633974483, 1.2, 1.5)
    applet.run(1010, raw_message(setpoint(1005, thrusts, hips)))
    fresh_ms = 1005 + 300 - 1010
    np.testing.assert_allclose(thrusts_driven_n(applet), thrusts, atol=0.05)      # the plant's own thrust
    for c in range(4):
        assert applet.override(c)[1] == fresh_ms
        assert applet.override(8 + c) == (pwm_us(hips[c] / (math.pi / 2)), fresh_ms)
    assert "m4: flying companion setpoints" in applet.texts()


def test_the_rate_feedback_adds_gain_x_planned_less_measured_rates_at_every_run(applet):
    """Gyro (0.1, 0.2, 0.3) rad/s; planned (0, 0.5, 0) changing by (1, 0, 0) per s, held after
    the 20 ms period: 15 ms in force, planned x is 0.015."""
    gain = np.zeros((4, 3))
    gain[0] = (10.0, 0.0, 0.0)
    gain[1] = (0.0, -4.0, 0.0)
    gain[2] = (0.0, 0.0, 2.0)
    applet.run(1010, raw_message(setpoint(1005, thrust_n=(15.0,) * 4, rates_ref_frd_rad_s=[0.0, 0.5, 0.0],
                                          rates_ref_change_frd_rad_s2=[1.0, 0.0, 0.0], rate_gain=gain.ravel().tolist())))
    applet.run(1025)
    expected = 15.0 + gain @ (np.array([0.015, 0.5, 0.0]) - [0.1, 0.2, 0.3])
    np.testing.assert_allclose(thrusts_driven_n(applet), expected, atol=0.05)


def test_the_shortfall_cover_measures_a_lost_rotor_on_the_gyro_as_the_project_fc_does(applet):
    """Rotor 1 stops giving 8 N at 20 ms: the gyro shows the roll and pitch acceleration it took.
    At every 4 ms run the applet drives what the project FC's gyro measure (sitl/fc/gyro_shortfall.py)
    and the cover (m4/setpoint.py) give on the same gyro, outputs and setpoint, and it names rotor 1."""
    effect = np.array([[-3.0, 3.0, 3.0, -3.0], [3.0, -3.0, 3.0, -3.0]])      # roll, pitch per N: quad X, FRD
    gain = np.full((4, 4), 0.5) - np.eye(4) * 0.5
    sp = setpoint(1005, thrust_n=(14.0,) * 4, shortfall_gain=gain.ravel().tolist(),
                  effectiveness_frd_rad_s2_per_n=effect.T.ravel().tolist())
    cover = ShortfallCover.from_fields(sp.shortfall_gain, sp.effectiveness_frd_rad_s2_per_n)
    meter = GyroShortfallMeter(AF, 0.004)
    rates = np.array([0.1, 0.2, 0.3])
    applet.g.GYRO = applet.lua.table(*rates)
    applet.run(1008, raw_message(sp))
    meter.update(rates, [0.0] * 4, [0.0] * 4, [0.0, 0.0], None)          # before the setpoint: nothing driven
    for now_ms in range(1012, 1100, 4):
        if now_ms > 1028:
            rates[:2] += -effect[:, 0] * 8.0 * 0.004                          # rotor 1 short by 8 N
        applet.g.GYRO = applet.lua.table(*rates)
        driven = thrusts_driven_n(applet)
        applet.run(now_ms)
        shortfall = meter.update(rates, driven, [14.0] * 4, [0.0, 0.0], cover.effectiveness_frd_rad_s2_per_n)
        np.testing.assert_allclose(thrusts_driven_n(applet), 14.0 + cover.thrust_change_n(shortfall), atol=0.1)
    assert shortfall[0] > 3.0 and shortfall[1:] == [0.0, 0.0, 0.0]           # the gyro here does not see the cover
    assert min(thrusts_driven_n(applet)[1:]) > 16.0                        # the others cover it


def test_a_frame_whose_crc_fails_is_dropped(applet):
    applet.run(1010, raw_message(setpoint(1005), corrupt=True))
    assert applet.override(0) is None


@pytest.mark.parametrize("msg, now_ms, armed, enabled, sender, reason", [
    (setpoint(1011), 1010, True, 1, COMPANION_COMPONENT_ID, "future"),
    (setpoint(850), 1010, True, 1, COMPANION_COMPONENT_ID, "too old"),
    (setpoint(1005, period_ms=0), 1010, True, 1, COMPANION_COMPONENT_ID, "period"),
    (setpoint(1005, thrust_n=(math.nan, 1.0, 1.0, 1.0)), 1010, True, 1, COMPANION_COMPONENT_ID, "not finite"),
    (setpoint(1005), 1010, False, 1, COMPANION_COMPONENT_ID, "disarmed"),
    (setpoint(1005), 1010, True, 0, COMPANION_COMPONENT_ID, "not engaged (M4_ENABLE 0)"),
    (setpoint(1005), 1010, True, 1, 190, "not from the companion"),
])
def test_setpoints_the_contract_refuses_move_nothing(applet, msg, now_ms, armed, enabled, sender, reason):
    applet.g.ARMED, applet.g.PARAMS["M4_ENABLE"] = armed, enabled
    applet.run(now_ms, raw_message(msg, comp_id=sender))
    assert applet.override(0) is None
    assert applet.texts()[-1] == f"m4: setpoint refused: {reason}"


def test_an_older_setpoint_than_the_one_in_use_is_refused(applet):
    applet.run(1010, raw_message(setpoint(1005, thrust_n=(20.0,) * 4)))
    in_use = applet.override(0)
    applet.run(1015, raw_message(setpoint(1000, thrust_n=(5.0,) * 4)))
    assert applet.override(0)[0] == in_use[0]
    assert applet.texts()[-1] == "m4: setpoint refused: out of order"


def test_stale_setpoints_leave_arducopter_flying_then_land_after_2_s(applet):
    applet.run(1010, raw_message(setpoint(1005)))
    applet.g.OVERRIDES[0] = None
    applet.run(1305)                                  # 1005 + 300: stale
    assert applet.override(0) is None                 # no override renewed: ArduCopter's mode flies
    assert applet.texts()[-1] == "m4: failsafe: no fresh setpoints, ArduCopter flies"
    applet.run(3300)
    assert applet.g.MODE == 4
    applet.run(3305)
    assert applet.g.MODE == 9                         # LAND
    assert applet.texts()[-1] == "m4: failsafe LAND: setpoints stale for 2 s"


def test_a_thrust_cut_stops_the_motors_and_disarms(applet):
    applet.run(1010, raw_message(setpoint(1005, flags=mavlink.M4_SETPOINT_FLAG_THRUST_CUT)))
    assert all(applet.override(c)[0] == 1000 for c in range(4))
    assert applet.g.ARMED is False


def test_the_frame_sent_is_one_instant_the_companion_reads(applet):
    applet.run(1010, raw_message(setpoint(1005, thrust_n=(12.0,) * 4)))
    applet.g.SENT = applet.lua.table()
    applet.run(1015)
    sent = applet.sent()
    assert [(chan, msg_id) for chan, msg_id, _ in sent] == [(COMPANION_CHANNEL, mavlink.MAVLINK_MSG_ID_ATTITUDE),
                                                            (COMPANION_CHANNEL, mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED),
                                                            (COMPANION_CHANNEL, mavlink.MAVLINK_MSG_ID_DEBUG_FLOAT_ARRAY)]
    attitude = struct.unpack("<Iffffff", sent[0][2])
    position = struct.unpack("<Iffffff", sent[1][2])
    np.testing.assert_allclose(attitude, (1015, 0.01, -0.02, 1.5, 0.1, 0.2, 0.3), rtol=1e-6)
    standing_m = AF.body_box_size_m[2] / 2           # EKF3's origin: the hull centre of the robot standing at boot
    np.testing.assert_allclose(position, (1015, 1.0, 2.0, -2.0 - standing_m, 0.5, 0.0, -0.1), rtol=1e-6)
    time_usec, array_id, name = struct.unpack_from("<QH10s", sent[2][2])
    data = struct.unpack_from("<58f", sent[2][2], 20)
    frame = mavlink.MAVLink_debug_float_array_message(time_usec, name, array_id, list(data))
    joints, thrusters = ARDUPILOT.translate([frame])
    assert joints.time_boot_ms == thrusters.time_boot_ms == 1015
    np.testing.assert_allclose(thrusters.thrust_cmd_n, [12.0] * 4, atol=0.05)
    np.testing.assert_allclose(thrusters.thrust_limit_n, [AF.thrust_max_n] * 4)
    assert all(0.7 < h < AF.nominal_hip_rad for h in joints.hip_angle_rad)     # on its way to 0.7 at the rate limit


@pytest.mark.parametrize("severity, sender, relayed", [
    (mavlink.MAV_SEVERITY_CRITICAL, COMPANION_COMPONENT_ID, True),
    (mavlink.MAV_SEVERITY_EMERGENCY, COMPANION_COMPONENT_ID, True),
    (mavlink.MAV_SEVERITY_WARNING, COMPANION_COMPONENT_ID, False),
    (mavlink.MAV_SEVERITY_CRITICAL, 190, False),
])
def test_the_companions_fault_announcement_is_said_again_as_ardupilots_own(applet, severity, sender, relayed):
    """As the project's FC: ground stations print the autopilot's texts (MAVProxy no other)."""
    text = "thrust loss rotor 4 (thrust bounds now 30.0, 30.0, 30.0, 3.2 N)"[:50]
    applet.run(1010, raw_message(mavlink.MAVLink_statustext_message(severity, text.encode()), comp_id=sender))
    said = [(t, applet.g.SEVERITIES[i + 1]) for i, t in enumerate(applet.texts())]
    assert ((text, severity) in said) == relayed
    applet.run(1015, raw_message(mavlink.MAVLink_statustext_message(severity, b"thrust loss rotor 2"), comp_id=sender))
    assert (("thrust loss rotor 2", severity) in [(t, applet.g.SEVERITIES[i + 1]) for i, t in
                                                 enumerate(applet.texts())]) == relayed      # shorter: no trailing bytes


def test_nothing_is_sent_before_the_companion_is_heard_or_while_disengaged():
    a = Applet()
    a.run(1000)
    assert a.sent() == []
    a.g.PARAMS["M4_ENABLE"] = 0
    a.hear_companion(1005)
    a.run(1010)
    assert a.sent() == []
    a.g.PARAMS["M4_ENABLE"] = 1
    a.run(1015)
    assert len(a.sent()) == 3


def test_the_applets_motor_model_is_the_airframes():
    """The constants the applet carries (a real robot's are its own) are those of the airframe
    file the plant flies."""
    text = APPLET.read_text()
    for name, value in (("K_T", AF.thrust_coefficient_n_s2), ("K_Q", AF.drag_torque_coefficient_n_m_s2),
                        ("K_E", AF.motor_back_emf_v_s_rad), ("R_OHM", AF.motor_resistance_ohm),
                        ("I0_A", AF.motor_no_load_current_a), ("HIP_RATE_MAX_RAD_S", AF.hip_rate_max_rad_s),
                        ("HULL_STANDING_M", ground_com_height_m(AF) + AF.com_offset_frd_m([AF.nominal_hip_rad] * 4)[2])):
        lua = Applet().lua
        lua.execute(text.split("local PARAM_KEY")[0] + f"\nRESULT = {name}")
        assert lua.globals().RESULT == pytest.approx(value, rel=1e-12), name
