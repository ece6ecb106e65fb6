"""Research, baselines and benchmarks: code that measures the onboard controller but never flies.

Static allocation over posture (`allocation`), the ArduCopter-style thrust-loss check the
detector is compared with (`thrust_loss_baseline`), the closed loop on the reduced-order model
(`rom_sim`), the same NMPC problem solved by IPOPT (`nmpc_ipopt`) and the NMPC bench behind
`m4-companion bench` (`nmpc_bench`). Installed with the project and free of MuJoCo, so the
bench runs on the robot; no onboard module imports it.
"""
