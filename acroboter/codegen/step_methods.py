"""The graph of one control step per method (acroboter.codegen.export_step): MLM (reduced or full system,
or the servo-constraints' least squares with internal forces), the penalty and iterative penalty methods
(multiplier or matrix form) and their input recoveries, each bounded by the input limits where the spec has
them (acroboter.codegen.step_qp).

Refused here, as ExportError: what the export cannot do for a spec (a singular MLM system, a recovery that
needs as many servo-constraints as inputs, a distribution it cannot bound).
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from ..model.settings import MLM_RCOND_LIMIT, PENALTY_SECONDARY_WEIGHT, RANK_TOLERANCE
from .solver_terms import mlm_bounded_terms, penalty_bounded_terms, servo_maps
from .step_graph import LINSOL_GENERAL, LINSOL_SPD, ExportError, StepGraph, constant
from .step_qp import symmetric, symmetric_numeric

# Non-redundant inputs: the distribution's Hessian must be nonsingular at the nominal configuration, its
# smallest/largest eigenvalue this far above acroboter.control.distribution.RANK_TOLERANCE (which is relative to
# the mean eigenvalue, never above the largest: the check is the stricter one).
SINGULAR_MARGIN = 1e3


def mlm_step(graph: StepGraph, system: str) -> ca.MX:
    """[M φ_qᵀ −H; φ_q 0 0; σ_q 0 0] [q̈; λ; u] = [−c; −γ; −ρ_s] (paper eq. 4), by sparse QR.

    'reduced' (default): M is constant, so q̈ = −M⁻¹(c + W y) with W = [φ_qᵀ, −H], y = [λ; u], C = [φ_q; σ_q]
    leaves the (m+l) square system (C M⁻¹ W) y = [γ; ρ_s] − C M⁻¹ c, the same reduction as the Python
    controller. 'full': the (n+m+l) system as written.
    """
    export, T = graph.export, graph.sx
    n, m, k, l = graph.n, graph.m, graph.k, graph.l
    if k > l:
        raise ExportError(
            f"MLM needs at least as many inputs as servo-constraints, found {k} servo-constraints for {l} inputs "
            "(redundant task): its matrix is not square. Export the penalty or iterative penalty method."
        )
    if l > k:
        return _mlm_internal_forces(graph)
    phi_q, sigma_q, H, c = T["phi_q"], T["sigma_q"], T["input_matrix"], T["bias_forces"]
    if system == "full":
        matrix = ca.vertcat(
            ca.horzcat(ca.SX(graph.mass_dm), phi_q.T, -H),
            ca.horzcat(phi_q, ca.SX(m, m + l)),
            ca.horzcat(sigma_q, ca.SX(k, m + l)),
        )
        rhs = ca.vertcat(-c, -T["gamma"], -graph.rho_s)
        offset = n + m
    else:
        w = ca.horzcat(phi_q.T, -H)
        cons = ca.vertcat(phi_q, sigma_q)
        minv = ca.SX(graph.inv_mass_dm)
        matrix = ca.mtimes(cons, ca.mtimes(minv, w))
        rhs = ca.vertcat(T["gamma"], graph.rho_s) - ca.mtimes(cons, ca.mtimes(minv, c))
        offset = m
    size = matrix.shape[0]
    numeric = graph.nominal(matrix)
    rcond = 1.0 / np.linalg.cond(numeric, 1)
    if not np.isfinite(rcond) or rcond < MLM_RCOND_LIMIT:
        raise ExportError(
            f"MLM's {size}x{size} system is singular at the nominal configuration (reciprocal condition number "
            f"{rcond:.1e}): the constraints are redundant or the task is not reachable by the inputs. "
            "Export the penalty or iterative penalty method, which handle redundancy."
        )
    pre = {"matrix": matrix, "rhs": rhs}
    if graph.wants_qdd and system == "reduced":  # q̈ = −M⁻¹(c + W y), as controllers.MLM.qdd
        pre.update({"minv_bias": ca.mtimes(minv, c), "minv_w": ca.mtimes(minv, w)})
    P = graph.prelude(pre)
    if export.parametric:
        # The fast path's singular-system check (controllers.MLM: LAPACK's gecon every step): with the same
        # factorization as y, A⁻¹ applied to two fixed vectors, 1/n·ones (gecon's start) and Higham's alternating
        # (−1)^i (1 + i/(n−1)) (LAPACK dlacn2's extra test), gives lower bounds on ‖A⁻¹‖₁, so an estimate of the
        # reciprocal 1-norm condition number that is never below the true one (as gecon's); the caller hands
        # every step whose estimate is within FAST_RCOND_MARGIN of MLM_RCOND_LIMIT to the reference and gecon.
        probes = np.stack([np.full(size, 1.0 / size), [(-1.0) ** i * (1.0 + i / (size - 1)) for i in range(size)]], 1)
        both = ca.solve(P["matrix"], ca.horzcat(P["rhs"], ca.DM(probes)), LINSOL_GENERAL)
        x, images = both[:, 0], both[:, 1:]
        norm1 = ca.mmax(ca.sum1(ca.fabs(P["matrix"])))
        lower = ca.mmax(ca.sum1(ca.fabs(images)) / ca.DM(np.abs(probes).sum(axis=0)).T)  # ≤ ‖A⁻¹‖₁
        graph.outputs["rcond"] = 1.0 / (norm1 * lower)
    else:
        x = ca.solve(P["matrix"], P["rhs"], LINSOL_GENERAL)
    if graph.wants_qdd:  # where a limit binds: _mlm_bounded_qdd (the reduced system only)
        graph.qdd = x[:n] if system == "full" else -(P["minv_bias"] + ca.mtimes(P["minv_w"], x))
    what = "reduced by the constant M (Schur complement in [lambda; u])" if system == "reduced" else "as written"
    export.linear_solvers.append(
        f"'{LINSOL_GENERAL}' (sparse Householder QR) on the {size}x{size} MLM system, {what}; reciprocal "
        f"1-norm condition number {rcond:.1e} at the nominal configuration"
    )
    export.notes.append(
        "MLM's matrix becomes singular only if the constraints turn redundant or the task unreachable; the "
        "C has no condition estimate, so a non-finite u signals that case: the caller must test isfinite(u)."
    )
    u0 = x[offset : offset + l]
    bounds = graph.bounds
    if not bounds.bounded:
        return u0
    terms = mlm_bounded_terms(graph.model, graph.params)
    check_nonsingular(graph, terms["hessian"], "MLM's servo-constraint least squares E^T E")
    export.distribution.append(
        "u = MLM's solution if within the limits; otherwise (a Switch, evaluated only then) the bounded least "
        "squares of the servo-constraints, 1/2 |E u - e|^2 (codegen.solver_terms.mlm_bounded_terms, "
        "E = sigma_q P H), over lower <= u <= upper: its unbounded minimiser -(E^T E)^-1 E^T e (SX Cholesky) if "
        "within, else the QP"
    )

    def branch(inputs, _extra):
        hessian, gradient = graph.bounds.sx_call("mlm_terms", graph.sx_inputs,
                                                 [symmetric(terms["hessian"]), terms["gradient"]], inputs)
        return graph.bounds.full_rank(hessian, gradient)

    out = bounds.after_unbounded(u0, [], branch)
    if graph.wants_qdd:
        graph.qdd = _mlm_bounded_qdd(graph, P, x, out[:l], u0)
    return out


def _mlm_bounded_qdd(graph: StepGraph, P: dict, x: ca.MX, u: ca.MX, u0: ca.MX) -> ca.MX:
    """controllers.MLM.qdd where a limit may bind: q̈ = −M⁻¹(c + W y) with y the Schur solution if u0 is within
    the limits, else y = [λ; u] with λ from the geometric rows, φ_q M⁻¹φ_qᵀ λ = rhs − schur[:m, m:] u (symmetric
    positive definite: LDLᵀ), evaluated only then (a Switch)."""
    m = graph.m

    def reactions(a):
        schur, rhs = a[2], a[3]
        lam_map = schur[:m, :m]
        residual = rhs[:m] - ca.mtimes(schur[:m, m:], a[1])
        lam = ca.solve(0.5 * (lam_map + lam_map.T), residual, LINSOL_SPD)
        return -(a[4] + ca.mtimes(a[5], ca.vertcat(lam, a[1])))

    return graph.bounds.switch("reactions", graph.bounds.within(u0),
                               [x, u, P["matrix"], P["rhs"], P["minv_bias"], P["minv_w"]],
                               lambda a: -(a[4] + ca.mtimes(a[5], a[0])), reactions)


def _mlm_internal_forces(graph: StepGraph) -> ca.MX:
    """MLM with more inputs than servo-constraints: E u = e has a family of solutions (internal forces).

    As controllers.MLM: always the distribution of codegen.solver_terms.mlm_bounded_terms, lexicographic
    (the servo-constraints exactly, then the internal forces at the preferred values), within the limits.
    """
    export, bounds, k, l = graph.export, graph.bounds, graph.k, graph.l
    terms = mlm_bounded_terms(graph.model, graph.params)
    e_map = terms["servo_map"]
    singular = np.linalg.svd(graph.nominal(e_map), compute_uv=False)
    ratio = (singular[-1] / singular[0]) ** 2 if singular[0] > 0 else 0.0
    if not ratio > SINGULAR_MARGIN * RANK_TOLERANCE:
        raise ExportError(
            f"MLM with {l} inputs for {k} servo-constraints: E = sigma_q P H ({k}x{l}) is rank deficient at the "
            f"nominal configuration (smallest/largest eigenvalue of E E^T {ratio:.1e}): the task is not reachable "
            "by the inputs. Export the penalty or iterative penalty method."
        )
    P = graph.prelude({"servo_map": e_map, "servo_target": terms["servo_target"]})
    export.system = "servo_least_squares"
    export.linear_solvers.append(
        f"SX Cholesky of the {k}x{k} matrix E E^T of MLM's servo-constraints E u = e (E = sigma_q P H, "
        f"codegen.solver_terms.mlm_bounded_terms; smallest/largest eigenvalue {ratio:.1e} at the nominal "
        "configuration): no Schur system, as the Python controller with more inputs than servo-constraints"
    )
    export.distribution.append(
        f"{l} inputs for {k} servo-constraints: u = u_pref + E^T (E E^T)^-1 (e - E u_pref), the solution of E u = e "
        "closest to the preferred values (acroboter.control.distribution's lexicographic eigen split of E^T E, in "
        "closed form)" + (", if within the limits; otherwise the QP with Hessian E^T E + mu Z Z^T, Z Z^T = "
        "I - E^T (E E^T)^-1 E, mu = SECONDARY_WEIGHT * tr(E^T E)/l" if bounds.bounded else "")
    )
    export.notes.append(
        "E E^T becomes singular only where the task is unreachable by the inputs; the C has no condition "
        "estimate there, so a non-finite u signals that case: the caller must test isfinite(u)."
    )
    return bounds.internal(P["servo_map"], P["servo_target"])


def penalty_step(graph: StepGraph, iterations: int, system: str) -> ca.MX:
    """Penalty (eqs. 8-13) and iterative penalty (eqs. 16-19), then the input recovery.

    A q̈₁ = −c + f, A q̈_{i+1} = M q̈_i + f with A = M + α̃ φ_qᵀφ_q + α̂ σ_qᵀσ_q, f = −α̃ φ_qᵀρ − α̂ σ_qᵀρ_s;
    λ̂ = α̂ (σ_q Σq̈_i + N ρ_s) and λ = α̃ (φ_q Σq̈_i + N ρ) (eqs. 17-18 summed), as in controllers.Penalty.
    """
    k, l, kind = graph.k, graph.l, graph.gains.recovery
    if kind in ("eq15", "kappa") and k != l:
        raise ExportError(
            f"recovery '{kind}' needs as many servo-constraints as inputs (found {k} for {l}): "
            "use 'projected' or 'eq12'"
        )
    recovery = _recovery_prelude(graph)
    mass_mx = ca.MX(graph.mass_dm)  # one constant node: the iterations' M q̈ and eq13's M q̈ share it
    if system == "matrix":
        P, lam, lam_hat, x = _penalty_matrix_form(graph, iterations, recovery, mass_mx)
    else:
        P, lam, lam_hat, x = _penalty_multiplier_form(graph, iterations, recovery)
    if graph.wants_qdd:
        graph.qdd = x  # q̈_N, the acceleration the method commands (controllers.Penalty.qdd)
    return _recovered_input(graph, P, lam, lam_hat, x, mass_mx)


def _penalty_matrix_form(graph: StepGraph, iterations: int, recovery: dict, mass_mx: ca.MX) -> tuple:
    """(P, λ, λ̂, q̈_N) of the n x n penalty matrix A = M + α̃ φ_qᵀφ_q + α̂ σ_qᵀσ_q, `iterations` solves."""
    export, g, T, n = graph.export, graph.gains, graph.sx, graph.n
    kind, lam = g.recovery, None
    phi_q, sigma_q, c = T["phi_q"], T["sigma_q"], T["bias_forces"]
    mass = ca.SX(graph.mass_dm)
    a = mass + g.alpha_geometric * ca.mtimes(phi_q.T, phi_q) + g.alpha_servo * ca.mtimes(sigma_q.T, sigma_q)
    force = -g.alpha_geometric * ca.mtimes(phi_q.T, graph.rho) - g.alpha_servo * ca.mtimes(sigma_q.T, graph.rho_s)
    pre = {"a": a, "force": force, "rhs": force - c, "sigma_q": sigma_q, "rho_s": graph.rho_s}
    if kind == "eq13":
        pre.update({"bias_forces": c, "phi_q": phi_q, "rho": graph.rho})
    P = graph.prelude(pre | recovery)
    # CasADi's MX linsol node factors A at every solve: the iterations refactor the same matrix
    # (identical numbers, so the same result as factoring once; only the cost differs).
    x = ca.solve(P["a"], P["rhs"], LINSOL_SPD)
    total = x
    for _ in range(iterations - 1):
        x = ca.solve(P["a"], ca.mtimes(mass_mx, x) + P["force"], LINSOL_SPD)
        total = total + x
    export.linear_solvers.append(
        f"'{LINSOL_SPD}' (sparse LDL^T) on the {n}x{n} penalty matrix A, {iterations} solve(s)"
    )
    lam_hat = graph.mx_gain("alpha_servo") * (ca.mtimes(P["sigma_q"], total) + iterations * P["rho_s"])
    if kind == "eq13":
        lam = graph.mx_gain("alpha_geometric") * (ca.mtimes(P["phi_q"], total) + iterations * P["rho"])
    return P, lam, lam_hat, x


def _penalty_multiplier_form(graph: StepGraph, iterations: int, recovery: dict) -> tuple:
    """(P, λ, λ̂, q̈_N or None) of the (m+k) x (m+k) multiplier matrix K = D⁻¹ + J M⁻¹ Jᵀ.

    With J = [φ_q; σ_q], D = diag(α̃ I, α̂ I), ρ_J = [ρ; ρ_s]: A = M + JᵀDJ, and A q̈_{i+1} = M q̈_i − JᵀDρ_J is
    M q̈_{i+1} = M q̈_i − JᵀΔΛ_{i+1} with ΔΛ_{i+1} = D(J q̈_{i+1} + ρ_J) the increment of [λ; λ̂] (eqs. 17-18).
    Eliminating q̈_{i+1}: K ΔΛ_{i+1} = J q̈_i + ρ_J, where J q̈₀ + ρ_J = ρ_J − J M⁻¹c and, by the definition of
    ΔΛ_i, J q̈_i + ρ_J = D⁻¹ΔΛ_i for i ≥ 1. The same iterates as the matrix form (Woodbury's identity), but the
    multipliers are solved for directly instead of as α times a residual of size 1/α.
    """
    export, g, T = graph.export, graph.gains, graph.sx
    m, k, kind, x = graph.m, graph.k, g.recovery, None
    phi_q, sigma_q, c = T["phi_q"], T["sigma_q"], T["bias_forces"]
    jac = ca.vertcat(phi_q, sigma_q)
    minv = ca.SX(graph.inv_mass_dm)
    minv_jt = ca.mtimes(minv, jac.T)
    if export.parametric:  # D⁻¹ from the run-time gains
        inv_sx = ca.vertcat(*([1.0 / g.alpha_geometric] * m + [1.0 / g.alpha_servo] * k))
        matrix = ca.diag(inv_sx) + ca.mtimes(jac, minv_jt)
    else:
        inv_penalty = np.array([1.0 / g.alpha_geometric] * m + [1.0 / g.alpha_servo] * k)
        matrix = ca.SX(constant(np.diag(inv_penalty))) + ca.mtimes(jac, minv_jt)
    qdd0 = -ca.mtimes(minv, c)
    pre = {"k": matrix, "rhs": ca.vertcat(graph.rho, graph.rho_s) + ca.mtimes(jac, qdd0)}
    if export.parametric:
        pre["inv_penalty"] = inv_sx
    if kind == "eq13":
        pre.update({"minv_jt": minv_jt, "qdd0": qdd0, "bias_forces": c, "phi_q": phi_q})
    elif graph.wants_qdd:
        pre.update({"minv_jt": minv_jt, "qdd0": qdd0})
    P = graph.prelude(pre | recovery)
    step = ca.solve(P["k"], P["rhs"], LINSOL_SPD)
    multipliers = step
    for _ in range(iterations - 1):
        step = ca.solve(P["k"], (P["inv_penalty"] if export.parametric else ca.DM(inv_penalty)) * step, LINSOL_SPD)
        multipliers = multipliers + step
    if kind == "eq13" or graph.wants_qdd:
        x = P["qdd0"] - ca.mtimes(P["minv_jt"], multipliers)  # q̈_N
    size = m + k
    export.linear_solvers.append(
        f"'{LINSOL_SPD}' (sparse LDL^T) on the {size}x{size} multiplier matrix D^-1 + J M^-1 J^T, "
        f"{iterations} solve(s)"
    )
    return P, multipliers[:m], multipliers[m:], x


def _recovered_input(graph: StepGraph, P: dict, lam, lam_hat, x, mass_mx: ca.MX) -> ca.MX:
    """u from the multipliers by the spec's recovery, within the limits."""
    export, g, k, l = graph.export, graph.gains, graph.k, graph.l
    kind, bounds = g.recovery, graph.bounds
    if kind == "projected" and l > k:
        # More inputs than servo-constraints: as controllers.Penalty, always the distribution of the fit
        # ½uᵀGu + gᵀu, G = EᵀE, g = servo_map λ̂ (codegen.solver_terms.penalty_bounded_terms), lexicographic in
        # the servo accelerations E u (E from codegen.solver_terms.mlm_bounded_terms).
        return bounds.task(P["bounded_hessian"], ca.mtimes(P["bounded_servo_map"], lam_hat), P["bounded_task_map"])
    if kind == "projected":
        size = P["normal"].shape[0]
        rhs = -ca.mtimes(P["normal_map"], lam_hat)
        solver = LINSOL_GENERAL if graph.k == l else LINSOL_SPD
        export.linear_solvers.append(f"'{solver}' on the {size}x{size} matrix of the projected recovery")
        u0 = ca.solve(P["normal"], rhs, solver)
        return _bounded_projected(graph, u0, lam_hat)
    if kind == "eq15":
        return _box_projection(graph, lam_hat)
    export.linear_solvers.append(f"'{LINSOL_SPD}' on the {l}x{l} matrix H^T H")
    if kind == "eq12":  # u = −(HᵀH)⁻¹Hᵀ σ_qᵀλ̂: min ½|H u + σ_qᵀλ̂|², gradient Hᵀσ_qᵀλ̂
        gradient = ca.mtimes(P["h_servo"], lam_hat)
        return _bounded_fit(graph, ca.solve(P["hth"], -gradient, LINSOL_SPD), gradient)
    if kind == "eq13":  # u = (HᵀH)⁻¹Hᵀ (M q̈ + c + φ_qᵀλ): min ½|H u − (M q̈ + c + φ_qᵀλ)|²
        generalized = ca.mtimes(mass_mx, x) + P["bias_forces"] + ca.mtimes(P["phi_q"].T, lam)
        gradient = -ca.mtimes(P["h_t"], generalized)
        return _bounded_fit(graph, ca.solve(P["hth"], -gradient, LINSOL_SPD), gradient)
    # kappa: u = −(κ(HᵀH)⁻¹Hᵀ − (1 − κ)σ_q) σ_qᵀλ̂ (sign of the σ_q term: see acroboter/recovery.py)
    pseudo = ca.solve(P["hth"], ca.mtimes(P["h_servo"], lam_hat), LINSOL_SPD)
    return _box_projection(graph, -(g.kappa * pseudo - (1.0 - g.kappa) * ca.mtimes(P["servo_servo"], lam_hat)))


def _bounded_projected(graph: StepGraph, u0: ca.MX, lam_hat: ca.MX) -> ca.MX:
    """Projected recovery, no more inputs than servo-constraints: u0 if within the limits, else the same fit
    ½uᵀGu + gᵀu (G = EᵀE, g = servo_map λ̂, codegen.solver_terms.penalty_bounded_terms) bounded, lexicographic."""
    bounds, model = graph.bounds, graph.model
    if not bounds.bounded:
        return u0
    terms = penalty_bounded_terms(model, graph.params)
    check_nonsingular(graph, terms["hessian"], "the projected recovery's fit E^T E")
    lam_sx = ca.SX.sym("lam_hat", graph.k)
    outputs = [symmetric(terms["hessian"]), ca.mtimes(terms["servo_map"], lam_sx)]
    graph.export.distribution.append(
        "u = the projected recovery if within the limits; otherwise (a Switch, evaluated only then) the same fit "
        "1/2 u^T G u + g^T u, G = E^T E, g = E^T F lambda_hat (E = sigma_q P H, F = sigma_q P sigma_q^T: "
        "codegen.solver_terms.penalty_bounded_terms) "
        "over lower <= u <= upper: its unbounded minimiser -G^-1 g (SX Cholesky) if within, else the QP"
    )

    def branch(inputs, extra):
        hessian, gradient = bounds.sx_call("projected_terms", [*graph.sx_inputs, lam_sx], outputs, [*inputs, *extra])
        return bounds.full_rank(hessian, gradient)

    return bounds.after_unbounded(u0, [lam_hat], branch)


def _bounded_fit(graph: StepGraph, u0: ca.MX, gradient: ca.MX) -> ca.MX:
    """eq12/eq13: u0 if within the limits, else their least squares in H u bounded (G = HᵀH): lexicographic,
    or weighted (PENALTY_SECONDARY_WEIGHT) with more inputs than servo-constraints, as controllers.Penalty."""
    bounds, l = graph.bounds, graph.l
    if not bounds.bounded:
        return u0
    H = graph.sx["input_matrix"]
    hth = ca.mtimes(H.T, H)
    weighted = l > graph.k
    if not weighted:
        check_nonsingular(graph, hth, "H^T H")
    graph.export.distribution.append(
        f"u = the {graph.gains.recovery} recovery if within the limits; otherwise (a Switch, evaluated only then) its "
        "least squares 1/2 u^T H^T H u + g^T u over lower <= u <= upper: "
        + ("weighted toward the preferred values, (H^T H + mu I) u = -g + mu u_pref, mu = PENALTY_SECONDARY_WEIGHT * "
           "tr(H^T H)/l (Cholesky), if within, else the QP with that Hessian" if weighted else
           "its unbounded minimiser (SX Cholesky) if within, else the QP")
    )

    def branch(inputs, extra):
        (hessian,) = bounds.sx_call("fit_terms", list(graph.sx_inputs), [symmetric(hth)], inputs)
        if weighted:
            return bounds.weighted(hessian, extra[0], PENALTY_SECONDARY_WEIGHT)
        return bounds.full_rank(hessian, extra[0])

    return bounds.after_unbounded(u0, [gradient], branch)


def _box_projection(graph: StepGraph, u: ca.MX) -> ca.MX:
    """eq15/kappa: explicit maps; bounded, the input within the limits closest to theirs (G = I): a clip."""
    if not graph.bounds.bounded:
        return u
    graph.export.distribution.append(
        f"u = the {graph.gains.recovery} recovery clipped onto the limits (its bounded form min 1/2 |u - u_rec|^2, "
        "G = I, as acroboter.control.recovery.InputRecovery.least_squares: the box projection, fmin/fmax)"
    )
    return graph.bounds.report_clip(u)


def _recovery_prelude(graph: StepGraph) -> dict[str, ca.SX]:
    """The state-dependent matrices of the input recovery (everything but λ̂), as SX."""
    T, kind, l = graph.sx, graph.gains.recovery, graph.l
    H, sigma_q = T["input_matrix"], T["sigma_q"]
    if kind == "projected" and graph.l > graph.k:
        terms = penalty_bounded_terms(graph.model, graph.params)
        e_map = mlm_bounded_terms(graph.model, graph.params)["servo_map"]
        k, l = graph.k, graph.l
        gram = ca.mtimes(e_map, e_map.T)
        check_nonsingular(graph, gram, f"the servo-constraint map E E^T ({k}x{k}, E = sigma_q P H)")
        ratio = check_nonsingular(graph, ca.mtimes([e_map, terms["hessian"], e_map.T]),
                                  f"the projected fit in the task directions E G E^T ({k}x{k})")
        graph.export.linear_solvers.append(
            f"SX Cholesky of the {k}x{k} matrices E G E^T (smallest/largest eigenvalue {ratio:.1e} at the nominal "
            "configuration) and E E^T of the input distribution (G = E^T E, "
            "codegen.solver_terms.penalty_bounded_terms; E = sigma_q P H, codegen.solver_terms.mlm_bounded_terms; "
            "P through an SX Cholesky of phi_q M^-1 phi_q^T)"
        )
        graph.export.distribution.append(
            f"{l} inputs for {k} servo-constraints: as controllers.Penalty, always the distribution of the projected "
            "recovery's fit 1/2 u^T G u + g^T u, G = E^T E, g = E^T F lambda_hat (F = sigma_q P sigma_q^T), "
            "lexicographic in the servo accelerations E u (acroboter.control.distribution.BoundedInputs.solve_task): "
            "the fit's input in the task directions u_F = -E^T (E G E^T)^-1 E g, its servo accelerations "
            "e_F = E u_F exactly and the internal forces (null(E)) at the preferred values: "
            "u = u_pref + E^T (E E^T)^-1 (e_F - E u_pref)"
            + (", if within the limits; otherwise the QP with Hessian E^T E + mu Z Z^T, Z Z^T = I - E^T (E E^T)^-1 E, "
               "gradient -E^T e_F - mu Z Z^T u_pref, mu = SECONDARY_WEIGHT * tr(E^T E)/l"
               if graph.bounds.bounded else "")
        )
        return {"bounded_hessian": symmetric(terms["hessian"]), "bounded_servo_map": terms["servo_map"],
                "bounded_task_map": e_map}
    if kind == "projected":
        return _projected_prelude(graph)
    if kind == "eq15":
        return {}
    if np.linalg.matrix_rank(graph.nominal(H)) < l:
        raise ExportError("H^T H is singular: the actuators' generalized forces are linearly dependent")
    pre = {"hth": ca.mtimes(H.T, H)}
    if kind in ("eq12", "kappa"):
        pre["h_servo"] = ca.mtimes(H.T, sigma_q.T)
    if kind == "eq13":
        pre["h_t"] = H.T
    if kind == "kappa":
        pre["servo_servo"] = ca.mtimes(sigma_q, sigma_q.T)
    return pre


def _projected_prelude(graph: StepGraph) -> dict[str, ca.SX]:
    """The projected recovery's fit |E u + F λ̂|² (codegen.solver_terms.penalty_bounded_terms: the servo accelerations
    of the inputs against those of the ideal servo force). As many inputs as servo-constraints: E u = −F λ̂ itself
    (QR; the normal equations would square E's condition); more servo-constraints: EᵀE u = −EᵀF λ̂ (LDLᵀ). E of full
    column rank is MLM's condition, checked at the nominal configuration."""
    e_map, f_map = servo_maps(graph.model)
    singular = np.linalg.svd(graph.nominal(e_map), compute_uv=False)
    ratio = (singular[-1] / singular[0]) ** 2 if singular[0] > 0 else 0.0  # as E^T E's eigenvalues
    if not ratio > SINGULAR_MARGIN * RANK_TOLERANCE:
        raise ExportError(
            f"the projected recovery's matrix E = sigma_q P H is singular at the nominal configuration (smallest/"
            f"largest eigenvalue of E^T E {ratio:.1e}): the inputs cannot set the servo accelerations there, and MLM "
            "cannot run either; export --recovery eq12 or eq13, or run the Python controller with --recovery kinetic"
        )
    graph.export.notes.append(
        f"projected recovery: E = sigma_q P H, F = sigma_q P sigma_q^T, P through an SX Cholesky of phi_q M^-1 "
        f"phi_q^T over the independent rows{_dropped(graph)}; smallest/largest eigenvalue of E^T E {ratio:.1e} at "
        "the nominal configuration."
    )
    if graph.k == graph.l:
        return {"normal": e_map, "normal_map": f_map}
    return {"normal": symmetric(ca.mtimes(e_map.T, e_map)), "normal_map": ca.mtimes(e_map.T, f_map)}


def _dropped(graph: StepGraph) -> str:
    redundant = graph.model.layout.redundant_rows
    return f" ({len(redundant)} redundant constraint rows left out)" if redundant else ""


def check_nonsingular(graph: StepGraph, hessian: ca.SX, what: str) -> float:
    """Smallest/largest eigenvalue of the (SX) Hessian at the nominal configuration; refuse if singular."""
    eigenvalues = np.linalg.eigvalsh(symmetric_numeric(graph.nominal(hessian)))
    ratio = eigenvalues[0] / eigenvalues[-1] if eigenvalues[-1] > 0 else 0.0
    if not ratio > SINGULAR_MARGIN * RANK_TOLERANCE:
        raise ExportError(
            f"cannot bound the inputs: {what} is singular at the nominal configuration (smallest/largest "
            f"eigenvalue {ratio:.1e}); the exported distribution expects internal forces only where there are "
            "more inputs than servo-constraints (the Python controller's eigen split handles this case)"
        )
    return ratio
