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
-- script (thrust_n + rate_gain x (planned rates - gyro)), and so does the shortfall cover on the
-- gyro's measure (sitl/fc/gyro_shortfall.py: the roll and pitch acceleration the robot lacks,
-- explained by the rotors that fall short; + shortfall_gain x shortfall). The ESCs' measure is
-- not run: the cover rests on the gyro alone.
-- The companion's STATUSTEXT at CRITICAL or above (its fault announcement) is said again as
-- ArduPilot's own, for ground stations that print the autopilot's texts alone.
-- Engage: parameter M4_ENABLE = 1 (the pilot or ground station sets it once airborne).

local SETPOINT_ID, SETPOINT_CRC_EXTRA = 48000, 204
local HEARTBEAT_ID, STATUSTEXT_ID = 0, 253
local COMPANION_SYS, COMPANION_COMP = 1, 191
local ATTITUDE_ID, LOCAL_POSITION_NED_ID, DEBUG_FLOAT_ARRAY_ID = 30, 32, 350
local SETPOINT_PAYLOAD_MAX = 225
local RATE_GAIN_MAX_N_PER_RAD_S = 50.0
local SHORTFALL_GAIN_MAX = 4.0       -- N per N short (m4/setpoint.py)
local EFFECTIVENESS_MAX_RAD_S2_PER_N = 100.0
local CUTOFF_RAD_S, DAMPING = 188.0, 0.7   -- the gyro measure's differentiating filter (30 Hz, Butterworth)
local DEADBAND_N = 1.5               -- shortfalls below this are the models' errors and the gyro's noise
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
local TAU_S = 0.03                   -- the rotor speed's time constant
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
local counts = {crc = 0, refused = 0, applied = 0, frames = 0, runs = 0, covering = 0}
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

-- The shortfall cover a setpoint asks for ({gain[16], effectiveness[8]}: gain rotor by rotor per
-- rotor short, the roll and pitch acceleration per newton rotor by rotor); nil when it asks for
-- none (all gains zero) or cannot be used (not finite, too large). Without a usable effectiveness
-- the gyro cannot measure, and the cover does nothing.
local function shortfall_cover(fields)
  local any_gain, any_effect = false, false
  for i = 1, 24 do
    local limit = i <= 16 and SHORTFALL_GAIN_MAX or EFFECTIVENESS_MAX_RAD_S2_PER_N
    if not finite(fields[i]) or math.abs(fields[i]) > limit then return nil end
    if i <= 16 then any_gain = any_gain or fields[i] ~= 0.0 else any_effect = any_effect or fields[i] ~= 0.0 end
  end
  if not (any_gain and any_effect) then return nil end
  return {gain = {table.unpack(fields, 1, 16)}, effect = {table.unpack(fields, 17, 24)}}
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
  local v = {string.unpack("<I4ffffffffffffI2BBB" .. string.rep("f", 42), payload)}
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
        fb = rate_feedback({table.unpack(v, 18, 35)}), cover = shortfall_cover({table.unpack(v, 36, 59)})}
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

