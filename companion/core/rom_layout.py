"""The reduced-order model's state, input and disturbance layout (no CasADi: the telemetry
and the feed index states with these too; `rom` documents what each entry means).

State x (20): p_ned_m (3), euler_rad (3), hip_rad (4), v_ned_m_s (3), rates_frd_rad_s (3),
hip_rate_rad_s (4). Input u (8): thrust_n (4), hip_accel_rad_s2 (4). Disturbance d (6).
"""

NX = 20
NU = 8
ND = 6

# Slices into the state and input vectors.
P = slice(0, 3)
EULER = slice(3, 6)
HIP = slice(6, 10)
V = slice(10, 13)
RATES = slice(13, 16)
HIP_RATE = slice(16, 20)
THRUST = slice(0, 4)
HIP_ACCEL = slice(4, 8)
