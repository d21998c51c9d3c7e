"""Bounded input distribution: the inputs closest to what the controller asks, within the limits.

Every controller ends with a small least-squares problem in the inputs u (l of them):

    primary     minimise ½ uᵀ G u + gᵀ u        (G positive semidefinite, l × l)
    subject to  min ≤ u ≤ max                   (the spec's limits: a winch never pushes)
    secondary   among the primary's minimisers, the one closest to u_pref (½|u − u_pref|²)

G and g come from the controller: the projected recovery's fit of the servo force in the M⁻¹
metric (penalty methods), or the servo-constraint accelerations |E u − e|² (MLM). The secondary
objective is the tension distribution of cable robots: where there are more inputs than the task
needs (four winches for the three of them a position and a level need), the primary leaves the
internal forces, the cables pulling against each other, free; they are set to the spec's
preferred values (`preferred`, default the middle of the limits) instead of growing without bound.

How it is solved:
1. If the caller has an unbounded solution it trusts (the unique one when the inputs are not
   redundant, computed as it always was) and it is within the limits, that is the answer: the
   results of a crane whose limits are never reached are those of an unbounded controller.
2. Otherwise, with G's scale taken as its mean eigenvalue tr(G)/l: lexicographic (MLM, weight 0):
   G is decomposed (LAPACK syevd, l × l), directions with an eigenvalue below RANK_TOLERANCE × the
   scale are internal forces Z (exactly free: MLM's E u = e has a family of solutions), and the
   solution is the minimum-norm least squares plus Z Zᵀ u_pref. Weighted (the penalty methods' fit,
   weight = PENALTY_SECONDARY_WEIGHT): ½ μ|u − u_pref|² with μ = weight × scale is added
   throughout, and (G + μI) u = μ u_pref − g is solved by Cholesky. The projected fit is never exact on a
   non-collocated crane, and there the cables' internal force moves its residual by 4e-10..8e-9 of
   G's mean eigenvalue, depending on the configuration: taken literally it would drive the cables
   to their limits for next to nothing (seen on the four-cable crane); the weighted form keeps them
   near the preferred level wherever the fit cares less than μ, and changes the rest by
   ~μ / (eigenvalue) relative (see PENALTY_SECONDARY_WEIGHT for the trade).
   Within the limits: done.
3. Otherwise a strictly convex QP with simple bounds: the Hessian of step 2 (the internal
   directions of the lexicographic case weighted by SECONDARY_WEIGHT × the scale), solved
   by DAQP, a dual active-set solver for small dense QPs (a workspace set up once, no allocation per
   solve). The inputs that end on a limit are reported in `limit_state` (DAQP's active set):
   saturation is never silent.
"""

from __future__ import annotations

import math

import daqp
import numpy as np
from scipy.linalg import lapack

from ..model.settings import RANK_TOLERANCE, SECONDARY_WEIGHT

# DAQP's feasibility tolerance on the bounds it leaves inactive (its default, 1e-6, is loose for N).
PRIMAL_TOLERANCE = 1e-9


class DistributionError(RuntimeError):
    """The QP solver did not return an optimal solution (the controller reports it, never NaN)."""


