"""Links as the robot meets them: delay and loss emulated inside the SITL (`emulation`), a UDP
delay/loss proxy between two processes (`netem_proxy`), a fuzzed-frame flooder (`fuzz_flood`)."""
