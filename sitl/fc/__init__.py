"""The simulated flight controller: what a real FC does between the plant and the companion
(MAVLink streams, commands, modes, setpoint checks and failsafes, the 4 ms fast loops, ESC
telemetry, routing between links). It reads the plant's sensed state, never flights or campaigns."""
