"""The flight pack: its voltage and how much charge the flight has drawn from it.

Without [plant] battery the voltage stays at the airframe's nominal voltage (the rotors'
ratings hold). With it the pack sags: open-circuit voltage from the state of charge along a
LiPo cell's discharge curve, less the internal resistance times the load.
"""

from __future__ import annotations

import numpy as np

from m4.airframe import Airframe

# A LiPo cell's open-circuit voltage against its state of charge (typical discharge curve).
_CELL_CHARGE = (0.0, 0.05, 0.1, 0.15, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0)
_CELL_OPEN_CIRCUIT_V = (3.27, 3.61, 3.69, 3.71, 3.73, 3.77, 3.79, 3.82, 3.87, 3.92, 3.98, 4.06, 4.20)
_MAH_PER_AS = 1000.0 / 3600.0


class Battery:
    def __init__(self, af: Airframe, sags: bool, charge: float = 1.0):
        """`charge`: state of charge at t = 0, 0..1 (only matters when the pack sags)."""
        self._af, self.sags, self._charge0 = af, sags, charge
        self.consumed_mah = 0.0
        self.voltage_v = self._voltage(0.0)

    @property
    def charge(self) -> float:
        return max(self._charge0 - self.consumed_mah / self._af.battery_capacity_mah, 0.0)

    def _voltage(self, current_a: float) -> float:
        af = self._af
        if not self.sags:
            return af.battery_nominal_voltage_v
        open_circuit = af.battery_cells * float(np.interp(self.charge, _CELL_CHARGE, _CELL_OPEN_CIRCUIT_V))
        return open_circuit - af.battery_internal_resistance_ohm * current_a

    def draw(self, current_a: float, dt_s: float) -> None:
        """`current_a` drawn for `dt_s`; the voltage is the pack's under that load."""
        self.draw_each([current_a], dt_s)

    def draw_each(self, currents_a: list[float], dt_s: float) -> None:
        """draw() of each current in turn, `dt_s` each (at least one; the physics steps between
        two updates of the rotors, one loop for all of them)."""
        consumed = self.consumed_mah
        for current_a in currents_a:
            consumed += (0.0 if 0.0 > current_a else current_a) * dt_s * _MAH_PER_AS   # max(., 0) without the call
        self.consumed_mah = consumed
        self.voltage_v = self._voltage(currents_a[-1])
