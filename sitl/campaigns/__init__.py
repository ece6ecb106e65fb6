"""Many flights (`m4-sitl campaign`): the fault grid, the detection campaign, and the engines that
fly them in parallel."""