class BoundedInputs:
    """Solve the bounded, prioritised least squares above for one controller (buffers reused)."""

    def __init__(self, lower: np.ndarray, upper: np.ndarray, preferred: np.ndarray, weight: float = 0.0):
        """`weight` > 0: the secondary objective is always on, ½ weight·tr(G)/l |u − u_pref|² added to
        the primary, for fits whose internal-force directions are not
        exactly free (see the module docstring); 0: strictly lexicographic."""
        self.lower = np.asarray(lower, dtype=float).copy()
        self.upper = np.asarray(upper, dtype=float).copy()
        self.preferred = np.asarray(preferred, dtype=float).copy()
        self.weight = float(weight)
        l = self.lower.size
        self.l = l
        self.bounded = bool(np.isfinite(self.lower).any() or np.isfinite(self.upper).any())
        self.u = np.zeros(l)
        self.unbounded = np.zeros(l)  # the last solve's solution without limits (what the controller asked)
        self.bounded_step = False  # True when the last solve had to bound the input (the QP ran)
        self.limit_state = np.zeros(l, dtype=np.int8)
        self._syevd, self._potrf, self._potrs = lapack.get_lapack_funcs(("syevd", "potrf", "potrs"),
                                                                        (np.zeros((1, 1)),))
        self._hessian = np.zeros((l, l))
        self._diagonal = self._hessian.reshape(-1)[:: l + 1]  # a view: the diagonal of _hessian
        self._sign = np.zeros(l)
        self._gradient = np.zeros(l)
        self._none = np.zeros((0, l))
        self._qp = daqp.Model()
        self._qp.setup(np.eye(l), np.zeros(l), self._none, self.upper, self.lower)
        self._qp.settings = {"primal_tol": PRIMAL_TOLERANCE}
        self.qp_solves = 0  # how many steps needed the QP (diagnostics)

    def within_limits(self, u: np.ndarray) -> bool:
        return not (np.less(u, self.lower).any() or np.greater(u, self.upper).any())

    def accept(self, u: np.ndarray) -> bool:
        """Take a trusted unbounded solution if it is within the limits (step 1)."""
        if not self.bounded or self.within_limits(u):
            self.u[:] = u
            self.limit_state[:] = 0
            self.bounded_step = False
            return True
        return False

    def solve(self, hessian: np.ndarray, gradient: np.ndarray) -> np.ndarray:
        """The bounded, prioritised minimiser (steps 2 and 3); writes self.u and self.limit_state."""
        # G's scale: its mean eigenvalue. Exact and cheap (also in the exported C, which needs no
        # eigenvalue solver for it); between 1/l of the largest eigenvalue and the largest.
        scale = float(hessian.trace()) / self.l
        if not math.isfinite(scale + float(gradient @ gradient)):
            raise DistributionError("the input distribution's terms are not finite")
        np.copyto(self._hessian, hessian)
        self._gradient[:] = gradient
        if self.weight > 0:
            # Weighted: (G + μI) u = μ u_pref − g, μ = weight · scale (positive definite: Cholesky).
            mu = self.weight * scale if scale > 0 else 1.0
            self._diagonal += mu
            self._gradient -= mu * self.preferred
            chol, info = self._potrf(self._hessian, lower=False, overwrite_a=False, clean=False)
            if info != 0:
                raise DistributionError(f"G + μI is not positive definite (LAPACK potrf info {info})")
            u, _ = self._potrs(chol, -self._gradient, lower=False)
        else:
            # Lexicographic: minimum-norm least squares + the internal forces (Z) at u_pref.
            eigenvalues, vectors, info = self._syevd(hessian, compute_v=1, lower=0)
            if info != 0 or not np.isfinite(eigenvalues).all():
                raise DistributionError(f"the distribution's G could not be decomposed (LAPACK syevd info {info})")
            internal = eigenvalues <= RANK_TOLERANCE * scale if scale > 0 else np.ones(self.l, dtype=bool)
            kept = ~internal
            u = -(vectors[:, kept] @ ((vectors[:, kept].T @ gradient) / eigenvalues[kept]))
            z = vectors[:, internal]
            if z.size:
                u += z @ (z.T @ self.preferred)
                # For the QP: the internal forces get a small weight, so that it is strictly convex.
                mu = SECONDARY_WEIGHT * scale if scale > 0 else 1.0
                self._hessian += mu * (z @ z.T)
                self._gradient -= mu * (z @ (z.T @ self.preferred))
        self.unbounded[:] = u
        if self.within_limits(u):
            self.u[:] = u
            self.limit_state[:] = 0
            self.bounded_step = False
            return self.u
        # Bounded: the strictly convex QP with simple bounds.
        self.bounded_step = True
        self._hessian += self._hessian.T  # exactly symmetric: the mean of G and Gᵀ
        self._hessian *= 0.5
        self._qp.update(H=self._hessian, f=self._gradient)
        x, _, exitflag, info = self._qp.solve()
        self.qp_solves += 1
        if exitflag < 1 or not math.isfinite(float(x @ x)):
            raise DistributionError(
                f"the bounded input distribution failed (DAQP exit flag {exitflag}): the limits or the "
                "controller's terms are inconsistent"
            )
        # The active set is DAQP's: a bound with a nonzero multiplier holds its input (exactly on it;
        # negative multipliers are lower bounds). Inactive bounds hold to PRIMAL_TOLERANCE: snap those too.
        np.sign(info["lam"], out=self._sign)
        self.limit_state[:] = self._sign
        np.maximum(x, self.lower, out=self.u)
        np.minimum(self.u, self.upper, out=self.u)
        return self.u
