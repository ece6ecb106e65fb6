-- m4_fc.lua: the M4's flight-controller side on stock ArduCopter 4.6 (docs/ardupilot.md).
--
-- In:  M4_SETPOINT (48000) from the companion (system 1, component 191). ArduPilot does not
--      know the id, so the frame fails its CRC check and reaches this script through the
--      bad-CRC path: its CRC is checked here with M4_SETPOINT's CRC extra.
-- Out: overrides of the motors (outputs 1..4) and hips (outputs 9..12) while a setpoint is
--      fresh; a telemetry frame to the companion at every run while engaged: ATTITUDE and
--      LOCAL_POSITION_NED (EKF3) and DEBUG_FLOAT_ARRAY "M4FC" (hips, thrusts), one instant.
--      The position's origin is on the floor, as the contract's: EKF3 sets its origin where the
--      robot stood at boot, with its hull centre HULL_STANDING_M above the floor.
-- Rules (docs/flight-controller.md, as far as Lua allows): a setpoint is refused when it
-- answers an instant in the future, older than max(150 ms, 2 periods), older than the one in
-- use, has a period outside 1..1000 ms, a value that is not finite, or comes while disarmed or
-- not engaged. It is fresh until t + max(3 P, 300 ms): the overrides end then by their own
-- timeout and ArduCopter's mode flies (the HOLD of the contract); after 2 s of stale setpoints
-- the script switches to LAND. The rate feedback of the contract runs at every run of the
-- script (thrust_n + rate_gain x (planned rates - gyro)); the shortfall cover does not.
-- The companion's STATUSTEXT at CRITICAL or above (its fault announcement) is said again as
-- ArduPilot's own, for ground stations that print the autopilot's texts alone.
-- Engage: parameter M4_ENABLE = 1 (the pilot or ground station sets it once airborne).

local SETPOINT_ID, SETPOINT_CRC_EXTRA = 48000, 204
local HEARTBEAT_ID, STATUSTEXT_ID = 0, 253
local COMPANION_SYS, COMPANION_COMP = 1, 191
local ATTITUDE_ID, LOCAL_POSITION_NED_ID, DEBUG_FLOAT_ARRAY_ID = 30, 32, 350
local SETPOINT_PAYLOAD_MAX = 225
local RATE_GAIN_MAX_N_PER_RAD_S = 50.0
local RUN_MS = 5
local MAX_AGE_MIN_MS, MAX_AGE_PERIODS = 150, 2
local STALE_MIN_MS, STALE_PERIODS = 300, 3
local LAND_AFTER_STALE_MS = 2000
local MODE_LAND = 9
local MAV_SEVERITY_CRITICAL, MAV_SEVERITY_WARNING, MAV_SEVERITY_INFO = 2, 4, 6

