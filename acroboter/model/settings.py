"""The controllers' settings and numerical thresholds.

Shared by the Python controllers and the exported C step (acroboter.codegen.export_step), so they
live below both: the code generator never imports the controllers.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .spec import Spec
from .spec_checks import resolved_priority

# MLM: a reciprocal condition number below this means a singular system (redundant constraints).
MLM_RCOND_LIMIT = 1e-13
# The fast path (acroboter.control.fast): its MLM step estimates the reciprocal condition number from two fixed
# probe vectors (never below the true one, like gecon's, but cruder: up to the system's size, 22 on the default
# crane, above it); a step whose estimate is below MLM_RCOND_LIMIT times this margin goes to the reference path,
# whose gecon decides as it always did.
FAST_RCOND_MARGIN = 1e3
# A step saturates when no input within the limits causes the servo-constraint accelerations the
# unbounded input would, to this fraction of max(1, their size): a limit that only moves internal
# forces (redundant inputs) is not saturation, whatever distribution the method then applies. Shared by
# the Python controllers' anti-windup and the stateful exported controller's (acroboter.codegen.controller_c).
SATURATION_TOLERANCE = 1e-6
# Eigenvalues of G below this fraction of its mean eigenvalue are internal forces (round-off leaves
# them at ~1e-15 relative where they are exactly zero).
RANK_TOLERANCE = 1e-9
# Weight of the secondary objective on the internal forces in the bounded QP (lexicographic case),
# relative to G's mean eigenvalue.
SECONDARY_WEIGHT = 1e-9
# The weighted secondary objective, relative likewise: the explicit recoveries eq12/eq13 with redundant
# inputs, where a limit is in the way (their unbounded fit is unique). The projected recovery (default)
# no longer uses it: its distribution is lexicographic in the servo accelerations
# (acroboter.control.distribution.BoundedInputs.solve_task), because this weight also pulled the task
# directions: on the four-cable crane's 55 s path, preferred = 152.5 N (the middle of [5, 300] N) gave
# 0.0976 mm against 0.0617 mm with 20 N (Penalty); the lexicographic form gives 0.0617 mm for both.
PENALTY_SECONDARY_WEIGHT = 1e-5
# Saturation as underactuation (acroboter.control.underactuation): a task direction that the inputs still free
# move at less than this fraction of the rate all inputs together move it is released, not forced (forcing it
# would ask more than 10 times the inputs). On the default crane the thrusts alone tilt the SU at 0.0013 of the
# winches' rate (E's level rows), so with every winch held the level is released, not flown on the fans. At 1e-2
# the yaw torque, once the yaw was released, was spent on the position and level through its weak coupling to
# them: on a planned path flown faster than planned it ran away to 1374-7300 N·m and 7 of 9 runs diverged; at
# 1e-1 none of the 18 planned runs diverged (docs/saturation.md, 2026-12-03).
UNDERACTUATION_RANK_TOLERANCE = 1e-1


# The sanity bound on a command (docs/controller.md, "Fail safe"): besides its limits, a force input (winch tension,
# thrust) is at most this many times the crane's weight (gravity taken at least 9.81 m/s²) and a torque at most as
# much times the largest distance of a body point from its body's centre (at least 0.1 m). A command beyond it is
# never applied: the stateful controller holds its last good command instead and says so.
COMMAND_BOUND_FACTOR = 5.0


def command_bounds(spec: Spec) -> tuple[np.ndarray, np.ndarray]:
    """(low, high) per input in its own unit: the spec's limits intersected with the sanity bound ±B, B = factor ×
    weight / |gain| (× the largest lever for a torque)."""
    weight = sum(b.mass for b in spec.bodies) * max(float(np.linalg.norm(spec.gravity)), 9.81)
    lever = max([0.1, *(float(np.linalg.norm(p)) for b in spec.bodies for p in map(b.point, b.points))])
    low, high, _ = spec.input_limits()
    bound = np.array([COMMAND_BOUND_FACTOR * weight * (lever if a.kind == "body_torque" else 1.0) / abs(a.gain)
                      for a in spec.actuators])
    return np.maximum(low, -bound), np.minimum(high, bound)


@dataclass(frozen=True)
class Gains:
    kp: float
    kd: float
    alpha_geometric: float
    alpha_servo: float
    omega: float
    mu: float
    recovery: str
    kappa: float
    ki: float = 0.0  # integral action on the servo-constraints (docs/integral_action.md); 0: the PD law
    # How a limit is met (docs/saturation.md): "qp" (bounded least squares) or "underactuation"; for the latter
    # the task components most important first, and the hysteresis that brings the full task back.
    saturation: str = "qp"
    priority: tuple[str, ...] = ()
    dwell: float = 0.1
    release_margin: float = 0.001

    @classmethod
    def from_spec(cls, spec: Spec, **overrides) -> Gains:
        c, p = spec.controller, spec.controller.penalty
        gains = cls(c.kp, c.kd, p.alpha_geometric, p.alpha_servo, p.omega, p.mu, p.recovery, p.kappa, c.ki,
                    c.saturation, resolved_priority(spec), c.underactuation.dwell, c.underactuation.margin)
        return replace(gains, **{k: v for k, v in overrides.items() if v is not None})

    def parameter_vector(self, servo_rows: int) -> np.ndarray:
        """The generated functions' p = [k_P, k_D, α̃, α̂, Ω, μ, k_I, z] (acroboter.codegen.structured.PARAMS,
        then the servo-constraints' integral z, one per row, here zero: the controller writes it each step)."""
        scalars = [self.kp, self.kd, self.alpha_geometric, self.alpha_servo, self.omega, self.mu, self.ki]
        return np.concatenate([scalars, np.zeros(servo_rows)])
