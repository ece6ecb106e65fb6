"""Unit conversions the simulator and the companion share: multiply a value in the first unit
by the constant to get it in the second."""

import math

RAD_S_TO_RPM = 60.0 / (2.0 * math.pi)
RPM_TO_RAD_S = 2.0 * math.pi / 60.0
