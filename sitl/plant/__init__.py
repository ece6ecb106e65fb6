"""The plant: the M4 in MuJoCo (rigid bodies, hip servos, thrusters with their motors, propellers,
ESCs and battery, hull drag, sensors) and the log of its true state (truth.npz). It knows nothing
of MAVLink or of the flight controller: it takes motor and servo commands and gives its state."""
