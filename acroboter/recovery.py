"""Input recovery for the penalty methods: u from the servo-constraint forces (design §8).

- projected (default): least squares over (u, Δλ) of H u − φ_qᵀ Δλ = −σ_qᵀ λ̂. The actuators need to
  reproduce the ideal servo force only up to constraint reactions; equals eq. 12 when collocated.
  When it cannot be met exactly (the crane's winches also pull the connector), the residual r is
  measured in the kinetic-energy metric rᵀM⁻¹r, i.e. by the acceleration it would cause. In natural
  coordinates the rows mix forces (N) and axis "forces" (N·m); the plain Euclidean norm weighs
  them arbitrarily, and in trials let the SU tilt by 3° where this metric keeps it under 0.2°.
- eq12: u = −(HᵀH)⁻¹Hᵀ σ_qᵀ λ̂
- eq13: u = (HᵀH)⁻¹Hᵀ (M q̈ + c + φ_qᵀ λ)
- eq15: u = λ̂ (only meaningful when H = −σ_qᵀ)
- kappa: u = −H† σ_qᵀ λ̂ with H† = κ(HᵀH)⁻¹Hᵀ + (1 − κ)σ_q (the paper's non-collocated blend)
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import cholesky, lstsq, solve_triangular

from .spec import RECOVERIES


class RecoveryError(ValueError):
    pass


class InputRecovery:
    def __init__(self, kind: str, n: int, m: int, k: int, l: int, kappa: float = 0.5):
        if kind not in RECOVERIES:
            raise RecoveryError(f"unknown input recovery '{kind}': choose one of {', '.join(RECOVERIES)}")
        if kind in ("eq15", "kappa") and k != l:
            raise RecoveryError(
                f"recovery '{kind}' needs as many servo-constraints as inputs (found {k} for {l}): "
                "use 'projected' or 'eq12'"
            )
        self.kind, self.kappa = kind, kappa
        self.u = np.zeros(l)
        self._servo_force = np.zeros(n)  # σ_qᵀ λ̂
        self._stacked = np.zeros((n, l + m), order="F")  # [H, −φ_qᵀ]
        self._hth = np.zeros((l, l))
        self._rhs = np.zeros(l)
        self._force = np.zeros(n)
        self._mass = np.full((n, n), np.nan)  # M whose Cholesky factor is cached (M is constant here)
        self._inv_chol = np.zeros((n, n))  # L⁻¹ with M = L Lᵀ
        self._weighted = np.zeros((n, l + m), order="F")
        self._target = np.zeros(n)

    def _pseudo_inverse_apply(self, H: np.ndarray, force: np.ndarray) -> np.ndarray:
        """(HᵀH)⁻¹Hᵀ force, raising a clear error if H has dependent columns."""
        np.matmul(H.T, H, out=self._hth)
        np.matmul(H.T, force, out=self._rhs)
        try:
            return np.linalg.solve(self._hth, self._rhs)
        except np.linalg.LinAlgError:
            raise RecoveryError("HᵀH is singular: the actuators' generalized forces are linearly dependent") from None

    def recover(self, H, phi_q, sigma_q, lam_hat, qdd, M, c, lam) -> np.ndarray:
        np.matmul(sigma_q.T, lam_hat, out=self._servo_force)
        kind = self.kind
        if kind == "projected":
            if not np.array_equal(M, self._mass):  # factor once: M is constant in natural coordinates
                self._mass[:] = M
                chol = cholesky(M, lower=True, check_finite=False)
                self._inv_chol[:] = solve_triangular(chol, np.eye(M.shape[0]), lower=True, check_finite=False)
            l = H.shape[1]
            self._stacked[:, :l] = H
            np.negative(phi_q.T, out=self._stacked[:, l:])
            # Weigh rows by L⁻¹: |L⁻¹ r|² = rᵀM⁻¹r. Pivoted QR (gelsy) copes with redundant constraints.
            np.matmul(self._inv_chol, self._stacked, out=self._weighted)
            np.matmul(self._inv_chol, self._servo_force, out=self._target)
            np.negative(self._target, out=self._target)
            sol = lstsq(self._weighted, self._target, lapack_driver="gelsy", check_finite=False)[0]
            self.u[:] = sol[:l]
        elif kind == "eq12":
            self.u[:] = -self._pseudo_inverse_apply(H, self._servo_force)
        elif kind == "eq13":
            np.matmul(M, qdd, out=self._force)
            self._force += c
            self._force += phi_q.T @ lam
            self.u[:] = self._pseudo_inverse_apply(H, self._force)
        elif kind == "eq15":
            self.u[:] = lam_hat
        else:  # kappa
            blend = self.kappa * np.linalg.solve(H.T @ H, H.T) + (1.0 - self.kappa) * sigma_q
            self.u[:] = -blend @ self._servo_force
        return self.u
