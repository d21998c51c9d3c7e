"""The three inverse-dynamics controllers of the paper (design §8), fed only by the compiled model.

Every controller maps (q, q̇, t) to the input u. One call into the compiled library gives every
model term at the state; the linear algebra is LAPACK through scipy on preallocated arrays.

  ρ   = γ   + 2Ωμ φ̇ + Ω² φ          (geometric constraints, Baumgarte-like penalty dynamics)
  ρ_s = γ_s + 2k_D σ̇ + k_P² σ       (servo-constraints: the tracking error dynamics)
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.linalg import lapack

from .compiled import CompiledModel
from .path import DesiredPath
from .recovery import InputRecovery
from .spec import Spec


class SingularSystemError(RuntimeError):
    """The controller's linear system has no unique solution (e.g. redundant constraints)."""


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

    @classmethod
    def from_spec(cls, spec: Spec, **overrides) -> Gains:
        c, p = spec.controller, spec.controller.penalty
        gains = cls(c.kp, c.kd, p.alpha_geometric, p.alpha_servo, p.omega, p.mu, p.recovery, p.kappa)
        return replace(gains, **{k: v for k, v in overrides.items() if v is not None})


class Controller:
    """Shared part: load a state into the model, evaluate all terms, form ρ and ρ_s."""

    name = "controller"

    def __init__(self, model: CompiledModel, path: DesiredPath, gains: Gains):
        self.model, self.path, self.gains = model, path, gains
        lay = model.layout
        self.n, self.m, self.k, self.l = lay.n, lay.m, lay.k, lay.l
        self._terms = model.functions["model_terms"]
        self.terms = self._terms.outputs  # views, refreshed by every _load
        self.rho = np.zeros(self.m)
        self.rho_s = np.zeros(self.k)
        self.qdd = np.zeros(self.n)
        self.lam = np.zeros(self.m)
        self.lam_hat = np.zeros(self.k)
        self.u = np.zeros(self.l)

    def _load(self, q: np.ndarray, qd: np.ndarray, t: float) -> None:
        model, g, T = self.model, self.gains, self.terms
        model.q[:] = q
        model.qd[:] = qd
        self.path.signals(t, model.s, model.sd, model.sdd)
        self._terms.call()
        # ρ = γ + 2Ωμ φ̇ + Ω² φ
        np.multiply(T["phi_dot"], 2.0 * g.omega * g.mu, out=self.rho)
        self.rho += T["gamma"]
        self.rho += g.omega**2 * T["phi"]
        # ρ_s = γ_s + 2 k_D σ̇ + k_P² σ
        np.multiply(T["sigma_dot"], 2.0 * g.kd, out=self.rho_s)
        self.rho_s += T["gamma_s"]
        self.rho_s += g.kp**2 * T["sigma"]

    def compute(self, q: np.ndarray, qd: np.ndarray, t: float) -> np.ndarray:
        """The input u at state (q, q̇) and time t (a view of an internal buffer)."""
        raise NotImplementedError


class MLM(Controller):
    """Method of Lagrange multipliers (paper eq. 4): one square system in (q̈, λ, u)."""

    name = "mlm"

    def __init__(self, model: CompiledModel, path: DesiredPath, gains: Gains):
        super().__init__(model, path, gains)
        n, m, k, l = self.n, self.m, self.k, self.l
        if k != l:
            raise SingularSystemError(
                f"MLM needs as many servo-constraints as inputs, found {k} servo-constraints for {l} inputs "
                "(redundant task): its matrix is not square. Use the penalty or iterative penalty method."
            )
        size = n + m + l
        self._matrix = np.zeros((size, size), order="F")
        self._rhs = np.zeros(size)
        self._getrf, self._getrs, self._gecon = lapack.get_lapack_funcs(("getrf", "getrs", "gecon"), (self._matrix,))

    def compute(self, q, qd, t):
        self._load(q, qd, t)
        n, m, T, A = self.n, self.m, self.terms, self._matrix
        A[:n, :n] = T["mass_matrix"]
        A[:n, n : n + m] = T["phi_q"].T
        A[:n, n + m :] = -T["input_matrix"]
        A[n : n + m, :n] = T["phi_q"]
        A[n + m :, :n] = T["sigma_q"]
        A[n + m :, n:] = 0.0
        A[n : n + m, n:] = 0.0
        self._rhs[:n] = -T["bias_forces"]
        self._rhs[n : n + m] = -T["gamma"]
        self._rhs[n + m :] = -self.rho_s
        anorm = np.abs(A).sum(axis=0).max()
        lu, piv, info = self._getrf(A, overwrite_a=True)
        rcond = self._gecon(lu, anorm)[0] if info == 0 else 0.0
        if info != 0 or rcond < 1e-13:
            raise SingularSystemError(
                f"MLM's {A.shape[0]}x{A.shape[0]} system is singular (reciprocal condition number {rcond:.1e}): "
                "the constraints are redundant or the task is not reachable by the inputs. MLM needs "
                "independent constraints; use the penalty or iterative penalty method, which handle redundancy."
            )
        x, info = self._getrs(lu, piv, self._rhs)
        self.qdd[:] = x[:n]
        self.lam[:] = x[n : n + m]
        self.u[:] = x[n + m :]
        return self.u


