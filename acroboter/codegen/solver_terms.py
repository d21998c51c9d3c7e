"""Solver-shaped terms: what each controller needs per step, in one generated call (plant: codegen/plant_step.py).

The mass matrix of natural coordinates is constant, so M⁻¹ is a numeric (sparse) constant here and
every product with it is folded into the generated code. Parameters that a user may change at run
time (gains, penalty numbers) are an input vector, not constants:

    p = [k_P, k_D, α̃, α̂, Ω, μ, k_I, z_1 … z_k]

(the layout acroboter.model.controller_parameters declares and reads by name: `runtime_view`).

z is the integral of the servo-constraints σ over time, held by the controller and written into p
every step when k_I ≠ 0 (docs/integral_action.md); with k_I = 0 it stays 0 and ρ_s is the PD law's
bit for bit (ρ + 0·z = ρ exactly in IEEE arithmetic).
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from ..model.controller_parameters import runtime_view
from ..model.layout import nominal_coordinates
from .symbolic import SymbolicModel


def constant_inverse_mass(model: SymbolicModel) -> ca.DM:
    q, qd = model.inputs[0], model.inputs[1]
    if ca.depends_on(model.mass_matrix, ca.vertcat(q, qd)):
        raise ValueError(
            "the mass matrix depends on the state: natural coordinates give a constant one; "
            "the solver terms assume it"
        )
    mass = np.array(ca.evalf(model.mass_matrix))
    inverse = np.linalg.inv(mass)
    inverse[np.abs(inverse) < 1e-15 * np.abs(inverse).max()] = 0.0  # exact zeros of the block structure
    return ca.sparsify(ca.DM(inverse))


def cholesky_solve(matrix: ca.SX, rhs: ca.SX) -> ca.SX:
    """X = S⁻¹ B for symmetric positive definite S (B: one or more columns), as expressions.

    CasADi's generic symbolic solve uses QR (about 9,000 operations at 16x16); Cholesky needs a
    tenth of that, needs no pivoting for a positive definite S, and skips S's structural zeros.
    """
    size = matrix.shape[0]
    low = [[ca.SX(0) for _ in range(size)] for _ in range(size)]
    for j in range(size):
        diag = matrix[j, j] - sum((low[j][k] * low[j][k] for k in range(j)), ca.SX(0))
        low[j][j] = ca.sqrt(diag)
        for i in range(j + 1, size):
            if matrix.sparsity().has_nz(i, j) or any(
                not (low[i][k].is_zero() or low[j][k].is_zero()) for k in range(j)
            ):
                low[i][j] = (matrix[i, j] - sum((low[i][k] * low[j][k] for k in range(j)), ca.SX(0))) / low[j][j]
    columns = []
    for c in range(rhs.shape[1]):
        y = [ca.SX(0)] * size
        for i in range(size):  # L y = b
            y[i] = (rhs[i, c] - sum((low[i][k] * y[k] for k in range(i)), ca.SX(0))) / low[i][i]
        x = [ca.SX(0)] * size
        for i in reversed(range(size)):  # Lᵀ x = y
            x[i] = (y[i] - sum((low[k][i] * x[k] for k in range(i + 1, size)), ca.SX(0))) / low[i][i]
        columns.append(ca.vertcat(*x))
    return ca.horzcat(*columns)


def servo_and_constraint_rates(model: SymbolicModel, *, kp, kd, ki, z, omega, mu) -> tuple[ca.SX, ca.SX]:
    """ρ = γ + 2Ωμ φ̇ + Ω² φ and ρ_s = γ_s + 2k_D σ̇ + k_P² σ + k_I z (z = ∫σ dt).

    Every controller's terms take ρ_s from here, so MLM, the penalty methods, every recovery and the
    bounded distributions see the same servo-error law.
    """
    rho = model.gamma + 2 * omega * mu * model.phi_dot + omega**2 * model.phi
    rho_s = model.gamma_s + 2 * kd * model.sigma_dot + kp**2 * model.sigma + ki * z
    return rho, rho_s


def controller_rates(model: SymbolicModel, p: ca.SX) -> tuple[ca.SX, ca.SX]:
    """ρ and ρ_s with the gains and z of the run-time vector p."""
    v = runtime_view(p, model.sigma.shape[0])
    return servo_and_constraint_rates(model, kp=v.kp, kd=v.kd, ki=v.ki, z=v.z, omega=v.omega, mu=v.mu)


def mlm_terms(model: SymbolicModel, p: ca.SX) -> dict[str, ca.SX]:
    """MLM's system reduced by the constant M (Schur complement on the multipliers and inputs).

    [M W; C 0][q̈; y] = [−c; −r] with W = [φ_qᵀ, −H], C = [φ_q; σ_q], r = [γ; ρ_s], y = [λ; u] gives
    (C M⁻¹ W) y = r − C M⁻¹ c and q̈ = −M⁻¹(c + W y).
    """
    minv = constant_inverse_mass(model)
    _, rho_s = controller_rates(model, p)
    w = ca.horzcat(model.phi_q.T, -model.input_matrix)
    c = ca.vertcat(model.phi_q, model.sigma_q)
    minv_w = ca.mtimes(minv, w)
    minv_c = ca.mtimes(minv, model.bias_forces)
    schur = ca.mtimes(c, minv_w)
    return {
        "schur": schur,
        "schur_rhs": ca.vertcat(model.gamma, rho_s) - ca.mtimes(c, minv_c),
        "schur_norm1": ca.mmax(ca.sum1(ca.fabs(schur))),  # for LAPACK's condition estimate
        "minv_bias": minv_c,
        "minv_w": minv_w,
    }


def penalty_terms(model: SymbolicModel, p: ca.SX) -> dict[str, ca.SX]:
    """Penalty matrix, right-hand sides and the projected recovery as a linear map of q̈.

    Recovery: the inputs whose servo accelerations are the ideal servo force's. On the constraint manifold a
    generalized force f accelerates the servo outputs by σ_q P f (P: _constrained_projections), so the inputs
    minimise |E u + F λ̂|² with E = σ_q P H, F = σ_q P σ_qᵀ (penalty_bounded_terms): G u = −g_map λ̂ with
    G = EᵀE, g_map = EᵀF, by Cholesky. With as many inputs as servo-constraints and E regular (MLM's condition)
    this is exact on any crane: the servo outputs accelerate as the penalty formulation's. The normal matrix
    depends on q alone and, with λ̂ = α̂(σ_q Σq̈_i + N ρ_s) after N iterations, the input is
    u = recovery_gain · Σq̈_i + N · recovery_offset.
    (With more inputs than servo-constraints EᵀE is singular: the map is zero, and the controller distributes
    the internal forces instead, acroboter.control.distribution.)
    """
    v = runtime_view(p, model.sigma.shape[0])
    alpha_g, alpha_s = v.alpha_geometric, v.alpha_servo
    rho, rho_s = controller_rates(model, p)
    phi_q, sigma_q = model.phi_q, model.sigma_q
    penalty_matrix = model.mass_matrix + alpha_g * ca.mtimes(phi_q.T, phi_q) + alpha_s * ca.mtimes(sigma_q.T, sigma_q)
    penalty_force = -alpha_g * ca.mtimes(phi_q.T, rho) - alpha_s * ca.mtimes(sigma_q.T, rho_s)
    return {
        "penalty_matrix": penalty_matrix,
        "penalty_force": penalty_force,
        "penalty_rhs": penalty_force - model.bias_forces,  # first iteration: M q̈₀ = −c
        "bias_forces": model.bias_forces,
        "phi_q": phi_q,
        "rho": rho,
        "sigma_q": sigma_q,
        "rho_s": rho_s,
        "input_matrix": model.input_matrix,
        # −α̂ (EᵀE)⁻¹EᵀF, applied to σ_q Σq̈ and to ρ_s
        **_projected_recovery(model, p, sigma_q, rho_s, alpha_s),
    }


def _constrained_projections(model: SymbolicModel, columns: ca.SX) -> tuple[ca.SX, ca.SX]:
    """(P X, M⁻¹φ_qᵀ S⁻¹ γ) with P = M⁻¹ − M⁻¹φ_qᵀ S⁻¹ φ_q M⁻¹, S = φ_q M⁻¹ φ_qᵀ (independent rows).

    P f is the acceleration a generalized force f causes on the constraint manifold (the
    constraint reactions taken out); −M⁻¹φ_qᵀ S⁻¹ γ is the part the constraints' own γ causes.
    """
    minv = constant_inverse_mass(model)
    rows = independent_rows(model)
    phi_q, gamma = model.phi_q[rows, :], model.gamma[rows]
    minv_phi_t = ca.mtimes(minv, phi_q.T)
    minv_x = ca.mtimes(minv, columns)
    solved = cholesky_solve(ca.mtimes(phi_q, minv_phi_t), ca.horzcat(ca.mtimes(phi_q, minv_x), gamma))
    px = minv_x - ca.mtimes(minv_phi_t, solved[:, : columns.shape[1]])
    return px, ca.mtimes(minv_phi_t, solved[:, columns.shape[1]])


def mlm_bounded_terms(model: SymbolicModel, p: ca.SX) -> dict[str, ca.SX]:
    """MLM's servo-constraints as a least-squares problem in u, for bounded or redundant inputs.

    The constrained dynamics give q̈(u) = P (H u − c) − M⁻¹φ_qᵀ S⁻¹ γ, and MLM asks
    σ_q q̈ = −ρ_s: E u = e with E = σ_q P H, e = −ρ_s + σ_q P c + σ_q M⁻¹φ_qᵀ S⁻¹ γ. Returned as the
    Hessian EᵀE and gradient −Eᵀe of ½|E u − e|², plus E and e: where the inputs are free and E
    is square this is MLM's own solution; with more inputs than servo-constraints it leaves the
    internal forces free, with limits it measures what saturation costs (in servo accelerations).
    """
    _, rho_s = controller_rates(model, p)
    p_cols, gamma_part = _constrained_projections(model, ca.horzcat(model.input_matrix, model.bias_forces))
    l = model.layout.l
    e_map = ca.mtimes(model.sigma_q, p_cols[:, :l])
    target = -rho_s + ca.mtimes(model.sigma_q, p_cols[:, l] + gamma_part)
    return {
        "hessian": ca.mtimes(e_map.T, e_map),
        "gradient": -ca.mtimes(e_map.T, target),
        "servo_map": e_map,
        "servo_target": target,
    }


def penalty_bounded_terms(model: SymbolicModel, p: ca.SX) -> dict[str, ca.SX]:
    """The projected recovery as a least-squares problem in u alone, for bounded or redundant inputs.

    The servo accelerations the inputs cause, E u with E = σ_q P H, against those of the ideal servo force
    −σ_qᵀλ̂, −F λ̂ with F = σ_q P σ_qᵀ (P as in _constrained_projections: constraint reactions taken out):
    min ½|E u + F λ̂|² is ½ uᵀ G u + gᵀ u with G = EᵀE and g = EᵀF λ̂ = servo_map · λ̂, whose minimiser is
    penalty_terms' recovery where G is regular, and a problem a bounded QP solver takes where it is not (more
    inputs than servo-constraints: internal forces).

    Why the servo accelerations and not the whole acceleration (a fit in the M⁻¹ metric, the recovery's form
    until 2026-12-06): the winches cannot reproduce an ideal force on the unit alone, and whatever that fit
    leaves moves the servo outputs too, which the feedback then absorbs as a tracking error; 1.1-496 mm on 13
    of 16 generated cranes (docs/plant-fuzz-cranes.md), 0.04-0.26 mm with this fit, as MLM.

    With more servo-constraints than inputs (a redundant task) the fit is exact where the rows agree (a repeated
    row) and least squares where they cannot all be met ('kinetic', the whole acceleration's fit, is the
    alternative there: acroboter.control.recovery).
    """
    e_map, f_map = servo_maps(model)
    return {
        "hessian": ca.mtimes(e_map.T, e_map),
        "servo_map": ca.mtimes(e_map.T, f_map),
    }


def servo_maps(model: SymbolicModel) -> tuple[ca.SX, ca.SX]:
    """(E, F) = (σ_q P H, σ_q P σ_qᵀ): the servo accelerations an input and an ideal servo force cause."""
    l = model.layout.l
    p_cols, _ = _constrained_projections(model, ca.horzcat(model.input_matrix, model.sigma_q.T))
    return ca.mtimes(model.sigma_q, p_cols[:, :l]), ca.mtimes(model.sigma_q, p_cols[:, l:])


def _projected_recovery(model, p, sigma_q, rho_s, alpha_s) -> dict[str, ca.SX]:
    l, k = model.layout.l, model.sigma.shape[0]
    if l > k:  # EᵀE is singular (internal forces): no map; the controllers always distribute there
        return {"recovery_gain": ca.SX.zeros(l, model.layout.n), "recovery_offset": ca.SX.zeros(l, 1)}
    terms = penalty_bounded_terms(model, p)
    servo_map = cholesky_solve(terms["hessian"], terms["servo_map"])
    return {
        "recovery_gain": -alpha_s * ca.mtimes(servo_map, sigma_q),
        "recovery_offset": -alpha_s * ca.mtimes(servo_map, rho_s),
    }


def penalty_iteration_function(model: SymbolicModel, name: str) -> ca.Function:
    """One iterative-penalty update with a given Cholesky factor (eq. 19 and the running sum).

    (chol, force, q̈_i, Σ) -> (q̈_{i+1}, Σ + q̈_{i+1}) with RᵀR q̈_{i+1} = M q̈_i + force, where R is the
    upper triangle of `chol` as LAPACK's potrf leaves it (the lower triangle is not read). The
    factorization stays LAPACK's, once per step; only the triangular solves of the later
    iterations run here, where they cost one C call each instead of four numpy/LAPACK calls.
    """
    n = model.layout.n
    chol = ca.SX.sym("chol", n, n)
    force, qdd, total = ca.SX.sym("force", n), ca.SX.sym("qdd", n), ca.SX.sym("qdd_sum", n)
    rhs = ca.mtimes(model.mass_matrix, qdd) + force  # M is constant: folded in
    y = [ca.SX(0)] * n
    for i in range(n):  # Rᵀ y = rhs
        y[i] = (rhs[i] - sum((chol[k, i] * y[k] for k in range(i)), ca.SX(0))) / chol[i, i]
    x = [ca.SX(0)] * n
    for i in reversed(range(n)):  # R x = y
        x[i] = (y[i] - sum((chol[i, k] * x[k] for k in range(i + 1, n)), ca.SX(0))) / chol[i, i]
    x_next = ca.vertcat(*x)
    return ca.Function(name, [chol, force, qdd, total], [x_next, total + x_next],
                       ["chol", "force", "qdd", "qdd_sum"], ["qdd_next", "qdd_sum_next"], {"cse": True})


def independent_rows(model: SymbolicModel) -> list[int]:
    """The constraint rows not implied by earlier ones, in order.

    Flagged rows (w − u×v) are dropped outright; any other dependency (a duplicated cable, say) is
    found from the rank of φ_q at the spec's nominal configuration: a row is kept if it raises the
    rank of the rows kept so far. Structural redundancy holds at every configuration, so one
    configuration decides it.
    """
    lay = model.layout
    q, s = model.inputs[0], model.inputs[2]
    signals = np.zeros(lay.n_signals)
    for anchor in model.spec.anchors:
        if anchor.name in lay.anchor_signal:
            j = lay.anchor_signal[anchor.name]
            signals[j : j + 3] = anchor.position
    jac = np.array(ca.Function("phi_q", [q, s], [model.phi_q])(nominal_coordinates(model.spec, lay), signals))
    keep: list[int] = []
    for i in range(lay.m):
        if i not in lay.redundant_rows and np.linalg.matrix_rank(jac[keep + [i]]) == len(keep) + 1:
            keep.append(i)
    return keep
