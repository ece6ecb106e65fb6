"""What the ESCs tell the flight controller, as ArduPilot's AP_ESC_Telem gathers it.

- RPM: bidirectional DShot answers every output frame of the FC (`sample()` at every FC
  tick) with the rotor's electrical period in microseconds as a 9-bit mantissa and a 3-bit
  exponent; the FC turns it into mechanical RPM (eRPM / pole pairs). A period too long for
  the encoding reads as 0 rpm. Commutation jitter (sensor noise) is on the period.
- Voltage, current, temperature and consumption: each ESC's serial telemetry, polled in
  turn at the airframe's serial_telemetry_hz per ESC, with resolutions 0.01 V, 0.01 A,
  1 degC and 1 mAh; `count` counts these packets per ESC (wrapping at 65536). The ESC
  measures its own consumption; its temperature rises with its current (first order).
- Every sample reaches the FC telemetry_delay_s after the instant it describes.

`report()` gives ESC_TELEMETRY_1_TO_4's fields as ArduPilot fills them: temperature (degC),
voltage (cV), current (cA), totalcurrent (mAh), rpm and count, unsigned 16-bit (8-bit for
the temperature), truncated. Noise only when the scenario asks for sensor noise.
"""

from __future__ import annotations

import collections
import math
from dataclasses import dataclass

import numpy as np

from m4.airframe import ROTOR_COUNT, Airframe
from m4.mavlink import mavlink
from m4.units import RAD_S_TO_RPM
from sitl.plant.state import RotorState

_US_PER_MINUTE = 60e6
_MANTISSA_BITS = 9                   # DShot telemetry: 9-bit mantissa
_MANTISSA_MAX = (1 << _MANTISSA_BITS) - 1
_EXPONENT_MAX = 7                    # 3-bit exponent
_UINT16 = 65535
_MAH_PER_AS = 1000.0 / 3600.0


def dshot_rpm(rpm: np.ndarray, pole_pairs: int) -> np.ndarray:
    """Mechanical RPM as the FC decodes it from bidirectional DShot's period encoding."""
    return np.array([_dshot_rpm(r, pole_pairs) for r in np.asarray(rpm, dtype=float).tolist()])


def _dshot_rpm(rpm: float, pole_pairs: int) -> float:
    erpm = rpm * pole_pairs
    period_us = _US_PER_MINUTE / erpm if erpm > 0.0 else math.inf
    if not period_us < (_MANTISSA_MAX + 1) << _EXPONENT_MAX:
        return 0.0
    period = int(period_us)
    exponent = period.bit_length() - _MANTISSA_BITS
    exponent = 0 if 0 > exponent else exponent         # the least that fits the mantissa (max(., 0), no call: every tick)
    decoded_us = (period >> exponent) << exponent
    return _US_PER_MINUTE / (decoded_us * pole_pairs) if decoded_us > 0 else 0.0


@dataclass(frozen=True)
class EscReport:
    """ESC_TELEMETRY_1_TO_4's fields for rotors 1..4."""
    temperature: list[int]
    voltage: list[int]
    current: list[int]
    totalcurrent: list[int]
    rpm: list[int]
    count: list[int]

    def message(self) -> mavlink.MAVLink_esc_telemetry_1_to_4_message:
        return mavlink.MAVLink_esc_telemetry_1_to_4_message(self.temperature, self.voltage, self.current,
                                                            self.totalcurrent, self.rpm, self.count)


