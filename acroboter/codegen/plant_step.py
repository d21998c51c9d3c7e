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

The plant's functions take the crane's physical parameters as an input vector `plant_params`
(acroboter.model.physical: masses, inertias, points, fixed lengths, drums, damping, gravity), so that a
plant may differ from the controller's model without a library of its own. M then depends on
them, not on the state: M⁻¹ is built from M's diagonal blocks (inverse_mass), which costs a few
divisions per call. Generated from a model without parameters (GenerationContext with
parametric_plant=False), the same functions fold the spec's numbers in and M⁻¹ is the numeric
constant, as the controllers' is.
"""

from __future__ import annotations

import casadi as ca

from .solver_terms import cholesky_solve, constant_inverse_mass
from .symbolic import SymbolicModel


def cable_rows(model: SymbolicModel) -> list[int]:
    """The constraint row of each spec cable (layout name `cable <name>`), in spec order."""
    return [model.layout.constraints.index(f"cable {c.name}") for c in model.spec.cables]


def cable_lengths(model: SymbolicModel, q: ca.SX) -> list[ca.SX]:
    """Each cable's current length: the winch coordinate of q, or the fixed length."""
    lay = model.layout
    return [q[lay.winch_index[c.name]] if c.winch is not None else ca.SX(model.fixed_lengths[c.name])
            for c in model.spec.cables]


def inverse_mass(model: SymbolicModel) -> ca.SX | ca.DM:
    """M⁻¹: the numeric constant when M has no parameters, else an expression in them.

    In natural coordinates M is block-diagonal up to a permutation (m E₃ per centre of mass, J ⊗ E₃
    per body's axes, I_r per drum): each block of coupled coordinates (1 × 1, or 3 × 3 for a body
    with products of inertia) is inverted on its own, so M⁻¹ keeps M's sparsity and costs one
    division per coordinate for a principal-axes body. At the spec's values it is the constant's
    numbers: 1/x is correctly rounded either way.
    """
    mass = model.mass_matrix
    if not ca.depends_on(mass, model.parameters):
        return constant_inverse_mass(model)
    q, qd = model.inputs[0], model.inputs[1]
    if ca.depends_on(mass, ca.vertcat(q, qd)):
        raise ValueError("the mass matrix depends on the state: natural coordinates give a constant one; "
                         "the plant's inverse assumes it")
    n = mass.shape[0]
    rows, cols = mass.sparsity().get_triplet()
    group = list(range(n))  # union-find over M's nonzeros: the blocks of coupled coordinates

    def root(i: int) -> int:
        while group[i] != i:
            i = group[i]
        return i

    for i, j in zip(rows, cols, strict=True):
        group[root(i)] = root(j)
    blocks: dict[int, list[int]] = {}
    for i in range(n):
        blocks.setdefault(root(i), []).append(i)
    inverse = ca.SX(n, n)
    for idx in blocks.values():
        block = mass[idx, idx]
        inverse[idx, idx] = 1 / block if len(idx) == 1 else (ca.inv_minor(block) if len(idx) <= 3 else ca.inv(block))
    return inverse


def row_weights(model: SymbolicModel, rows: list[int], cable_active: ca.SX) -> ca.SX:
    """a over the independent rows: cable_active[c] on cable c's row, 1 on every other row."""
    by_row = {r: c for c, r in enumerate(cable_rows(model))}
    return ca.vertcat(*[cable_active[by_row[r]] if r in by_row else ca.SX(1) for r in rows])


def plant_derivative(model: SymbolicModel, u: ca.SX, zeta: ca.SX, omega: ca.SX, rows: list[int],
                     weights: ca.SX, minv: ca.SX | ca.DM | None = None) -> tuple[ca.SX, ca.SX]:
    """(ẋ, λ) for x = [q, q̇, W_inputs, W_anchors, E_damping] with the row weights a (module docstring).

    Only the independent constraint rows take part: redundant rows describe no extra physics and
    would make the multiplier system singular. λ is over those rows (0 on a slack cable's row).
    `minv`: M⁻¹ (default inverse_mass(model)).
    """
    qd = model.inputs[1]
    minv = inverse_mass(model) if minv is None else minv
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


