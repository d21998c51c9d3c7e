"""Bounded input distribution: the inputs closest to what the controller asks, within the limits.

Every controller ends with a small least-squares problem in the inputs u (l of them):

    primary     minimise ½ uᵀ G u + gᵀ u        (G positive semidefinite, l × l)
    subject to  min ≤ u ≤ max                   (the spec's limits: a winch never pushes)
    secondary   among the primary's minimisers, the one closest to u_pref (½|u − u_pref|²)

G and g come from the controller: the servo-constraint accelerations, |E u + F λ̂|² for the penalty methods'
projected recovery (those of the ideal servo force, F = σ_q P σ_qᵀ), |E u − e|² for MLM. The secondary
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
   solution is the minimum-norm least squares plus Z Zᵀ u_pref. Weighted (weight > 0; the explicit
   recoveries eq12/eq13 with redundant inputs, where a limit is in the way):
   ½ μ|u − u_pref|² with μ = weight × scale is added throughout, and (G + μI) u = μ u_pref − g is
   solved by Cholesky. Within the limits: done.
3. Otherwise a strictly convex QP with simple bounds: the Hessian of step 2 (the internal
   directions of the lexicographic case weighted by SECONDARY_WEIGHT × the scale), solved
   by DAQP, a dual active-set solver for small dense QPs (a workspace set up once, no allocation per
   solve). The inputs that end on a limit are reported in `limit_state` (DAQP's active set):
   saturation is never silent.

The penalty methods' projected fit with redundant inputs (`solve_task`): lexicographic in the
servo-constraint accelerations, as MLM. (Written when the fit was of the whole acceleration in the M⁻¹
metric, G = HᵀPH, which has no exact null space of its own: on the four-cable crane G's smallest eigenvalue
was 5e-15..1.3e-7 of its mean along the cables' internal force, and −G⁻¹g asked for −440..+480 N on the 55 s
path for next to nothing. Since 2026-12-06 G = EᵀE, whose null space is null(E) exactly; the same steps give
its lexicographic solution, and the figures below are of the earlier fit.) Its internal forces are those of
the task, the null space of E = σ_q P H (the servo-constraint accelerations per input, generated
`mlm_bounded_terms`): an input along it leaves σ̈ unchanged, whatever the fit says about the rest of
the crane. So, with Π = I − Eᵀ(EEᵀ)⁻¹E the projector onto that null space:
  (1) the fit's input in the task directions, u_F = argmin ½uᵀGu + gᵀu over u = Eᵀw:
      u_F = −Eᵀ(E G Eᵀ)⁻¹E g (Cholesky of the k × k matrix E G Eᵀ); its servo accelerations e_F = E u_F;
  (2) E u = e_F exactly, the internal forces at the preferred values: u = Π u_pref + u_F, which is
      MLM's lexicographic distribution (step 2 above) of ½|E u − e_F|², here in closed form (Cholesky
      of E Eᵀ: the null space of EᵀE is null(E)); outside the limits step 3 with the Hessian
      EᵀE + μΠ, μ = SECONDARY_WEIGHT × tr(EᵀE)/l, as MLM's.
The servo accelerations asked (e_F) do not depend on u_pref or on limits that do not bind; u_pref
moves u only along null(E). Measured on the four-cable crane's 55 s path (winches [5, 300] N):
null(E) is (−1, 1, −1, 1)/2 in the four tensions (the thrusts' and torque's share below 5e-4) and
parallel to G's weakest eigenvector (1 − |cos| ≤ 2.3e-7); what (2) gives up of the fit is at most
5.8e-6 of its optimum (the fit's weight along null(E), NᵀGN, is 4e-15..5.4e-7 of G's mean eigenvalue);
E G Eᵀ's condition number is 1.2e4. Tracking (max position error) is the same, to 1e-8 relative,
for u_pref = 20 or 152.5 N, with limits [5, 300], [5, 25] or ±1e6 N: Penalty 0.0617 mm,
Iterative Penalty (3) 0.0614 mm (MLM 0.0621 mm), every tension within 20.00..20.28 N. The weighted
form used before (½ μ|u − u_pref|² on the fit, μ = 1e-5 tr(G)/l) pulled along every direction,
also the cables' common tension (a task direction): 0.0976 mm with u_pref = 152.5 N (the default
preferred of [5, 300] N) against 0.0617 mm with 20 N, its servo accelerations off by 1e-3 m/s².
Tried as well: a rank decision on G (eigenvalues below 1e-7 or 1e-6 of the mean as internal forces,
minimum norm in the rest, then (2)) tracked alike (0.0617 mm), but G's weakest eigenvalue reaches
1.3e-7 of the mean, so any such tolerance sits next to measured values, and the C would need an
eigen-solver; the form here needs neither and is exact in the task by construction. Cost in Python:
one more generated call (E) and two 6 × 6 Choleskys, a control step of 32 µs against 24 µs.
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
        crossed = np.flatnonzero(self.lower > self.upper)
        if crossed.size:  # (the spec's schema refuses these; a caller's own limits come here)
            i = int(crossed[0])
            raise ValueError(f"input {i}: min {self.lower[i]:g} is above max {self.upper[i]:g}; give min <= max")
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

    def solve_task(self, hessian: np.ndarray, gradient: np.ndarray, servo_map: np.ndarray,
                   unbounded_only: bool = False) -> np.ndarray:
        """The fit ½uᵀGu + gᵀu with redundant inputs, lexicographic in the servo accelerations E u
        (E = servo_map, k × l, full row rank; see the module docstring): E u = e_F = E u_F exactly with
        u_F = −Eᵀ(E G Eᵀ)⁻¹E g, the internal forces (null(E)) at u_pref, then the limits.

        The eigen split of step 2 for ½|E u − e_F|² in closed form (the null space of EᵀE is null(E)):
        u = u_pref − Eᵀ(EEᵀ)⁻¹E(u_pref − u_F), by two k × k Choleskys; outside the limits, step 3's QP
        with Hessian EᵀE + μΠ, Π = I − Eᵀ(EEᵀ)⁻¹E, μ = SECONDARY_WEIGHT · tr(EᵀE)/l (as MLM's)."""
        if self.weight != 0.0:
            raise ValueError("solve_task is lexicographic: construct BoundedInputs with weight 0")
        E = servo_map
        # potrf reads the upper triangles: E G Eᵀ and E Eᵀ are symmetric up to round-off
        chol, info = self._potrf(E @ hessian @ E.T, lower=False, overwrite_a=True, clean=False)
        gram_chol, gram_info = self._potrf(E @ E.T, lower=False, overwrite_a=True, clean=False)
        if info != 0 or gram_info != 0:
            raise DistributionError("the fit is singular in the task directions: "
                                    + ("E Eᵀ" if gram_info else "E G Eᵀ")
                                    + f" is not positive definite (LAPACK potrf info {gram_info or info})")
        w, _ = self._potrs(chol, E @ gradient, lower=False)  # u_F = −Eᵀw
        y, _ = self._potrs(gram_chol, E @ self.preferred, lower=False)
        if not math.isfinite(float(w @ w) + float(y @ y)):
            raise DistributionError("the input distribution's terms are not finite")
        y += w
        u = self.preferred - E.T @ y  # Π u_pref + u_F
        if unbounded_only:  # saturation as underactuation: the full task's input, whatever the limits
            self.unbounded[:] = u
            return u
        if self._take_unbounded(u):
            return self.u
        # Step 3: ½|E u − e_F|² + ½μ|Π(u − u_pref)|², within the limits.
        np.matmul(E.T, E, out=self._hessian)
        scale = float(self._hessian.trace()) / self.l
        mu = SECONDARY_WEIGHT * scale if scale > 0 else 1.0
        projector = np.eye(self.l) - E.T @ self._potrs(gram_chol, E, lower=False)[0]
        self._hessian += mu * projector
        np.matmul(E.T, E @ (E.T @ w), out=self._gradient)  # −Eᵀe_F, e_F = E u_F
        self._gradient -= mu * (projector @ self.preferred)
        return self._bounded()

    def solve(self, hessian: np.ndarray, gradient: np.ndarray, unbounded_only: bool = False) -> np.ndarray:
        """The bounded, prioritised minimiser (steps 2 and 3); writes self.u and self.limit_state.
        `unbounded_only`: step 2's minimiser, returned whatever the limits (saturation as underactuation)."""
        # G's scale: its mean eigenvalue. Exact and cheap (also in the exported C, which needs no
        # eigenvalue solver for it); between 1/l of the largest eigenvalue and the largest.
        scale = float(hessian.trace()) / self.l
        if not (math.isfinite(scale) and np.isfinite(gradient).all()):  # (gradient @ gradient would overflow)
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
        if unbounded_only:
            self.unbounded[:] = u
            return u
        if self._take_unbounded(u):
            return self.u
        return self._bounded()

    def _take_unbounded(self, u: np.ndarray) -> bool:
        """Record the unbounded minimiser u; if it is within the limits it is the answer (True)."""
        self.unbounded[:] = u
        if not self.within_limits(u):
            return False
        self.u[:] = u
        self.limit_state[:] = 0
        self.bounded_step = False
        return True

    def _bounded(self) -> np.ndarray:
        """Step 3 with the Hessian and gradient in self._hessian, self._gradient: the strictly convex QP
        with simple bounds."""
        self.bounded_step = True
        self._hessian += self._hessian.T  # exactly symmetric: the mean of G and Gᵀ
        # In units where the mean eigenvalue is 1 (same minimiser): DAQP's tolerances are absolute
        # (sing_tol 3.7e-11, zero_tol 1e-11), so a fit in small units (tr(G)/l = 3e-6) hid the internal
        # forces' weight (SECONDARY_WEIGHT × scale) below them and missed the optimum by 1 % of u.
        scale = float(self._hessian.trace()) / (2.0 * self.l)
        self._hessian *= 0.5 / scale if scale > 0 else 0.5
        if scale > 0:
            self._gradient /= scale
        self._qp.update(H=self._hessian, f=self._gradient)
        x, _, exitflag, info = self._qp.solve()
        self.qp_solves += 1
        if exitflag < 1 or not math.isfinite(float(x @ x)):
            # (DAQP reports success with a non-finite x for a Hessian that is not positive definite)
            raise DistributionError(
                f"the bounded input distribution failed (DAQP exit flag {exitflag}, input {x.tolist()}): the "
                "controller's fit is not convex or its terms are inconsistent with the limits"
            )
        # The active set is DAQP's: a bound with a nonzero multiplier holds its input (exactly on it;
        # negative multipliers are lower bounds). Inactive bounds hold to PRIMAL_TOLERANCE: snap those too.
        np.sign(info["lam"], out=self._sign)
        self.limit_state[:] = self._sign
        np.maximum(x, self.lower, out=self.u)
        np.minimum(self.u, self.upper, out=self.u)
        return self.u
