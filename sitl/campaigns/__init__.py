"""Many flights: the fault grid (`m4-sitl campaign`), the detection campaign, posture against a fixed
posture (`m4-sitl compare`), and the engines that fly them in parallel."""
