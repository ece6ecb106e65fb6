"""The MuJoCo plant as ArduPilot's physics: the JSON interface of ArduPilot's SITL (servo packets
in, sensor lines out), in lockstep, with the scenario's faults and the truth log."""
