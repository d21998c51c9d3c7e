"""The plant's symbolic code: the Baumgarte DAE with cables that only pull, and one RK4 step of it.

    [M  φ_qᵀ] [q̈]   [H u − c                ]
    [φ_q  0 ] [λ] = [−γ − 2ζ_B ω_B φ̇ − ω_B² φ]      (docs/model.md §8, over the independent rows)

A cable constrains only |p_a − p_b| ≤ L. Which cables are taut is the plant's business (events,
acroboter/plant.py); here every cable row i of the independent rows gets a weight a_i, the entry
of the input `cable_active` (1 taut, 0 slack), body rows weight 1, and the multipliers solve

    (diag(a) S diag(a) + diag(1 − a)) λ = a ∘ r,    S = φ_q M⁻¹ φ_qᵀ,  r = φ_q M⁻¹ f + γ + 2ζωφ̇ + ω²φ,

so a slack row gets λ_i = 0 exactly (the matrix stays positive definite) and, for an all-ones mask,
every number is the rigid plant's (multiplying by 1.0 and adding 0.0 are exact in IEEE arithmetic).
The mask is held over the step: switching it is an event the caller resolves between steps.
"""

from __future__ import annotations

import casadi as ca

from .structured import cholesky_solve, constant_inverse_mass, independent_rows
from .symbolic import SymbolicModel


def cable_rows(model: SymbolicModel) -> list[int]:
    """The constraint row of each spec cable (layout name `cable <name>`), in spec order."""
    return [model.layout.constraints.index(f"cable {c.name}") for c in model.spec.cables]


def cable_lengths(model: SymbolicModel, q: ca.SX) -> list[ca.SX]:
    """Each cable's current length: the winch coordinate of q, or the fixed length."""
    lay = model.layout
    return [q[lay.winch_index[c.name]] if c.winch is not None else ca.SX(c.length) for c in model.spec.cables]


def row_weights(model: SymbolicModel, rows: list[int], cable_active: ca.SX) -> ca.SX:
    """a over the independent rows: cable_active[c] on cable c's row, 1 on every other row."""
    by_row = {r: c for c, r in enumerate(cable_rows(model))}
    return ca.vertcat(*[cable_active[by_row[r]] if r in by_row else ca.SX(1) for r in rows])


def plant_derivative(model: SymbolicModel, u: ca.SX, zeta: ca.SX, omega: ca.SX, rows: list[int],
                     weights: ca.SX) -> tuple[ca.SX, ca.SX]:
    """(ẋ, λ) for x = [q, q̇, W_inputs, W_anchors, E_damping] with the row weights a (module docstring).

    Only the independent constraint rows take part: redundant rows describe no extra physics and
    would make the multiplier system singular. λ is over those rows (0 on a slack cable's row).
    """
    qd = model.inputs[1]
    minv = constant_inverse_mass(model)
    phi, phi_q, phi_dot, gamma = model.phi[rows], model.phi_q[rows, :], model.phi_dot[rows], model.gamma[rows]
    applied = ca.mtimes(model.input_matrix, u) - model.bias_forces
    minv_applied = ca.mtimes(minv, applied)
    # φ_q q̈ = −γ − 2ζω φ̇ − ω² φ with q̈ = M⁻¹(f − φ_qᵀλ):  (φ_q M⁻¹ φ_qᵀ) λ = φ_q M⁻¹ f + γ + 2ζωφ̇ + ω²φ
    schur = ca.mtimes(ca.mtimes(phi_q, minv), phi_q.T)
    rhs = ca.mtimes(phi_q, minv_applied) + gamma + 2 * zeta * omega * phi_dot + omega**2 * phi
    a = ca.diag(weights)
    masked = ca.mtimes(ca.mtimes(a, schur), a) + ca.diag(1 - weights)
    lam = cholesky_solve(masked, weights * rhs)
    qdd = minv_applied - ca.mtimes(minv, ca.mtimes(phi_q.T, lam))
    power_inputs = ca.dot(u, ca.mtimes(model.input_matrix.T, qd))
    power_anchors = ca.dot(lam, phi_dot - ca.mtimes(phi_q, qd))  # λᵀ φ_t: work of moving anchors
    power_damping = ca.dot(qd, ca.gradient(model.dissipation, qd))
    return ca.vertcat(qd, qdd, power_inputs, power_anchors, power_damping), lam


