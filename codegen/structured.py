"""Solver-shaped terms: what each controller and the plant need per step, in one generated call.

The mass matrix of natural coordinates is constant, so M⁻¹ is a numeric (sparse) constant here and
every product with it is folded into the generated code. Parameters that a user may change at run
time (gains, penalty numbers) are an input vector, not constants:

    p = [k_P, k_D, α̃, α̂, Ω, μ]
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from acroboter.layout import nominal_coordinates
from codegen.symbolic import SymbolicModel

PARAMS = ("kp", "kd", "alpha_geometric", "alpha_servo", "omega", "mu")


def constant_inverse_mass(model: SymbolicModel) -> ca.DM:
    q, qd = model.inputs[0], model.inputs[1]
    if ca.depends_on(model.mass_matrix, ca.vertcat(q, qd)):
        raise ValueError(
            "the mass matrix depends on the state: natural coordinates give a constant one; "
            "the structured solver terms assume it"
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


def servo_and_constraint_rates(model: SymbolicModel, p: ca.SX) -> tuple[ca.SX, ca.SX]:
    """ρ = γ + 2Ωμ φ̇ + Ω² φ and ρ_s = γ_s + 2k_D σ̇ + k_P² σ."""
    kp, kd, omega, mu = p[0], p[1], p[4], p[5]
    rho = model.gamma + 2 * omega * mu * model.phi_dot + omega**2 * model.phi
    rho_s = model.gamma_s + 2 * kd * model.sigma_dot + kp**2 * model.sigma
    return rho, rho_s


def mlm_terms(model: SymbolicModel, p: ca.SX) -> dict[str, ca.SX]:
    """MLM's system reduced by the constant M (Schur complement on the multipliers and inputs).

    [M W; C 0][q̈; y] = [−c; −r] with W = [φ_qᵀ, −H], C = [φ_q; σ_q], r = [γ; ρ_s], y = [λ; u] gives
    (C M⁻¹ W) y = r − C M⁻¹ c and q̈ = −M⁻¹(c + W y).
    """
    minv = constant_inverse_mass(model)
    _, rho_s = servo_and_constraint_rates(model, p)
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

    Recovery: minimise |H u − φ_qᵀ Δλ + σ_qᵀ λ̂|² in the M⁻¹ metric over x = (u, Δλ):
    (Bᵀ M⁻¹ B) x = −(Bᵀ M⁻¹ σ_qᵀ) λ̂ with B = [H, −φ_qᵀ]. Only the independent constraint rows enter
    B: redundant rows span no new reaction directions and would make the normal equations singular.
    The normal matrix depends on q alone, so it is factored here (Cholesky, in the generated code)
    and, with λ̂ = α̂(σ_q Σq̈_i + N ρ_s) after N iterations, the input is
    u = recovery_gain · Σq̈_i + N · recovery_offset.
    """
    alpha_g, alpha_s = p[2], p[3]
    rho, rho_s = servo_and_constraint_rates(model, p)
    phi_q, sigma_q = model.phi_q, model.sigma_q
    penalty_matrix = model.mass_matrix + alpha_g * ca.mtimes(phi_q.T, phi_q) + alpha_s * ca.mtimes(sigma_q.T, sigma_q)
    penalty_force = -alpha_g * ca.mtimes(phi_q.T, rho) - alpha_s * ca.mtimes(sigma_q.T, rho_s)
    minv = constant_inverse_mass(model)
    rows = independent_rows(model)
    b = ca.horzcat(model.input_matrix, -phi_q[rows, :].T)
    minv_b = ca.mtimes(minv, b)
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
        # u-rows of −α̂ (BᵀM⁻¹B)⁻¹ BᵀM⁻¹σ_qᵀ, applied to σ_q Σq̈ and to ρ_s
        **_projected_recovery(model, minv_b, b, sigma_q, rho_s, alpha_s),
    }


def _projected_recovery(model, minv_b, b, sigma_q, rho_s, alpha_s) -> dict[str, ca.SX]:
    l = model.layout.l
    servo_map = cholesky_solve(ca.mtimes(b.T, minv_b), ca.mtimes(minv_b.T, sigma_q.T))[:l, :]
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


def plant_derivative(model: SymbolicModel, u: ca.SX, zeta: ca.SX, omega: ca.SX, rows: list[int]) -> ca.SX:
    """ẋ of x = [q, q̇, W_inputs, W_anchors, E_damping] for the Baumgarte DAE (design §9).

    Only the independent constraint rows take part: redundant rows describe no extra physics and
    would make the multiplier system singular.
    """
    qd = model.inputs[1]
    minv = constant_inverse_mass(model)
    phi, phi_q, phi_dot, gamma = model.phi[rows], model.phi_q[rows, :], model.phi_dot[rows], model.gamma[rows]
    applied = ca.mtimes(model.input_matrix, u) - model.bias_forces
    minv_applied = ca.mtimes(minv, applied)
    # φ_q q̈ = −γ − 2ζω φ̇ − ω² φ with q̈ = M⁻¹(f − φ_qᵀλ):  (φ_q M⁻¹ φ_qᵀ) λ = φ_q M⁻¹ f + γ + 2ζωφ̇ + ω²φ
    schur = ca.mtimes(ca.mtimes(phi_q, minv), phi_q.T)
    lam = cholesky_solve(schur, ca.mtimes(phi_q, minv_applied) + gamma + 2 * zeta * omega * phi_dot + omega**2 * phi)
    qdd = minv_applied - ca.mtimes(minv, ca.mtimes(phi_q.T, lam))
    power_inputs = ca.dot(u, ca.mtimes(model.input_matrix.T, qd))
    power_anchors = ca.dot(lam, phi_dot - ca.mtimes(phi_q, qd))  # λᵀ φ_t: work of moving anchors
    power_damping = ca.dot(qd, ca.gradient(model.dissipation, qd))
    return ca.vertcat(qd, qdd, power_inputs, power_anchors, power_damping)


def plant_step_function(model: SymbolicModel, name: str) -> ca.Function:
    """One RK4 step: (x, u, [h, ζ_B, ω_B], signals at t, t + h/2, t + h) -> x(t + h)."""
    q, qd, s, sd, sdd = model.inputs
    n, ns = q.shape[0], s.shape[0]
    lay = model.layout
    rows = independent_rows(model)
    u = ca.SX.sym("u", lay.l)
    zeta, omega = ca.SX.sym("zeta"), ca.SX.sym("omega")
    deriv = ca.Function(
        f"{name}_derivative",
        [ca.vertcat(q, qd), u, zeta, omega, s, sd, sdd],
        [plant_derivative(model, u, zeta, omega, rows)],
        {"cse": True},
    )
    x = ca.MX.sym("x", 2 * n + 3)
    um = ca.MX.sym("u", lay.l)
    settings = ca.MX.sym("settings", 3)  # h, ζ_B, ω_B
    stage = ca.MX.sym("stage_signals", 9 * ns)  # [s, ṡ, s̈] at t, t + h/2, t + h
    h, z, w = settings[0], settings[1], settings[2]

    def f(xx, k):
        sig = stage[3 * ns * k : 3 * ns * (k + 1)]
        return deriv(xx[: 2 * n], um, z, w, sig[:ns], sig[ns : 2 * ns], sig[2 * ns :])

    k1 = f(x, 0)
    k2 = f(x + 0.5 * h * k1, 1)
    k3 = f(x + 0.5 * h * k2, 1)
    k4 = f(x + h * k3, 2)
    x_next = x + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
    return ca.Function(name, [x, um, settings, stage], [x_next], ["x", "u", "settings", "stage_signals"], ["x_next"])
