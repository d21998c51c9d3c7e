"""Input recovery for the penalty methods: u from the servo-constraint forces (docs/model.md §6).

- projected (default): the inputs whose servo accelerations are those of the ideal servo force:
  min |E u + F λ̂|² with E = σ_q P H, F = σ_q P σ_qᵀ, P the constrained projection (a generalized force f
  accelerates the servo outputs by σ_q P f once the constraint reactions are taken out). Exact on any crane
  whose E is regular (MLM's condition): the winches need not reproduce the ideal force on the unit, only its
  effect on what the servo-constraints prescribe; equals eq. 15 when collocated (H = −σ_qᵀ). The generated
  code solves (EᵀE) u = −(EᵀF) λ̂ by Cholesky and hands over u as a linear map of Σq̈ (see
  acroboter.codegen.solver_terms.penalty_terms); should it be singular (the map comes out non-finite), the
  minimum-norm solution by pivoted QR of the same least squares (acroboter.codegen.solver_terms.penalty_bounded_terms).
  Until 2026-12-06 the fit was of the whole acceleration (in the M⁻¹ metric): what it left moved the servo
  outputs too, 1.1-496 mm of tracking error on 13 of 16 generated cranes (docs/plant-fuzz-cranes.md).
- kinetic: the recovery's form until 2026-12-06, the whole acceleration fitted: min over (u, Δλ) of
  |H u − φ_qᵀ Δλ + σ_qᵀ λ̂|² in the M⁻¹ metric (rᵀM⁻¹r, the acceleration a residual force r causes), Δλ
  eliminated: ½uᵀGu + gᵀu with G = HᵀPH, g = HᵀPσ_qᵀλ̂. Not exact where the winches cannot reproduce an ideal
  force on the unit alone, and what it leaves moves the servo outputs too (1.1-496 mm on generated cranes); but
  on a crane whose zero dynamics are unstable (the four-input crane: MLM and the projected recovery diverge at
  28.7-28.9 s) that inexactness kept it within 20 mm. Computed with numpy (the reference path only: the fast
  path and export-step take the others).
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
from scipy.linalg import lstsq

from ..model.spec import RECOVERIES


class RecoveryError(ValueError):
    pass


class InputRecovery:
    def __init__(self, kind: str, mass: np.ndarray, k: int, l: int, kappa: float, rows=None):
        """`rows`: the independent geometric constraint rows (the kinetic fit's reactions)."""
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
        self._minv = np.linalg.inv(mass)
        self._rows = rows

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

    def _projected(self, bounded: dict, lam_hat: np.ndarray) -> None:
        # EᵀE singular: u is not unique; pivoted QR picks the minimum-norm solution.
        np.matmul(bounded["servo_map"], lam_hat, out=self._hrhs)
        self.u[:] = lstsq(bounded["hessian"], -self._hrhs, lapack_driver="gelsy", check_finite=False)[0]

    def _kinetic_fit(self, terms: dict, lam_hat: np.ndarray) -> None:
        """G = HᵀPH and g = HᵀPσ_qᵀλ̂ into _hth, _hrhs, P = M⁻¹ − M⁻¹φ_qᵀ(φ_q M⁻¹φ_qᵀ)⁻¹φ_q M⁻¹ (independent rows)."""
        H, phi_q = terms["input_matrix"], terms["phi_q"]
        if self._rows is not None:
            phi_q = phi_q[self._rows]
        minv_phi = self._minv @ phi_q.T
        projector = self._minv - minv_phi @ np.linalg.solve(phi_q @ minv_phi, minv_phi.T)
        ph = projector @ H
        np.matmul(H.T, ph, out=self._hth)
        np.matmul(ph.T, terms["sigma_q"].T @ lam_hat, out=self._hrhs)

    def least_squares(self, terms: dict, lam_hat: np.ndarray, qdd: np.ndarray, lam: np.ndarray):
        """(G, g) of ½uᵀGu + gᵀu whose minimiser is this recovery's u (after recover()), for the limits.

        kinetic, eq12 and eq13 are least squares: bounded, they stay the same fit. eq15 and kappa are
        explicit maps: bounded, they give the input within the limits closest to their u.
        (The projected recovery has its own terms: acroboter.codegen.solver_terms.penalty_bounded_terms.)
        """
        H = terms["input_matrix"]
        if self.kind == "kinetic":
            self._kinetic_fit(terms, lam_hat)
            return self._hth, self._hrhs
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

    def recover(self, terms: dict, lam_hat: np.ndarray, qdd: np.ndarray, lam: np.ndarray,
                bounded: dict | None = None) -> np.ndarray:
        """u from the penalty step's terms (acroboter.codegen.solver_terms.penalty_terms), λ̂, q̈ and λ;
        the projected recovery reads `bounded` (penalty_bounded_terms at the same state)."""
        kind = self.kind
        if kind == "projected":
            self._projected(bounded, lam_hat)
            return self.u
        if kind == "kinetic":  # the minimum-norm minimiser of ½uᵀGu + gᵀu
            self._kinetic_fit(terms, lam_hat)
            self.u[:] = lstsq(self._hth, -self._hrhs, lapack_driver="gelsy", check_finite=False)[0]
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