-- The gyro measure (sitl/fc/gyro_shortfall.py): what the outputs give and what the plan's thrusts
-- would (each through the motor's lag), the roll and pitch acceleration expected from them and
-- the plan, and the gyro's, both through one second-order differentiating filter; what the robot
-- lacks, explained by the rotors that fall short. It runs at every run, whoever flies.
local meter = {commanded = nil, planned = nil, value = nil, rate = nil}
local shortfall_n = nil              -- rotors 1..4, N beyond DEADBAND_N; nil: no measure

local function motor_speeds(speeds, thrust_n, decay)
  local out = {}
  for i = 1, 4 do
    local target = math.sqrt(math.max(thrust_n[i], 0.0) / K_T)
    out[i] = speeds == nil and target or target + (speeds[i] - target) * decay
  end
  return out
end

-- y'' = w^2 (u - y) - 2 zeta w y', the input held over dt_s, solved exactly, channel by channel.
local function filter(u, dt_s)
  if meter.value == nil then
    meter.value, meter.rate = {table.unpack(u)}, {0.0, 0.0, 0.0, 0.0}
    return
  end
  local sigma = DAMPING * CUTOFF_RAD_S
  local wd = CUTOFF_RAD_S * math.sqrt(1.0 - DAMPING * DAMPING)
  local decay, c, s = math.exp(-sigma * dt_s), math.cos(wd * dt_s), math.sin(wd * dt_s)
  for k = 1, #u do
    local e, v = meter.value[k] - u[k], meter.rate[k]
    meter.value[k] = u[k] + decay * (e * c + (v + sigma * e) / wd * s)
    meter.rate[k] = decay * (v * c - (CUTOFF_RAD_S * CUTOFF_RAD_S * e + sigma * v) / wd * s)
  end
end

-- The s >= 0 of least total with effect @ s = lacking: one rotor, or the two whose effects
-- bracket it; zeros where none do.
local function rotor_shortfall_n(effect, lacking)
  local best, best_total = nil, math.huge
  for i = 1, 3 do
    for j = i + 1, 4 do
      local a, b, c, d = effect[2 * i - 1], effect[2 * j - 1], effect[2 * i], effect[2 * j]
      local det = a * d - b * c
      local scale = math.max(math.abs(a), math.abs(b), math.abs(c), math.abs(d))
      if math.abs(det) > 1e-6 * scale * scale then
        local s_i = (lacking[1] * d - b * lacking[2]) / det
        local s_j = (a * lacking[2] - c * lacking[1]) / det
        if s_i >= 0.0 and s_j >= 0.0 and s_i + s_j < best_total then
          best, best_total = {i, s_i, j, s_j}, s_i + s_j
        end
      end
    end
  end
  local out = {0.0, 0.0, 0.0, 0.0}
  if best ~= nil then
    out[best[1]], out[best[3]] = best[2], best[4]
  end
  return out
end

local function measure(now, dt_s)
  local volts, gyro = pack_voltage(), ahrs:get_gyro()
  if gyro == nil then
    return
  end
  local commanded = {}
  for i = 1, 4 do
    local pwm = SRV_Channels:get_output_pwm_chan(MOTOR_OUT + i - 1) or PWM_MIN
    commanded[i] = thrust_for((pwm - PWM_MIN) / (PWM_MAX - PWM_MIN), volts)
  end
  local flown = (sp ~= nil and stale_since == nil and not sp.cut) and sp or nil
  local decay = math.exp(-dt_s / TAU_S)
  meter.commanded = motor_speeds(meter.commanded, commanded, decay)
  meter.planned = motor_speeds(meter.planned, flown and flown.thrust or commanded, decay)
  local expected = {0.0, 0.0}
  if flown and flown.fb ~= nil and now - flown.applied < flown.period then
    expected = {flown.fb[4], flown.fb[5]}
  end
  local effect = flown and flown.cover and flown.cover.effect
  if effect then
    for i = 1, 4 do
      local more_n = K_T * (meter.commanded[i] ^ 2 - meter.planned[i] ^ 2)
      expected[1] = expected[1] + effect[2 * i - 1] * more_n
      expected[2] = expected[2] + effect[2 * i] * more_n
    end
  end
  filter({gyro:x(), gyro:y(), expected[1], expected[2]}, dt_s)
  if not effect then
    shortfall_n = nil
    return
  end
  shortfall_n = rotor_shortfall_n(effect, {meter.value[3] - meter.rate[1], meter.value[4] - meter.rate[2]})
  for i = 1, 4 do
    shortfall_n[i] = math.max(shortfall_n[i] - DEADBAND_N, 0.0)
  end
end

-- The other rotors' cover for the rotors' shortfall: rotor i's change.
local function cover_n(cover, i)
  if shortfall_n == nil then
    return 0.0
  end
  local change = 0.0
  for j = 1, 4 do
    change = change + cover.gain[4 * (i - 1) + j] * shortfall_n[j]
  end
  if change ~= 0.0 then
    counts.covering = counts.covering + 1
  end
  return change
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
      thrust = thrust + feedback_n(sp.fb, i, now - sp.applied, sp.period, gyro)
    end
    if sp.cover ~= nil then
      thrust = thrust + cover_n(sp.cover, i)
    end
    thrust = clamp(thrust, THRUST_MIN_N, THRUST_MAX_N)
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

-- Every REPORT_MS: runs a second, frames sent, setpoints applied, refused and with a bad CRC,
-- and rotor outputs the cover changed (each text within STATUSTEXT's 50 characters).
local function report(now)
  if next_report_ms == nil then
    next_report_ms = now + REPORT_MS
  elseif now >= next_report_ms then
    say(MAV_SEVERITY_INFO, string.format("%.0f runs/s, %d frames, %d setpoints", counts.runs * 1000 / (now -
      next_report_ms + REPORT_MS), counts.frames, counts.applied))
    say(MAV_SEVERITY_INFO, string.format("%d refused, %d bad CRC, %d covered", counts.refused, counts.crc,
      counts.covering))
    counts = {crc = 0, refused = 0, applied = 0, frames = 0, runs = 0, covering = 0}
    next_report_ms = now + REPORT_MS
  end
end

local function update()
  local now = millis():toint()
  local dt_s = last_run_ms == nil and 0.0 or (now - last_run_ms) / 1000.0
  counts.runs = counts.runs + 1
  report(now)
  measure(now, dt_s)                 -- what the last run's outputs and setpoint gave, before a new one
  receive(now)
  drive(now)
  track_hips(dt_s)
  last_run_ms = now
  if chan ~= nil and enable:get() == 1 and arming:is_armed() then
    send_frame(now)
  end
  return update, RUN_MS
end

say(MAV_SEVERITY_INFO, "m4_fc.lua running")
return update()
