"""The controllers' settings and numerical thresholds.

Shared by the Python controllers and the exported C step (acroboter.codegen.export_step), so they
live below both: the code generator never imports the controllers.
"""

from __future__ import annotations

from dataclasses import field, make_dataclass
from typing import Any

import numpy as np

from .controller_parameters import OVERRIDES, PARAMETERS, check_override, runtime_vector
from .ranges import sampled_gain_problems
from .spec import Spec, integral_gain_problem
from .spec_checks import resolved_priority

# MLM: a reciprocal condition number below this means a singular system (redundant constraints).
MLM_RCOND_LIMIT = 1e-13
# The fast path (acroboter.control.fast_path): its MLM step estimates the reciprocal condition number from two fixed
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


def _from_spec(cls, spec: Spec, **overrides) -> Gains:
    """The spec's settings, with the `overrides` that are not None (unchecked: `resolve_gains` checks them)."""
    values = {p.name: p.read(spec) for p in PARAMETERS}
    values["priority"] = resolved_priority(spec)
    values.update({k: v for k, v in overrides.items() if v is not None})
    return cls(**values)


def _parameter_vector(self, servo_rows: int) -> np.ndarray:
    """The generated functions' run-time p (acroboter.model.controller_parameters.runtime_names), z zero."""
    return runtime_vector(self, servo_rows)


# The settings a controller runs with: one field per declared controller parameter (their order), then the
# saturation priority resolved from the spec's task. Derived, so a parameter is declared in one place.
Gains = make_dataclass(
    "Gains",
    [*((p.name, Any) for p in PARAMETERS), ("priority", tuple, field(default=()))],
    frozen=True,
    namespace={"from_spec": classmethod(_from_spec), "parameter_vector": _parameter_vector,
               "__doc__": "A controller's settings: every parameter of acroboter.model.controller_parameters, and the "
                          "saturation priority (the task's components, most important first)."},
)
Gains.__module__ = __name__


class GainError(ValueError):
    """An override a controller cannot run with: `name` is the parameter (as declared), `problem` why."""

    def __init__(self, name: str, problem: str):
        self.name, self.problem = name, problem
        super().__init__(f"{name}: {problem}")


def resolve_gains(spec: Spec, **overrides) -> Gains:
    """The spec's settings with `overrides` (None: none) checked and applied, every check in one place: each value
    in its declared range or choices, the servo law stable sampled at the spec's rate (naming the gain given), ki
    within Routh–Hurwitz. TypeError for an unknown name; GainError (a ValueError) naming the parameter."""
    unknown = sorted(set(overrides) - set(OVERRIDES))
    if unknown:
        raise TypeError(f"unknown controller setting(s) {', '.join(unknown)}: use {', '.join(OVERRIDES)}")
    for name, value in overrides.items():
        if (problem := check_override(name, value)) is not None:
            raise GainError(name, problem)
    gains = Gains.from_spec(spec, **overrides)
    given = (overrides.get("kp") is not None, overrides.get("kd") is not None)
    for name, problem in sampled_gain_problems(gains.kp, gains.kd, spec.controller.rate_hz, ("kp", "kd"), given):
        raise GainError(name, problem)
    if (problem := integral_gain_problem(gains.kp, gains.kd, gains.ki)) is not None:
        raise GainError("ki", problem)
    return gains