def plant_step_function(model: SymbolicModel, name: str, rows: list[int]) -> ca.Function:
    """One RK4 step with the cable mask held, over the independent constraint `rows`:

    (x, u, [h, ζ_B, ω_B], signals at t, t + h/2, t + h, cable_active, plant_params)
        -> x(t + h),
           cable_tension (per spec cable, 2 L λ at the start of the step, N; > 0 pulls; 0 for a
                          slack cable and for a dependent row the plant leaves out),
           cable_gap     (per spec cable, |p_a − p_b| − L at the end of the step, m; > 0 stretched),
           cable_events  ([max over taut cables of −tension, max over slack cables of gap], each at
                          least 0 and over the independent cable rows only: two numbers the caller
                          compares with its tolerances instead of scanning both vectors every step;
                          a taut cable's tension counts at the start of the step and as the last RK4
                          stage estimates it at the end, so that a cable that starts to push inside the
                          step is flagged in it, and its instant located, not a step late).
    """
    q, qd, s, sd, sdd = model.inputs
    n, ns = q.shape[0], s.shape[0]
    lay = model.layout
    cables = model.spec.cables
    nc = len(cables)
    theta = model.parameters
    u = ca.SX.sym("u", lay.l)
    zeta, omega = ca.SX.sym("zeta"), ca.SX.sym("omega")
    active = ca.SX.sym("cable_active", nc)
    # A parametric M⁻¹ is evaluated once per step and enters the derivative as plain symbols: the
    # four stages do not repeat its divisions, and x·(1/m) is not rewritten into x/m (which rounds
    # differently), so at the spec's values every product is the folded constant's, bit for bit.
    minv_expr = inverse_mass(model)
    parametric = isinstance(minv_expr, ca.SX)
    minv = ca.SX.sym("minv", minv_expr.sparsity()) if parametric else minv_expr
    xdot, lam = plant_derivative(model, u, zeta, omega, rows, row_weights(model, rows, active), minv)
    deriv_inputs = [ca.vertcat(q, qd), u, zeta, omega, s, sd, sdd, active, theta]
    if parametric:
        deriv_inputs.append(ca.vertcat(*minv.nonzeros()))
        minv_fn = ca.Function(f"{name}_inverse_mass", [theta], [ca.vertcat(*minv_expr.nonzeros())], {"cse": True})
    deriv = ca.Function(f"{name}_derivative", deriv_inputs, [xdot, lam], {"cse": True})
    # Per cable: tension from the row's multiplier, gap from the row's φ = |d|² − L² as φ / (|d| + L)
    # (no cancellation near taut), both as functions of their own inputs.
    lengths = cable_lengths(model, q)
    crows = cable_rows(model)
    multipliers = ca.SX.sym("lambda", len(rows))
    tension = ca.vertcat(
        *[2 * lengths[c] * multipliers[rows.index(r)] if r in rows else ca.SX(0) for c, r in enumerate(crows)]
    )
    tension_fn = ca.Function(f"{name}_tension", [q, multipliers, theta], [tension], {"cse": True})
    gap = ca.vertcat(
        *[model.phi[r] / (ca.sqrt(model.phi[r] + lengths[c] ** 2) + lengths[c]) for c, r in enumerate(crows)]
    )
    gap_fn = ca.Function(f"{name}_gap", [q, s, theta], [gap], {"cse": True})
    independent_cables = [c for c, r in enumerate(crows) if r in rows]

    x = ca.MX.sym("x", 2 * n + 3)
    um = ca.MX.sym("u", lay.l)
    settings = ca.MX.sym("settings", 3)  # h, ζ_B, ω_B
    stage = ca.MX.sym("stage_signals", 9 * ns)  # [s, ṡ, s̈] at t, t + h/2, t + h
    mask = ca.MX.sym("cable_active", nc)
    params = ca.MX.sym("plant_params", theta.shape[0])
    h, z, w = settings[0], settings[1], settings[2]
    minv_nz = [minv_fn(params)] if parametric else []

    def f(xx, k):
        sig = stage[3 * ns * k : 3 * ns * (k + 1)]
        return deriv(xx[: 2 * n], um, z, w, sig[:ns], sig[ns : 2 * ns], sig[2 * ns :], mask, params, *minv_nz)

    k1, lam1 = f(x, 0)
    k2, _ = f(x + 0.5 * h * k1, 1)
    k3, _ = f(x + 0.5 * h * k2, 1)
    x4 = x + h * k3
    k4, lam4 = f(x4, 2)
    x_next = x + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
    start_tension = tension_fn(x[:n], lam1, params)
    # The last stage's tension, at its estimate of the end state: free here, and close enough to flag a
    # cable whose tension crosses zero inside the step (the plant locates the instant on exact tensions).
    end_tension = tension_fn(x4[:n], lam4, params)
    end_gap = gap_fn(x_next[:n], stage[6 * ns : 7 * ns], params)
    slack_indicator, taut_indicator = ca.MX(0), ca.MX(0)
    for c in independent_cables:
        slack_indicator = ca.fmax(slack_indicator, -mask[c] * ca.fmin(start_tension[c], end_tension[c]))
        taut_indicator = ca.fmax(taut_indicator, (1 - mask[c]) * end_gap[c])
    return ca.Function(
        name,
        [x, um, settings, stage, mask, params],
        [x_next, start_tension, end_gap, ca.vertcat(slack_indicator, taut_indicator)],
        # A folded plant's parameter input is empty: named apart, so that it shares no buffer with the
        # parametric plant's (the bindings share inputs by name).
        ["x", "u", "settings", "stage_signals", "cable_active", "plant_params" if parametric else "no_plant_params"],
        ["x_next", "cable_tension", "cable_gap", "cable_events"],
    )
