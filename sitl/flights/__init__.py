"""One flight end to end (`m4-sitl fly`, model matching): the SITL and the companion
started as processes, their records read back, metrics.json, figures and video."""