-- The M4 (m4/airframes/m4_reference.toml): motor and propeller, thrust and hip ranges.
local K_T = 4.4e-05                  -- thrust coefficient, N/(rad/s)^2
local K_Q = 8.8e-07                  -- drag torque coefficient, N m/(rad/s)^2
local K_E = 0.013641852265019601     -- back-EMF constant, V s/rad
local R_OHM = 0.07860005933989143    -- winding resistance
local I0_A = 1.0                     -- no-load current
local THRUST_MIN_N, THRUST_MAX_N = 0.0, 30.0
local HIP_MIN_RAD, HIP_MAX_RAD = 0.0, 1.5707963267948966
local HIP_NOMINAL_RAD = 0.7853981633974483
local HIP_RATE_MAX_RAD_S = 6.0
local HULL_STANDING_M = 0.075        -- the hull centre above the floor when the robot stands (half the hull's height)
local PWM_MIN, PWM_MAX = 1000, 2000  -- MOT_PWM_MIN/MAX and SERVO9..12_MIN/MAX
local MOTOR_OUT, HIP_OUT = 0, 8      -- first output (0-based) of motors 1..4 and hips 1..4
local HIP_FUNCTION = 94              -- Script1..4 on SERVO9..12

local PARAM_KEY = 48
assert(param:add_table(PARAM_KEY, "M4_", 1), "m4_fc: cannot add the M4_ parameters")
assert(param:add_param(PARAM_KEY, 1, "ENABLE", 0), "m4_fc: cannot add M4_ENABLE")
local enable = Parameter("M4_ENABLE")

mavlink:init(2, 10)
mavlink:register_rx_msgid(SETPOINT_ID)
mavlink:register_rx_msgid(HEARTBEAT_ID)
mavlink:register_rx_msgid(STATUSTEXT_ID)

local chan = nil                     -- the companion's MAVLink channel (from its HEARTBEAT)
local sp = nil                       -- the setpoint in use: {t, period, thrust{}, hip{}, cut, applied, fb}
local stale_since = nil
local landed_by_us = false
local hip_est = {HIP_NOMINAL_RAD, HIP_NOMINAL_RAD, HIP_NOMINAL_RAD, HIP_NOMINAL_RAD}
local hip_rate_est = {0.0, 0.0, 0.0, 0.0}
local last_run_ms = nil
local counts = {crc = 0, refused = 0, applied = 0, frames = 0, runs = 0}
local last_refusal = ""
local REPORT_MS = 10000              -- how often the script reports its counts (STATUSTEXT)
local next_report_ms = nil

local function crc_accumulate(crc, s, first, last)
  for i = first, last do
    local tmp = s:byte(i) ~ (crc & 0xff)
    tmp = (tmp ~ (tmp << 4)) & 0xff
    crc = ((crc >> 8) ~ (tmp << 8) ~ (tmp << 3) ~ (tmp >> 4)) & 0xffff
  end
  return crc
end

-- The raw mavlink_message_t: magic at byte 3, len 4, sysid 8, compid 9, msgid 10..12,
-- payload from 13 (264 bytes), the received checksum at 277..278.
local function crc_ok(msg, len, extra)
  local crc = crc_accumulate(0xffff, msg, 4, 12 + len)
  crc = crc_accumulate(crc, string.char(extra), 1, 1)
  return crc == (msg:byte(277) | (msg:byte(278) << 8))
end

local function finite(x)
  return x == x and x ~= math.huge and x ~= -math.huge
end

local function clamp(x, lo, hi)
  return math.min(math.max(x, lo), hi)
end

-- ESC throttle 0..1 that turns the nominal propeller at the speed giving thrust_n on voltage_v
-- (sitl/plant/thrusters.py: k_e w + R (k_q w^2 / k_e + i0) = throttle x V).
local function throttle_for(thrust_n, voltage_v)
  if thrust_n <= 0.0 then
    return 0.0
  end
  local w = math.sqrt(thrust_n / K_T)
  return clamp((K_E * w + R_OHM * (K_Q * w * w / K_E + I0_A)) / voltage_v, 0.0, 1.0)
end

-- The thrust the nominal rotor settles at on throttle x voltage_v (the inverse of throttle_for).
local function thrust_for(throttle, voltage_v)
  local drive = K_E * math.max(throttle * voltage_v - R_OHM * I0_A, 0.0)
  local w = 2.0 * drive / (K_E * K_E + math.sqrt(K_E ^ 4 + 4.0 * K_Q * R_OHM * drive))
  return K_T * w * w
end

local function pack_voltage()
  local v = battery:voltage(0)
  if v == nil or v < 1.0 then
    return 14.8
  end
  return v
end

local function say(severity, text)
  gcs:send_text(severity, "m4: " .. text)
end

local function refuse(reason)
  counts.refused = counts.refused + 1
  if reason ~= last_refusal then
    last_refusal = reason
    say(MAV_SEVERITY_WARNING, "setpoint refused: " .. reason)
  end
end

-- The rate feedback a setpoint asks for ({ref[3], change[3], gain[12]}, gain rotor by rotor, x y z
-- each); nil when it asks for none (all gains zero) or cannot be used (not finite, a gain beyond
-- RATE_GAIN_MAX_N_PER_RAD_S).
local function rate_feedback(fields)
  local any = false
  for i = 1, 18 do
    if not finite(fields[i]) then return nil end
    if i > 6 then
      if math.abs(fields[i]) > RATE_GAIN_MAX_N_PER_RAD_S then return nil end
      any = any or fields[i] ~= 0.0
    end
  end
  if not any then return nil end
  return fields
end

-- Rotor i's thrust change from the rate feedback, the setpoint in force for in_force_ms.
local function feedback_n(fb, i, in_force_ms, period_ms, gyro)
  local held_s = math.min(math.max(in_force_ms, 0), period_ms) / 1000.0
  local rates = {gyro:x(), gyro:y(), gyro:z()}
  local change = 0.0
  for j = 1, 3 do
    change = change + fb[6 + 3 * (i - 1) + j] * (fb[j] + fb[3 + j] * held_s - rates[j])
  end
  return change
end

local function setpoint_fault(t, period, values, now)
  if period < 1 or period > 1000 then return "period" end
  if t > now then return "future" end
  if now - t > math.max(MAX_AGE_MIN_MS, MAX_AGE_PERIODS * period) then return "too old" end
  if sp ~= nil and t < sp.t then return "out of order" end
  for i = 1, #values do
    if not finite(values[i]) then return "not finite" end
  end
  if not arming:is_armed() then return "disarmed" end
  if enable:get() ~= 1 then return "not engaged (M4_ENABLE 0)" end
  return nil
end

local function on_setpoint(msg, now)
  local len = msg:byte(4)
  if len > SETPOINT_PAYLOAD_MAX or not crc_ok(msg, len, SETPOINT_CRC_EXTRA) then
    counts.crc = counts.crc + 1
    return
  end
  if msg:byte(8) ~= COMPANION_SYS or msg:byte(9) ~= COMPANION_COMP then
    refuse("not from the companion")
    return
  end
  local payload = msg:sub(13, 12 + len) .. string.rep("\0", SETPOINT_PAYLOAD_MAX - len)
  local v = {string.unpack("<I4ffffffffffffI2BBB" .. string.rep("f", 18), payload)}
  local t, period, flags = v[1], v[14], v[17]
  local values = {table.unpack(v, 2, 13)}
  if v[15] ~= 1 or v[16] ~= 1 then
    refuse("addressed to another system")
    return
  end
  local reason = setpoint_fault(t, period, values, now)
  if reason ~= nil then
    refuse(reason)
    return
  end
  local thrust, hip = {}, {}
  for i = 1, 4 do
    thrust[i] = clamp(values[i], THRUST_MIN_N, THRUST_MAX_N)
    hip[i] = clamp(values[4 + i], HIP_MIN_RAD, HIP_MAX_RAD)
  end
  if sp == nil or stale_since ~= nil then
    say(MAV_SEVERITY_INFO, "flying companion setpoints")
  end
  sp = {t = t, period = period, thrust = thrust, hip = hip, cut = (flags & 1) ~= 0, applied = now,
        fb = rate_feedback({table.unpack(v, 18, 35)})}
  stale_since, last_refusal = nil, ""
  counts.applied = counts.applied + 1
end

-- The companion's STATUSTEXT at CRITICAL or above (its fault, a crash) said again as ArduPilot's
-- own, as the project's FC does: ground stations print the autopilot's texts (MAVProxy no other).
local function relay_text(msg)
  local severity, len = msg:byte(13), msg:byte(4)
  if severity > MAV_SEVERITY_CRITICAL then
    return
  end
  local text = msg:sub(14, math.min(12 + len, 63))
  gcs:send_text(severity, text:match("^[^\0]*"))
end

local function receive(now)
  local msg, from = mavlink:receive_chan()
  while msg do
    local id = msg:byte(10) | (msg:byte(11) << 8) | (msg:byte(12) << 16)
    if id == SETPOINT_ID then
      on_setpoint(msg, now)
    elseif id == STATUSTEXT_ID and msg:byte(8) == COMPANION_SYS and msg:byte(9) == COMPANION_COMP then
      relay_text(msg)
    elseif id == HEARTBEAT_ID and msg:byte(8) == COMPANION_SYS and msg:byte(9) == COMPANION_COMP then
      if chan ~= from then
        chan = from
        say(MAV_SEVERITY_INFO, string.format("companion heard on channel %d", from))
      end
    end
    msg, from = mavlink:receive_chan()
  end
end

-- Outputs: the setpoint while fresh (overrides that end by themselves when it goes stale).
local function drive(now)
  for i = 1, 4 do
    SRV_Channels:set_output_pwm(HIP_FUNCTION + i - 1, PWM_MIN + math.floor(
      (HIP_NOMINAL_RAD - HIP_MIN_RAD) / (HIP_MAX_RAD - HIP_MIN_RAD) * (PWM_MAX - PWM_MIN) + 0.5))
  end
  if sp == nil then
    return
  end
  local fresh_ms = sp.t + math.max(STALE_PERIODS * sp.period, STALE_MIN_MS) - now
  if fresh_ms <= 0 then
    if stale_since == nil then
      stale_since = now
      say(MAV_SEVERITY_WARNING, "failsafe: no fresh setpoints, ArduCopter flies")
    elseif not landed_by_us and now - stale_since >= LAND_AFTER_STALE_MS and arming:is_armed() then
      landed_by_us = vehicle:set_mode(MODE_LAND)
      say(MAV_SEVERITY_WARNING, "failsafe LAND: setpoints stale for 2 s")
    end
    return
  end
  if sp.cut then
    for i = 1, 4 do
      SRV_Channels:set_output_pwm_chan_timeout(MOTOR_OUT + i - 1, PWM_MIN, fresh_ms)
    end
    if arming:is_armed() then
      arming:disarm()
      say(MAV_SEVERITY_INFO, "thrust cut: disarmed")
    end
    return
  end
  local volts, gyro = pack_voltage(), ahrs:get_gyro()
  for i = 1, 4 do
    local thrust = sp.thrust[i]
    if sp.fb ~= nil and gyro ~= nil then
      thrust = clamp(thrust + feedback_n(sp.fb, i, now - sp.applied, sp.period, gyro), THRUST_MIN_N, THRUST_MAX_N)
    end
    local pwm = PWM_MIN + math.floor(throttle_for(thrust, volts) * (PWM_MAX - PWM_MIN) + 0.5)
    SRV_Channels:set_output_pwm_chan_timeout(MOTOR_OUT + i - 1, pwm, fresh_ms)
    local hip_pwm = PWM_MIN + math.floor((sp.hip[i] - HIP_MIN_RAD) / (HIP_MAX_RAD - HIP_MIN_RAD)
                                         * (PWM_MAX - PWM_MIN) + 0.5)
    SRV_Channels:set_output_pwm_chan_timeout(HIP_OUT + i - 1, hip_pwm, fresh_ms)
  end
end

-- The hips as the servos move them (no feedback on ArduPilot): the commanded angle, followed at
-- the servo's rate limit.
local function track_hips(dt_s)
  for i = 1, 4 do
    local pwm = SRV_Channels:get_output_pwm_chan(HIP_OUT + i - 1) or PWM_MIN
    local goal = HIP_MIN_RAD + (pwm - PWM_MIN) / (PWM_MAX - PWM_MIN) * (HIP_MAX_RAD - HIP_MIN_RAD)
    local step = clamp(goal - hip_est[i], -HIP_RATE_MAX_RAD_S * dt_s, HIP_RATE_MAX_RAD_S * dt_s)
    hip_est[i] = hip_est[i] + step
    hip_rate_est[i] = dt_s > 0 and step / dt_s or 0.0
  end
end

local function send_frame(now)
  local pos, vel = ahrs:get_relative_position_NED_origin(), ahrs:get_velocity_NED()
  local gyro = ahrs:get_gyro()
  if pos == nil or vel == nil or gyro == nil then
    return
  end
  mavlink:send_chan(chan, ATTITUDE_ID, string.pack("<I4ffffff", now, ahrs:get_roll(), ahrs:get_pitch(),
    ahrs:get_yaw(), gyro:x(), gyro:y(), gyro:z()))
  mavlink:send_chan(chan, LOCAL_POSITION_NED_ID, string.pack("<I4ffffff", now, pos:x(), pos:y(),
    pos:z() - HULL_STANDING_M, vel:x(), vel:y(), vel:z()))
  local volts, data = pack_voltage(), {}
  for i = 1, 4 do
    local pwm = SRV_Channels:get_output_pwm_chan(MOTOR_OUT + i - 1) or PWM_MIN
    data[i] = hip_est[i]
    data[4 + i] = hip_rate_est[i]
    data[8 + i] = thrust_for((pwm - PWM_MIN) / (PWM_MAX - PWM_MIN), volts)
    data[12 + i] = THRUST_MAX_N
  end
  data[17] = (sp ~= nil and stale_since == nil) and 1.0 or 0.0
  local floats = string.pack("<" .. string.rep("f", #data), table.unpack(data))
  mavlink:send_chan(chan, DEBUG_FLOAT_ARRAY_ID, string.pack("<I8I2c10", now * 1000, 1, "M4FC")
    .. floats .. string.rep("\0", 4 * (58 - #data)))
  counts.frames = counts.frames + 1
end

-- Every REPORT_MS: runs a second, frames sent, setpoints applied, refused and with a bad CRC.
local function report(now)
  if next_report_ms == nil then
    next_report_ms = now + REPORT_MS
  elseif now >= next_report_ms then
    say(MAV_SEVERITY_INFO, string.format("%.0f runs/s, %d frames, %d setpoints", counts.runs * 1000 / (now -
      next_report_ms + REPORT_MS), counts.frames, counts.applied))
    say(MAV_SEVERITY_INFO, string.format("%d refused, %d with a bad CRC", counts.refused, counts.crc))
    counts = {crc = 0, refused = 0, applied = 0, frames = 0, runs = 0}
    next_report_ms = now + REPORT_MS
  end
end

local function update()
  local now = millis():toint()
  counts.runs = counts.runs + 1
  report(now)
  receive(now)
  drive(now)
  track_hips(last_run_ms == nil and 0.0 or (now - last_run_ms) / 1000.0)
  last_run_ms = now
  if chan ~= nil and enable:get() == 1 and arming:is_armed() then
    send_frame(now)
  end
  return update, RUN_MS
end

say(MAV_SEVERITY_INFO, "m4_fc.lua running")
return update()
