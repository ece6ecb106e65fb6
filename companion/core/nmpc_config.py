"""Settings of the NMPC: horizon, step, weights and bounds, frozen once built.

The cost is the paper's quadratic tracking cost, in squared-residual form:

    sum_{k<N} |x_k - x_ref_k|^2_Q + |u_k - u_hover|^2_R  +  |x_N - x_ref_N|^2_(terminal_scale Q)

Thrust is penalised as its deviation from the per-rotor hover thrust (not as raw thrust): a
raw-thrust penalty pulls every thrust down and costs altitude while it is transient, the
deviation does not. Yaw and yaw rate carry no weight (yaw is free: after a rotor loss the
robot spins). A small weight pulls the hips to the nominal posture (or the pinned one), so
the legs move only when that helps; the hip entries of a caller's reference are ignored.
Weights are diagonal and enter the compiled functions as parameters, so changing them never
recompiles anything.

Two weights are set against what the ROM leaves out. With the legs as their three lumps (the
plant's inertia, 25 % below the old legs-at-thrusters model) a cheap hip acceleration made the
legs the NMPC's fastest attitude actuator: bang-bang leg swings (hip accelerations at their
50 rad/s^2 bound) whose reaction torques and servo lag the ROM does not have, so fault-free
agile flight on the MuJoCo plant at 10 Hz diverged. hip_accel = 5e-4 keeps the legs as slow
as the servos follow (about 3 rad/s^2 RMS). The roll/pitch rate weight damps the swing a
rotor loss starts: at 10 Hz a held thrust step spins the body for a whole period, and 0.5
let the recovery limit-cycle at +-30 deg.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from companion.core import rom

SCHEMES = ("sqp", "rti")


@dataclass(frozen=True)
class NmpcWeights:
    """Diagonal weights of the cost, per unit of the state and input (SI, rad)."""

    position: tuple[float, float, float] = (20.0, 20.0, 40.0)
    roll_pitch: float = 20.0
    hip: float = 0.2
    velocity: tuple[float, float, float] = (4.0, 4.0, 6.0)
    roll_pitch_rate: float = 3.0
    hip_rate: float = 0.01
    thrust: float = 0.01
    hip_accel: float = 5e-4
    terminal_scale: float = 5.0
    horizontal_saturated_scale: float = 0.1   # north and east position and velocity weights times this
                                               # while the plans saturate the rotors (altitude_first)

    def state_diag(self) -> np.ndarray:
        q = np.zeros(rom.NX)
        q[rom.P] = self.position
        q[rom.EULER] = (self.roll_pitch, self.roll_pitch, 0.0)         # yaw free
        q[rom.HIP] = self.hip
        q[rom.V] = self.velocity
        q[rom.RATES] = (self.roll_pitch_rate, self.roll_pitch_rate, 0.0)  # yaw rate free
        q[rom.HIP_RATE] = self.hip_rate
        return q

    def input_diag(self) -> np.ndarray:
        r = np.zeros(rom.NU)
        r[rom.THRUST] = self.thrust
        r[rom.HIP_ACCEL] = self.hip_accel
        return r

    def validate(self) -> None:
        values = np.concatenate([self.state_diag(), self.input_diag(), [self.terminal_scale,
                                                                         self.horizontal_saturated_scale]])
        if not np.all(np.isfinite(values)) or np.any(values < 0):
            raise ValueError("NmpcWeights: every weight must be finite and >= 0")
        if not 0 <= self.horizontal_saturated_scale <= 1:
            raise ValueError("NmpcWeights: horizontal_saturated_scale must lie in [0, 1]")
        if self.thrust <= 0 or self.hip_accel <= 0:
            raise ValueError("NmpcWeights: thrust and hip_accel weights must be > 0 (they keep the QP convex)")


@dataclass(frozen=True)
class NmpcConfig:
    """horizon stages of dt_s seconds; fixed_hip_rad pins every hip (the fixed-posture variant).

    control_period_s: how often the controller is re-solved (None: every dt_s); the warm start
    is the previous plan shifted by control_period_s / dt_s stages, and when it is shorter than
    dt_s the hip bounds are also enforced at its end (the only stretch of a plan ever flown).
    time_budget_share: the share of the control period a solve may take; it stops iterating when
    the next iteration would end past it (the plan so far is used; 0: no budget).
    scheme: "sqp" iterates the Gauss-Newton SQP towards the optimum at every solve; "rti" is the
    real-time iteration (companion.core.rti): one QP per solve, prepared by `Nmpc.prepare`
    before the state arrives (max_iterations, cost_tol_rel and the time budget are the SQP's).
    """

    horizon: int = 5
    dt_s: float = 0.1
    rk4_substeps: int = 1
    weights: NmpcWeights = field(default_factory=NmpcWeights)
    roll_pitch_max_rad: float = math.radians(90.0)
    fixed_hip_rad: float | None = None
    control_period_s: float | None = None
    max_iterations: int = 10
    cost_tol_rel: float = 1e-5         # converged when the QP step would lower the cost by less than this
    time_budget_share: float = 0.0     # of the control period (dt_s when none is given); 0: unbounded
    scheme: str = "rti"
    codegen: bool = True               # compile the linearisation to C (cached); False: CasADi's VM (the
                                       # controller's detector and disturbance estimate follow it)

    def validate(self) -> None:
        if self.scheme not in SCHEMES:
            raise ValueError(f"NmpcConfig.scheme must be one of {', '.join(map(repr, SCHEMES))}, got {self.scheme!r}")
        if self.horizon < 1:
            raise ValueError(f"NmpcConfig.horizon must be >= 1, got {self.horizon}")
        if not (math.isfinite(self.dt_s) and self.dt_s > 0):
            raise ValueError(f"NmpcConfig.dt_s must be > 0, got {self.dt_s}")
        if self.rk4_substeps < 1:
            raise ValueError(f"NmpcConfig.rk4_substeps must be >= 1, got {self.rk4_substeps}")
        if not 0 < self.roll_pitch_max_rad <= math.pi / 2:
            raise ValueError("NmpcConfig.roll_pitch_max_rad must lie in (0, pi/2]")
        if self.max_iterations < 1:
            raise ValueError(f"NmpcConfig.max_iterations must be >= 1, got {self.max_iterations}")
        if not 0.0 <= self.time_budget_share <= 1.0:
            raise ValueError(f"NmpcConfig.time_budget_share must lie in [0, 1], got {self.time_budget_share}")
        if self.control_period_s is not None and not self.control_period_s > 0:
            raise ValueError(f"NmpcConfig.control_period_s must be > 0, got {self.control_period_s}")
        self.weights.validate()

    @property
    def time_budget_s(self) -> float | None:
        """How long a solve may take (None: as long as its iterations take)."""
        period = self.dt_s if self.control_period_s is None else self.control_period_s
        return self.time_budget_share * period if self.time_budget_share > 0 else None

    @property
    def warm_start_shift(self) -> float:
        """Stages the previous plan moves forward between two solves."""
        period = self.dt_s if self.control_period_s is None else self.control_period_s
        return period / self.dt_s