class EscTelemetry:
    def __init__(self, af: Airframe, tick_ms: int, noise: bool = False, seed: int = 0):
        self._af, self._tick_ms, self._noise = af, tick_ms, noise
        self._rng = np.random.default_rng([seed, 1])        # a stream of its own beside the plant's sensors
        self._delay_ms = round(af.esc_telemetry_delay_s * 1000.0)
        self._serial_period_ms = round(1000.0 / af.esc_serial_telemetry_hz)
        # ESC i answers at i / 4 of the polling period: the FC asks them in turn.
        self._serial_next_ms = [i * self._serial_period_ms // ROTOR_COUNT for i in range(ROTOR_COUNT)]
        self._next_ms = 0
        self._last_ms: int | None = None
        self._decay = (math.nan, math.nan)                  # (dt_s, the temperature's decay over it)
        self._temperature_c = [af.esc_ambient_temperature_c] * ROTOR_COUNT     # Python floats: four numbers
        self._consumed_mah = [0.0] * ROTOR_COUNT
        self._count = [0] * ROTOR_COUNT                      # serial packets received, per ESC
        # Samples on their way to the FC: (arrival_ms, rotor or None for the RPM of all, values)
        self._in_flight: collections.deque = collections.deque()
        self._rpm = [0] * ROTOR_COUNT
        self._serial = [(0, 0, 0, 0)] * ROTOR_COUNT          # (temperature, voltage, current, totalcurrent)

    def sample(self, now_ms: int, truth: RotorState) -> None:
        """At an output frame of the FC (once per tick; other calls are ignored): the ESCs
        measure the rotors' truth."""
        if now_ms < self._next_ms:
            return
        self._next_ms = (now_ms // self._tick_ms + 1) * self._tick_ms
        self._integrate(now_ms, truth)
        arrival = now_ms + self._delay_ms
        self._in_flight.append((arrival, None, self._measured_rpm(truth)))
        for i in range(ROTOR_COUNT):
            if now_ms >= self._serial_next_ms[i]:
                while self._serial_next_ms[i] <= now_ms:
                    self._serial_next_ms[i] += self._serial_period_ms
                self._in_flight.append((arrival, i, self._serial_packet(i, truth)))

    def _integrate(self, now_ms: int, truth: RotorState) -> None:
        af = self._af
        dt_s = 0.0 if self._last_ms is None else (now_ms - self._last_ms) / 1000.0
        self._last_ms = now_ms
        if dt_s != self._decay[0]:           # the tick, but for the first sample
            self._decay = (dt_s, math.exp(-dt_s / af.esc_thermal_time_constant_s))
        decay = self._decay[1]
        ambient_c, rise_c_per_a = af.esc_ambient_temperature_c, af.esc_temperature_rise_c_per_a
        consumed, temperature = self._consumed_mah, self._temperature_c
        for i, current in enumerate(map(float, truth.esc_current_a)):
            current = 0.0 if 0.0 > current else current          # max(current, 0) without the call
            consumed[i] += current * dt_s * _MAH_PER_AS
            steady = ambient_c + rise_c_per_a * current
            temperature[i] = steady + (temperature[i] - steady) * decay

    def _measured_rpm(self, truth: RotorState) -> list[int]:
        rpm = [w * RAD_S_TO_RPM for w in map(float, truth.rotor_speed_rad_s)]
        if self._noise:
            rpm = (np.array(rpm) / (1.0 + self._rng.normal(0.0, self._af.esc_rpm_noise_fraction, ROTOR_COUNT))).tolist()
        pole_pairs = self._af.motor_pole_pairs
        # max(r, 0), then min(decoded, _UINT16): without the builtins' calls
        return [_UINT16 if _UINT16 < (d := int(_dshot_rpm(0.0 if 0.0 > r else r, pole_pairs))) else d for r in rpm]

    def _serial_packet(self, i: int, truth: RotorState) -> tuple[int, int, int, int]:
        af = self._af
        voltage_v, current_a = truth.battery_voltage_v, float(truth.esc_current_a[i])
        if self._noise:
            voltage_v += self._rng.normal(0.0, af.esc_voltage_noise_v)
            current_a += self._rng.normal(0.0, af.esc_current_noise_a)
        return (int(min(max(self._temperature_c[i], 0), 255)), _u16(100.0 * voltage_v), _u16(100.0 * current_a),
                _u16(self._consumed_mah[i]))

    def _arrived(self, now_ms: int) -> None:
        """Take in the samples that have reached the FC by `now_ms`."""
        while self._in_flight and self._in_flight[0][0] <= now_ms:
            _, rotor, values = self._in_flight.popleft()
            if rotor is None:
                self._rpm = values
            else:
                self._serial[rotor] = values
                self._count[rotor] = (self._count[rotor] + 1) % (_UINT16 + 1)

    def rpm(self, now_ms: int) -> list[int]:
        """report(now_ms).rpm, without building the rest of the report (the FC reads it every tick)."""
        self._arrived(now_ms)
        return list(self._rpm)

    def report(self, now_ms: int) -> EscReport:
        """What the FC knows of its ESCs at `now_ms`."""
        self._arrived(now_ms)
        temperature, voltage, current, total = (list(col) for col in zip(*self._serial))
        return EscReport(temperature=temperature, voltage=voltage, current=current, totalcurrent=total,
                         rpm=list(self._rpm), count=list(self._count))


def _u16(value: float) -> int:
    return int(min(max(value, 0.0), _UINT16))