class Penalty(Controller):
    """Penalty formulation (paper eqs. 8-13) and its iterative extension (eqs. 16-19).

    iterations = 1 is the plain penalty method: A q̈₁ = M q̈₀ − α̃ φ_qᵀρ − α̂ σ_qᵀρ_s with M q̈₀ = −c is
    exactly eq. 8. More iterations refine q̈ and the multipliers with the same factorization of A.
    """

    def __init__(self, model: CompiledModel, path: DesiredPath, gains: Gains, iterations: int = 1):
        super().__init__(model, path, gains)
        if iterations < 1:
            raise ValueError("iterations must be at least 1")
        self.iterations = iterations
        self.name = "penalty" if iterations == 1 else f"iterative-{iterations}"
        n = self.n
        self._a = np.zeros((n, n), order="F")  # penalty matrix A
        self._penalty_force = np.zeros(n)  # −α̃ φ_qᵀρ − α̂ σ_qᵀρ_s
        self._rhs = np.zeros(n)
        self._potrf, self._potrs = lapack.get_lapack_funcs(("potrf", "potrs"), (self._a,))
        self.recovery = InputRecovery(gains.recovery, n, self.m, self.k, self.l, gains.kappa)

    def _factor(self, matrix: np.ndarray, what: str) -> np.ndarray:
        chol, info = self._potrf(matrix, lower=False, overwrite_a=True, clean=False)
        if info != 0:
            raise SingularSystemError(
                f"{what} is not positive definite (LAPACK potrf info {info}): check the penalty numbers"
            )
        return chol

    def compute(self, q, qd, t):
        self._load(q, qd, t)
        g, T = self.gains, self.terms
        M, phi_q, sigma_q = T["mass_matrix"], T["phi_q"], T["sigma_q"]
        a = self._a
        # A = M + α̃ φ_qᵀφ_q + α̂ σ_qᵀσ_q
        np.matmul(phi_q.T, phi_q, out=a)
        a *= g.alpha_geometric
        a += g.alpha_servo * (sigma_q.T @ sigma_q)
        a += M
        np.matmul(phi_q.T, self.rho, out=self._penalty_force)
        self._penalty_force *= -g.alpha_geometric
        self._penalty_force -= g.alpha_servo * (sigma_q.T @ self.rho_s)
        chol_a = self._factor(a, "the penalty matrix A = M + α̃ φ_qᵀφ_q + α̂ σ_qᵀσ_q")

        # M q̈₀ = −c: the first right-hand side needs no solve for q̈₀.
        self._rhs[:] = -T["bias_forces"]
        self.lam[:] = 0.0
        self.lam_hat[:] = 0.0
        for i in range(self.iterations):
            if i > 0:  # right-hand side M q̈_i
                np.matmul(M, self.qdd, out=self._rhs)
            self._rhs += self._penalty_force
            x, info = self._potrs(chol_a, self._rhs, lower=False)
            self.qdd[:] = x
            # λ_{i+1} = λ_i + α̃(φ_q q̈_{i+1} + ρ),  λ̂_{i+1} = λ̂_i + α̂(σ_q q̈_{i+1} + ρ_s)
            self.lam += g.alpha_geometric * (phi_q @ self.qdd + self.rho)
            self.lam_hat += g.alpha_servo * (sigma_q @ self.qdd + self.rho_s)
        self.recovery.recover(T["input_matrix"], phi_q, sigma_q, self.lam_hat, self.qdd, M, T["bias_forces"], self.lam)
        self.u[:] = self.recovery.u
        return self.u


def make_controller(method: str, model: CompiledModel, path: DesiredPath, gains: Gains) -> Controller:
    """'mlm', 'penalty' or 'iterative-N'."""
    if method == "mlm":
        return MLM(model, path, gains)
    if method == "penalty":
        return Penalty(model, path, gains, iterations=1)
    if method.startswith("iterative-") and method.removeprefix("iterative-").isdigit():
        return Penalty(model, path, gains, iterations=int(method.removeprefix("iterative-")))
    raise ValueError(f"unknown method '{method}': use mlm, penalty or iterative-N (N >= 1)")
