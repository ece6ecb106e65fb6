"""The shared floor of the M4 project: what the onboard companion and the simulator both read.

- `airframe`: the one source of the robot's numbers (`airframes/m4_reference.toml`).
- `attitude`: quaternions, Euler angles and rotations (numpy only).
- `fault_kind`: what fails on a rotor, numbered as the dialect's M4_FAULT_KIND (the detector's
  verdict, the plant's injected failure, the logs).
- `toml_fields`: validated TOML tables whose errors name the key.
- `units`: unit conversions (rad/s and rpm).
- `mission`, `mission_plan`: the scenario file's `[mission]` and the plan it makes in time.
- `mavlink`: the project's dialect (MAVLink 2 only), transports, signing and tlogs.
- `feed`: the Zenoh feed's keys, payloads, settings and sessions.

Nothing here imports CasADi, MuJoCo or matplotlib.
"""