def plant_step_function(model: SymbolicModel, name: str) -> ca.Function:
    """One RK4 step with the cable mask held:

    (x, u, [h, ζ_B, ω_B], signals at t, t + h/2, t + h, cable_active)
        -> x(t + h),
           cable_tension (per spec cable, 2 L λ at the start of the step, N; > 0 pulls; 0 for a
                          slack cable and for a dependent row the plant leaves out),
           cable_gap     (per spec cable, |p_a − p_b| − L at the end of the step, m; > 0 stretched),
           cable_events  ([max over taut cables of −tension, max over slack cables of gap], each at
                          least 0 and over the independent cable rows only: two numbers the caller
                          compares with its tolerances instead of scanning both vectors every step).
    """
    q, qd, s, sd, sdd = model.inputs
    n, ns = q.shape[0], s.shape[0]
    lay = model.layout
    cables = model.spec.cables
    nc = len(cables)
    rows = independent_rows(model)
    u = ca.SX.sym("u", lay.l)
    zeta, omega = ca.SX.sym("zeta"), ca.SX.sym("omega")
    active = ca.SX.sym("cable_active", nc)
    xdot, lam = plant_derivative(model, u, zeta, omega, rows, row_weights(model, rows, active))
    deriv = ca.Function(
        f"{name}_derivative",
        [ca.vertcat(q, qd), u, zeta, omega, s, sd, sdd, active],
        [xdot, lam],
        {"cse": True},
    )
    # Per cable: tension from the row's multiplier, gap from the row's φ = |d|² − L² as φ / (|d| + L)
    # (no cancellation near taut), both as functions of their own inputs.
    lengths = cable_lengths(model, q)
    crows = cable_rows(model)
    multipliers = ca.SX.sym("lambda", len(rows))
    tension = ca.vertcat(
        *[2 * lengths[c] * multipliers[rows.index(r)] if r in rows else ca.SX(0) for c, r in enumerate(crows)]
    )
    tension_fn = ca.Function(f"{name}_tension", [q, multipliers], [tension], {"cse": True})
    gap = ca.vertcat(
        *[model.phi[r] / (ca.sqrt(model.phi[r] + lengths[c] ** 2) + lengths[c]) for c, r in enumerate(crows)]
    )
    gap_fn = ca.Function(f"{name}_gap", [q, s], [gap], {"cse": True})
    independent_cables = [c for c, r in enumerate(crows) if r in rows]

    x = ca.MX.sym("x", 2 * n + 3)
    um = ca.MX.sym("u", lay.l)
    settings = ca.MX.sym("settings", 3)  # h, ζ_B, ω_B
    stage = ca.MX.sym("stage_signals", 9 * ns)  # [s, ṡ, s̈] at t, t + h/2, t + h
    mask = ca.MX.sym("cable_active", nc)
    h, z, w = settings[0], settings[1], settings[2]

    def f(xx, k):
        sig = stage[3 * ns * k : 3 * ns * (k + 1)]
        return deriv(xx[: 2 * n], um, z, w, sig[:ns], sig[ns : 2 * ns], sig[2 * ns :], mask)

    k1, lam1 = f(x, 0)
    k2, _ = f(x + 0.5 * h * k1, 1)
    k3, _ = f(x + 0.5 * h * k2, 1)
    k4, _ = f(x + h * k3, 2)
    x_next = x + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
    start_tension = tension_fn(x[:n], lam1)
    end_gap = gap_fn(x_next[:n], stage[6 * ns : 7 * ns])
    slack_indicator, taut_indicator = ca.MX(0), ca.MX(0)
    for c in independent_cables:
        slack_indicator = ca.fmax(slack_indicator, -mask[c] * start_tension[c])
        taut_indicator = ca.fmax(taut_indicator, (1 - mask[c]) * end_gap[c])
    return ca.Function(
        name,
        [x, um, settings, stage, mask],
        [x_next, start_tension, end_gap, ca.vertcat(slack_indicator, taut_indicator)],
        ["x", "u", "settings", "stage_signals", "cable_active"],
        ["x_next", "cable_tension", "cable_gap", "cable_events"],
    )
