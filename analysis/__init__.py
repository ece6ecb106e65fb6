"""Figures and metrics of a flight from its tlog alone, real or simulated: no MuJoCo, and
matplotlib only in `analysis.figures` (the `plot` extra). Used by `m4-companion plot` on a
laptop and by `m4-sitl fly` on its own flights."""
