"""The controllers' settings and numerical thresholds.

Shared by the Python controllers and the exported C step (acroboter.codegen.export_step), so they
live below both: the code generator never imports the controllers.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .spec import Spec

# MLM: a reciprocal condition number below this means a singular system (redundant constraints).
MLM_RCOND_LIMIT = 1e-13
# Eigenvalues of G below this fraction of its mean eigenvalue are internal forces (round-off leaves
# them at ~1e-15 relative where they are exactly zero).
RANK_TOLERANCE = 1e-9
# Weight of the secondary objective on the internal forces in the bounded QP (lexicographic case),
# relative to G's mean eigenvalue.
SECONDARY_WEIGHT = 1e-9
# The penalty methods' weighted secondary objective (redundant inputs), relative likewise: it sets
# how tightly the internal force stays at u_pref. On the four-cable crane's 55 s path with u_pref =
# 20 N (tension range; max position error 0.062 mm in all three): 4e-6: 17.1..23.3 N; 1e-5:
# 19.0..21.5 N; 1e-4: 20.0..20.4 N. A u_pref far from the need (152.5 N) also pulls real directions:
# 0.07, 0.09, 0.41 mm. The internal force's share of the fit there is 4e-10..8e-9 of G's mean
# eigenvalue, its other directions' share at least 0.16.
PENALTY_SECONDARY_WEIGHT = 1e-5


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

    @classmethod
    def from_spec(cls, spec: Spec, **overrides) -> Gains:
        c, p = spec.controller, spec.controller.penalty
        gains = cls(c.kp, c.kd, p.alpha_geometric, p.alpha_servo, p.omega, p.mu, p.recovery, p.kappa, c.ki)
        return replace(gains, **{k: v for k, v in overrides.items() if v is not None})

    def parameter_vector(self, servo_rows: int) -> np.ndarray:
        """The generated functions' p = [k_P, k_D, α̃, α̂, Ω, μ, k_I, z] (acroboter.codegen.structured.PARAMS,
        then the servo-constraints' integral z, one per row, here zero: the controller writes it each step)."""
        scalars = [self.kp, self.kd, self.alpha_geometric, self.alpha_servo, self.omega, self.mu, self.ki]
        return np.concatenate([scalars, np.zeros(servo_rows)])
