"""Input recovery for the penalty methods: u from the servo-constraint forces (docs/model.md §6).

- projected (default): least squares over (u, Δλ) of H u − φ_qᵀ Δλ = −σ_qᵀ λ̂. The actuators need to
  reproduce the ideal servo force only up to constraint reactions; equals eq. 12 when collocated.
  When it cannot be met exactly (the crane's winches also pull the connector), the residual r is
  measured in the kinetic-energy metric rᵀM⁻¹r, i.e. by the acceleration it would cause. In natural
  coordinates the rows mix forces (N) and axis "forces" (N·m); the plain Euclidean norm weighs
  them arbitrarily, and in trials let the SU tilt by 3° where this metric keeps it under 0.2°.
  The generated code solves the normal equations (BᵀM⁻¹B) x = −(BᵀM⁻¹σ_qᵀ) λ̂, B = [H, −φ_qᵀ] over the
  independent constraint rows, by Cholesky, and hands over u as a linear map of Σq̈ (see
  acroboter.codegen.solver_terms.penalty_terms); should they be singular (dependent actuators and reactions:
  the map comes out non-finite), a pivoted QR of M^(-1/2) B gives the minimum-norm solution.
- eq12: u = −(HᵀH)⁻¹Hᵀ σ_qᵀ λ̂
- eq13: u = (HᵀH)⁻¹Hᵀ (M q̈ + c + φ_qᵀ λ)
- eq15: u = λ̂ (only meaningful when H = −σ_qᵀ)
- kappa: u = −H† σ_qᵀ λ̂ with H† = κ(HᵀH)⁻¹Hᵀ − (1 − κ)σ_q, the paper's non-collocated blend. The
  paper prints +(1 − κ)σ_q, but with its own convention H = −σ_qᵀ that term points against the
  pseudo-inverse (κ = 0.5 would give u = 0 on a collocated system); −σ_q is the transpose
  approximation Hᵀ of H† there, so κ blends two consistent inverses and every κ gives u = λ̂ when
  H = −σ_qᵀ with orthonormal rows.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.linalg import cholesky, lstsq, solve_triangular

from ..model.spec import RECOVERIES


class RecoveryError(ValueError):
    pass


class InputRecovery:
    def __init__(self, kind: str, mass: np.ndarray, k: int, l: int, kappa: float):
        if kind not in RECOVERIES:
            raise RecoveryError(f"unknown input recovery '{kind}': choose one of {', '.join(RECOVERIES)}")
        if kind in ("eq15", "kappa") and k != l:
            raise RecoveryError(
                f"recovery '{kind}' needs as many servo-constraints as inputs (found {k} for {l}): "
                "use 'projected' or 'eq12'"
            )
        n = mass.shape[0]
        self.kind, self.kappa, self.l = kind, kappa, l
        self.mass = mass
        self.u = np.zeros(l)
        self._servo_force = np.zeros(n)
        self._force = np.zeros(n)
        self._hth = np.zeros((l, l))
        self._hrhs = np.zeros(l)
        chol = cholesky(mass, lower=True, check_finite=False)
        self._inv_chol = solve_triangular(chol, np.eye(n), lower=True, check_finite=False)  # M^(-1/2)

    def _pseudo_inverse_apply(self, H: np.ndarray, force: np.ndarray) -> np.ndarray:
        """(HᵀH)⁻¹Hᵀ force, raising a clear error if H has dependent columns."""
        np.matmul(H.T, H, out=self._hth)
        np.matmul(H.T, force, out=self._hrhs)
        try:
            return np.linalg.solve(self._hth, self._hrhs)
        except np.linalg.LinAlgError:
            raise RecoveryError("HᵀH is singular: the actuators' generalized forces are linearly dependent") from None

    def projected_fast(self, terms: dict, qdd_sum: np.ndarray, iterations: int) -> np.ndarray:
        """u = recovery_gain · Σq̈ + N · recovery_offset (generated); None if the map is not finite."""
        offset = terms["recovery_offset"]
        if not math.isfinite(offset[0]):  # a failed (singular) factorization leaves NaN in every entry
            return None
        np.matmul(terms["recovery_gain"], qdd_sum, out=self.u)
        if iterations == 1:
            self.u += offset
        else:
            self.u += iterations * offset
        return self.u

    def _projected(self, terms: dict, lam_hat: np.ndarray) -> None:
        # Singular normal equations: Δλ is not unique; pivoted QR picks the minimum-norm solution.
        stacked = np.hstack([terms["input_matrix"], -terms["phi_q"].T])
        np.matmul(terms["sigma_q"].T, lam_hat, out=self._servo_force)
        sol = lstsq(self._inv_chol @ stacked, -(self._inv_chol @ self._servo_force), lapack_driver="gelsy",
                    check_finite=False)[0]
        self.u[:] = sol[: self.l]

    def least_squares(self, terms: dict, lam_hat: np.ndarray, qdd: np.ndarray, lam: np.ndarray):
        """(G, g) of ½uᵀGu + gᵀu whose minimiser is this recovery's u (after recover()), for the limits.

        eq12 and eq13 are least squares in H u: bounded, they stay the same fit. eq15 and kappa are
        explicit maps: bounded, they give the input within the limits closest to their u.
        (The projected recovery has its own terms: acroboter.codegen.solver_terms.penalty_bounded_terms.)
        """
        H = terms["input_matrix"]
        if self.kind in ("eq12", "eq13"):
            if self.kind == "eq12":  # min ½|H u + σ_qᵀ λ̂|²
                np.matmul(terms["sigma_q"].T, lam_hat, out=self._force)
            else:  # min ½|H u − (M q̈ + c + φ_qᵀ λ)|²
                np.matmul(self.mass, qdd, out=self._force)
                self._force += terms["bias_forces"]
                self._force += terms["phi_q"].T @ lam
                self._force *= -1.0
            np.matmul(H.T, H, out=self._hth)
            np.matmul(H.T, self._force, out=self._hrhs)
            return self._hth, self._hrhs
        np.copyto(self._hth, np.eye(self.l))  # eq15, kappa: min ½|u − u_recovered|²
        np.negative(self.u, out=self._hrhs)
        return self._hth, self._hrhs

    def recover(self, terms: dict, lam_hat: np.ndarray, qdd: np.ndarray, lam: np.ndarray) -> np.ndarray:
        """u from the penalty step's terms (acroboter.codegen.solver_terms.penalty_terms), λ̂, q̈ and λ."""
        kind = self.kind
        if kind == "projected":
            self._projected(terms, lam_hat)
            return self.u
        H, sigma_q = terms["input_matrix"], terms["sigma_q"]
        np.matmul(sigma_q.T, lam_hat, out=self._servo_force)
        if kind == "eq12":
            self.u[:] = -self._pseudo_inverse_apply(H, self._servo_force)
        elif kind == "eq13":
            np.matmul(self.mass, qdd, out=self._force)
            self._force += terms["bias_forces"]
            self._force += terms["phi_q"].T @ lam
            self.u[:] = self._pseudo_inverse_apply(H, self._force)
        elif kind == "eq15":
            self.u[:] = lam_hat
        else:  # kappa
            blend = self.kappa * np.linalg.solve(H.T @ H, H.T) - (1.0 - self.kappa) * sigma_q
            self.u[:] = -blend @ self._servo_force
        return self.u
