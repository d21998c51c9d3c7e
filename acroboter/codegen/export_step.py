"""Export one controller's complete control step as self-contained C (issue "Embedded control step").

    python -m codegen.export_step [--spec model_spec/acroboter.toml] [--method penalty|mlm|iterative-N]
                                  [--recovery projected|eq12|eq13|eq15|kappa] [--kp ...] [--out DIR]

The step u = step(q, qd, s, sd, sdd) is one CasADi MX graph: the spec's SX model terms and what is
assembled from them (one casadi.Function with shared subexpressions, called on the MX symbols), the
linear solves as casadi.solve(..., linsol) with linear solvers CasADi generates C for ('ldl', sparse
LDLᵀ, for the symmetric positive definite matrices; 'qr', sparse Householder QR, for MLM's nonsymmetric
indefinite system), the input recovery and the bounded input distribution (below). CasADi's
CodeGenerator writes <name>.c and <name>.h: plain C linked against libm only (sqrt, sincos, fmin, fmax;
plus the compiler's memset): no Python, no LAPACK, no heap. The QP solver's inlined runtime includes
<stdio.h> and <stdarg.h> for iteration printing that is compiled out (CASADI_SNPRINTF is not defined),
so no stdio function is referenced; a target without those headers needs empty stand-ins.

Formulations (the same control law; the options only choose which linear systems are solved):
- penalty / iterative-N, --penalty-system multipliers (what 'auto', the default, picks unless the spec
  has redundant constraints): with J = [φ_q; σ_q], D = diag(α̃, α̂),
  A = M + JᵀDJ, and each iteration A q̈_{i+1} = M q̈_i − JᵀDρ_J is solved through the multiplier
  increment ΔΛ = [Δλ; Δλ̂]: (D⁻¹ + J M⁻¹Jᵀ) ΔΛ = J q̈_i + ρ_J (Woodbury; M is constant). The matrix is
  (m+k) square and sparse instead of n square and nearly full, and λ̂ comes out directly instead of
  as α̂ times a residual of size 1/α̂: 2-3x faster and, against a 40-digit reference, u to ~1e-14
  where the A form (and the Python controller, which uses it) reach ~1e-10.
- --penalty-system matrix: A q̈ = ... with A = M + α̃ φ_qᵀφ_q + α̂ σ_qᵀσ_q, as controllers.Penalty.
  'auto' picks it for specs with redundant constraints: their rows make D⁻¹ + J M⁻¹Jᵀ nearly singular
  (eigenvalues ~1/α) and, off the constraint manifold (measured states), their multipliers large, so
  λ̂ carries their round-off (~1e-7 relative in trials) where the A form keeps ~1e-9.
- mlm, --mlm-system reduced (default): [M φ_qᵀ −H; φ_q 0 0; σ_q 0 0] reduced by the constant M to its
  (m+l) Schur complement in (λ, u), as controllers.MLM; --mlm-system full: the (n+m+l) system itself.

Gains are baked into the C as constants, not taken as a parameter input: the step is a fixed artifact
for the robot's real-time computer, compiled from a spec whose [controller] section already holds
the tuned numbers; constants let CasADi fold them (e.g. α̃ φ_qᵀφ_q is one scaled product), keep the
call signature the same as the model functions (q, qd, s, sd, sdd), and leave no way to run with a
mismatched or unvalidated gain set. Changing a gain means re-exporting; the header records them all.

The mass matrix of natural coordinates is constant, so its Cholesky factor's inverse L⁻¹ (used by the
'projected' recovery, a least squares in the M⁻¹ metric) is a numeric constant in the C as well.

Input limits (the spec's actuator `limits` and `preferred`, baked in as constants like the gains) are
honoured as the Python controllers do (acroboter.distribution.BoundedInputs), branch for branch, so the
C gives their u also where a limit binds:
- no more inputs than servo-constraints: the unbounded u above if it is within the limits (bit for bit
  the unbounded export); otherwise, in a CasADi Switch that the C evaluates only then, the recovery's
  least squares ½uᵀGu + gᵀu (projected: G = HᵀPH, g = HᵀPσ_qᵀλ̂, codegen.structured.penalty_bounded_terms;
  MLM: ½|E u − e|², mlm_bounded_terms; eq12/eq13: G = HᵀH), its unbounded minimiser if within, else a
  box QP; eq15/kappa (explicit maps, G = I): the clip onto the limits.
- more inputs than servo-constraints (internal forces, e.g. the four-cable crane): always distributed.
  Penalty methods (projected recovery): weighted, (G + μI)u = −g + μ u_pref by SX Cholesky, with
  μ = PENALTY_SECONDARY_WEIGHT·tr(G)/l; MLM: lexicographic, u = u_pref + Eᵀ(EEᵀ)⁻¹(e − E u_pref) (Python's
  eigen split of EᵀE in closed form) and, bounded, the QP with Hessian EᵀE + μZZᵀ, ZZᵀ = I − Eᵀ(EEᵀ)⁻¹E,
  μ = SECONDARY_WEIGHT·tr(EᵀE)/l.
- G's scale is its mean eigenvalue tr(G)/l, as in BoundedInputs: a sum of the diagonal, no eigenvalue
  solver in the C.
- the QP is CasADi's own active-set solver 'qrqp', generated inline (no external library, no heap),
  with the step-2 Hessian and gradient divided by that scale (unit mean eigenvalue).
Recoveries the export cannot bound are refused (ExportError, exit 2): those whose distribution Hessian
is singular at the nominal configuration although there are no more inputs than servo-constraints
(Python's eigen split would find internal forces there), and MLM where E is rank deficient.
"""

from __future__ import annotations

import re
import textwrap
from dataclasses import dataclass, field
from pathlib import Path

import casadi as ca
import numpy as np
from scipy.linalg import cholesky, solve_triangular

from ..model.layout import Layout, nominal_coordinates
from ..model.settings import MLM_RCOND_LIMIT, PENALTY_SECONDARY_WEIGHT, RANK_TOLERANCE, SECONDARY_WEIGHT, Gains
from ..model.spec import MAX_ITERATIONS, RECOVERIES, Spec, load_spec
from .generate import INPUT_NAMES
from .structured import cholesky_solve, mlm_bounded_terms, penalty_bounded_terms
from .symbolic import SymbolicModel, build_symbolic_model

LINSOL_SPD = "ldl"  # sparse LDLᵀ, static ordering, no pivoting: fine for symmetric positive definite
LINSOL_GENERAL = "qr"  # sparse Householder QR: any nonsingular square matrix
# Model terms the step needs, in the order of the wrapped SX function's outputs.
TERMS = (
    "bias_forces", "phi", "phi_q", "phi_dot", "gamma",
    "sigma", "sigma_q", "sigma_dot", "gamma_s", "input_matrix",
)
GAIN_OPTIONS = ("kp", "kd", "alpha_geometric", "alpha_servo", "omega", "mu", "kappa")
# Relative singular value below which the projected recovery's least-squares matrix counts as rank
# deficient (redundant constraints): then, and only then, a Tikhonov term makes its normal equations solvable.
RANK_TOL = 1e-10
TIKHONOV = 1e-12
MLM_SYSTEMS = ("reduced", "full")
PENALTY_SYSTEMS = ("auto", "multipliers", "matrix")
SYSTEM_TEXT = {
    "reduced": "the (n+m+l) system reduced by the constant M to its (m+l) Schur complement in [lambda; u]",
    "full": "the (n+m+l) system as written",
    "multipliers": "each iteration solves (D^-1 + J M^-1 J^T) dLambda = J qdd_i + rho_J for the increment of "
    "[lambda; lambda_hat], J = [phi_q; sigma_q], D = diag(alpha_geometric, alpha_servo), rho_J = [rho; rho_s]; "
    "by Woodbury's identity the same iterates as A qdd_{i+1} = M qdd_i + f with A = M + J^T D J",
    "matrix": "each iteration solves A qdd_{i+1} = M qdd_i + f, A = M + alpha_geometric phi_q^T phi_q "
    "+ alpha_servo sigma_q^T sigma_q",
    "servo_least_squares": "more inputs than servo-constraints: no Schur system; the servo-constraints' "
    "accelerations E u = e on the constraint manifold (codegen.structured.mlm_bounded_terms), as controllers.MLM",
}


class ExportError(RuntimeError):
    """The step cannot be exported for this spec and method (clear message, no traceback in the CLI)."""


@dataclass
class StepExport:
    """The MX function of one control step and what the generated files will say about it."""

    name: str  # C symbol and file stem
    function: ca.Function
    spec: Spec
    spec_path: Path | None
    method: str
    iterations: int | None  # None for MLM
    gains: Gains
    layout: Layout
    system: str  # MLM: reduced | full; penalty methods: multipliers | matrix
    linear_solvers: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    distribution: list[str] = field(default_factory=list)  # how the input limits are honoured (header)
    qp_used: bool = False


def parse_method(method: str) -> int | None:
    """Iterations of a penalty method ('penalty' = 1, 'iterative-N' = N), None for 'mlm'."""
    if method == "mlm":
        return None
    if method == "penalty":
        return 1
    if method.startswith("iterative-") and method.removeprefix("iterative-").isdigit():
        iterations = int(method.removeprefix("iterative-"))
        if 1 <= iterations <= MAX_ITERATIONS:
            return iterations
    raise ExportError(f"unknown method '{method}': use mlm, penalty or iterative-N (1 <= N <= {MAX_ITERATIONS})")


def step_name(spec: Spec, method: str, recovery: str) -> str:
    """C symbol of the step: <spec>_<method>[_<recovery> if not the default projected]_step."""
    parts = [spec.name, method.replace("-", "_")]
    if method != "mlm" and recovery != "projected":
        parts.append(recovery)
    name = "_".join(parts) + "_step"
    if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", name):
        raise ExportError(f"'{name}' is not a valid C identifier")
    return name


def sx_terms(model: SymbolicModel) -> dict[str, ca.SX]:
    """The model terms the step needs as SX, with their structural sparsity (constant zeros removed).

    generate.py densifies its outputs for the numeric side; here the sparsity is kept, so the products
    and factorizations downstream only touch structural nonzeros.
    """
    return {t: ca.sparsify(ca.SX(getattr(model, t))) for t in TERMS}


def constant_mass_matrix(model: SymbolicModel) -> np.ndarray:
    """M as numbers; raise if it depends on the state (natural coordinates guarantee it does not)."""
    mass = ca.SX(model.mass_matrix)
    if not mass.is_constant():
        raise ExportError("the mass matrix depends on the state: the export assumes natural coordinates (constant M)")
    return np.array(ca.evalf(mass).full(), dtype=float)


def _constant(matrix: np.ndarray) -> ca.DM:
    """A numeric matrix as a sparse DM, dropping round-off entries of its block structure."""
    matrix = matrix.copy()
    matrix[np.abs(matrix) < 1e-15 * np.abs(matrix).max()] = 0.0
    return ca.sparsify(ca.DM(matrix))


class _Graph:
    """Shared state while one step's MX graph is built.

    `prelude(outputs)` turns SX expressions of (q, qd, s, sd, sdd) into one casadi.Function (the model
    terms and everything assembled from them, with common subexpressions shared, as straight-line C)
    and returns its outputs called on the step's MX inputs. The linear solves and the few products
    between them stay in MX.
    """

    def __init__(self, export: StepExport, model: SymbolicModel):
        self.export, self.model, self.gains = export, model, export.gains
        lay = model.layout
        self.n, self.m, self.k, self.l, ns = lay.n, lay.m, lay.k, lay.l, lay.n_signals
        self.sx = sx_terms(model)
        self.mass = constant_mass_matrix(model)
        chol = cholesky(self.mass, lower=True)
        self.inv_chol = solve_triangular(chol, np.eye(self.n), lower=True)  # L⁻¹, M = L Lᵀ
        self.mass_dm = _constant(self.mass)
        self.inv_mass_dm = _constant(self.inv_chol.T @ self.inv_chol)
        self.inputs = [ca.MX.sym("q", self.n), ca.MX.sym("qd", self.n)]
        self.inputs += [ca.MX.sym(name, ns) for name in ("s", "sd", "sdd")]
        g, T = self.gains, self.sx
        # ρ = γ + 2Ωμ φ̇ + Ω² φ (geometric penalty); ρ_s = γ_s + 2 k_D σ̇ + k_P² σ (servo error dynamics)
        self.rho = T["gamma"] + 2.0 * g.omega * g.mu * T["phi_dot"] + g.omega**2 * T["phi"]
        self.rho_s = T["gamma_s"] + 2.0 * g.kd * T["sigma_dot"] + g.kp**2 * T["sigma"]
        self.params = ca.DM(g.parameter_vector(self.k))  # codegen.structured's p, as constants (z = 0)
        self.bounds = _Bounds(self)

    def prelude(self, outputs: dict[str, ca.SX]) -> dict[str, ca.MX]:
        names = list(outputs)
        fn = ca.Function(
            f"{self.export.name}_terms", self.model.inputs, [outputs[k] for k in names],
            list(INPUT_NAMES), names, {"cse": True},
        )
        return dict(zip(names, fn(*self.inputs), strict=True))

    def nominal(self, expr: ca.SX) -> np.ndarray:
        """expr at the spec's nominal configuration, at rest, signals at the anchors' positions."""
        lay = self.model.layout
        q0 = nominal_coordinates(self.model.spec, lay)
        s0 = np.zeros(lay.n_signals)
        for anchor in self.model.spec.anchors:
            if anchor.name in lay.anchor_signal:
                j = lay.anchor_signal[anchor.name]
                s0[j : j + 3] = anchor.position
        zeros_q, zeros_s = np.zeros(lay.n), np.zeros(lay.n_signals)
        fn = ca.Function("nominal", self.model.inputs, [ca.densify(expr)])
        return np.array(fn(q0, zeros_q, s0, zeros_s, zeros_s).full())


def build_step(spec: Spec, method: str, gains: Gains, spec_path: Path | None = None, name: str | None = None,
               mlm_system: str = "reduced", penalty_system: str = "auto") -> StepExport:
    """Build the MX function u = step(q, qd, s, sd, sdd) of one method with the given (baked-in) gains."""
    iterations = parse_method(method)
    if gains.recovery not in RECOVERIES:
        raise ExportError(f"unknown input recovery '{gains.recovery}': choose one of {', '.join(RECOVERIES)}")
    if penalty_system not in PENALTY_SYSTEMS:
        raise ExportError(f"unknown penalty system '{penalty_system}': choose one of {', '.join(PENALTY_SYSTEMS)}")
    if mlm_system not in MLM_SYSTEMS:
        raise ExportError(f"unknown MLM system '{mlm_system}': choose one of {', '.join(MLM_SYSTEMS)}")
    if gains.ki != 0:
        raise ExportError(
            f"integral action (ki = {gains.ki:g}) cannot be exported: the exported step is stateless "
            "(u from q, qd, s, sd, sdd) and the integral z = ∫σ dt with its anti-windup is state the Python "
            "controller holds (docs/integral_action.md): export from a spec without ki (or ki = 0) in its "
            "[controller], and add the integral on the target"
        )
    model = build_symbolic_model(spec)
    name = name or step_name(spec, method, gains.recovery)
    redundant = model.layout.redundant_rows
    if penalty_system == "auto":
        # Redundant rows make D⁻¹ + J M⁻¹Jᵀ nearly singular (eigenvalues ~ 1/α) and, off the constraint
        # manifold, their multipliers large: λ̂ then carries their round-off (~1e-7 relative in trials).
        penalty_system = "matrix" if redundant else "multipliers"
    system = mlm_system if iterations is None else penalty_system
    export = StepExport(name, None, spec, spec_path, method, iterations, gains, model.layout, system)  # type: ignore[arg-type]
    graph = _Graph(export, model)
    if iterations is not None and redundant and system == "multipliers":
        export.notes.append(
            "the spec has redundant constraints: the multiplier matrix is nearly singular and, off the constraint "
            "manifold, u loses accuracy (~1e-7 relative); --penalty-system matrix (auto's choice here) keeps ~1e-9."
        )
    elif iterations is not None and redundant:
        export.notes.append(
            "formulation 'matrix': the spec has redundant constraints, which make the multiplier form's matrix "
            "nearly singular."
        )
    if iterations is None:
        u = _mlm(graph, mlm_system)
    else:
        u = _penalty(graph, iterations, penalty_system)
    export.function = ca.Function(name, graph.inputs, [ca.densify(u)], list(INPUT_NAMES), ["u"])
    export.qp_used = graph.bounds.used_qp
    return export


def _mlm(graph: _Graph, system: str) -> ca.MX:
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
    P = graph.prelude({"matrix": matrix, "rhs": rhs})
    x = ca.solve(P["matrix"], P["rhs"], LINSOL_GENERAL)
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
    bounds.check_nonsingular(terms["hessian"], "MLM's servo-constraint least squares E^T E")
    export.distribution.append(
        "u = MLM's solution if within the limits; otherwise (a Switch, evaluated only then) the bounded least "
        "squares of the servo-constraints, 1/2 |E u - e|^2 (codegen.structured.mlm_bounded_terms, "
        "E = sigma_q P H), over lower <= u <= upper: its unbounded minimiser -(E^T E)^-1 E^T e (SX Cholesky) if "
        "within, else the QP"
    )

    def branch(inputs, _extra):
        hessian, gradient = graph.bounds.sx_call("mlm_terms", graph.model.inputs,
                                                 [_symmetric(terms["hessian"]), terms["gradient"]], inputs)
        return graph.bounds.full_rank(hessian, gradient)

    return bounds.after_unbounded(u0, [], branch)


def _mlm_internal_forces(graph: _Graph) -> ca.MX:
    """MLM with more inputs than servo-constraints: E u = e has a family of solutions (internal forces).

    As controllers.MLM: always the distribution of codegen.structured.mlm_bounded_terms, lexicographic
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
        f"codegen.structured.mlm_bounded_terms; smallest/largest eigenvalue {ratio:.1e} at the nominal "
        "configuration): no Schur system, as the Python controller with more inputs than servo-constraints"
    )
    export.distribution.append(
        f"{l} inputs for {k} servo-constraints: u = u_pref + E^T (E E^T)^-1 (e - E u_pref), the solution of E u = e "
        "closest to the preferred values (acroboter.distribution's lexicographic eigen split of E^T E, in closed "
        "form)" + (", if within the limits; otherwise the QP with Hessian E^T E + mu Z Z^T, Z Z^T = "
        "I - E^T (E E^T)^-1 E, mu = SECONDARY_WEIGHT * tr(E^T E)/l" if bounds.bounded else "")
    )
    export.notes.append(
        "E E^T becomes singular only where the task is unreachable by the inputs; the C has no condition "
        "estimate there, so a non-finite u signals that case: the caller must test isfinite(u)."
    )
    return bounds.internal(P["servo_map"], P["servo_target"])


def _penalty(graph: _Graph, iterations: int, system: str) -> ca.MX:
    """Penalty (eqs. 8-13) and iterative penalty (eqs. 16-19), then the input recovery.

    A q̈₁ = −c + f, A q̈_{i+1} = M q̈_i + f with A = M + α̃ φ_qᵀφ_q + α̂ σ_qᵀσ_q, f = −α̃ φ_qᵀρ − α̂ σ_qᵀρ_s;
    λ̂ = α̂ (σ_q Σq̈_i + N ρ_s) and λ = α̃ (φ_q Σq̈_i + N ρ) (eqs. 17-18 summed), as in controllers.Penalty.
    """
    export, g, T = graph.export, graph.gains, graph.sx
    n, k, l = graph.n, graph.k, graph.l
    kind = g.recovery
    if kind in ("eq15", "kappa") and k != l:
        raise ExportError(
            f"recovery '{kind}' needs as many servo-constraints as inputs (found {k} for {l}): "
            "use 'projected' or 'eq12'"
        )
    phi_q, sigma_q, c = T["phi_q"], T["sigma_q"], T["bias_forces"]
    mass_mx = ca.MX(graph.mass_dm)
    recovery = _recovery_prelude(graph)
    if system == "matrix":
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
        lam_hat = g.alpha_servo * (ca.mtimes(P["sigma_q"], total) + iterations * P["rho_s"])
        if kind == "eq13":
            lam = g.alpha_geometric * (ca.mtimes(P["phi_q"], total) + iterations * P["rho"])
    else:
        # Multiplier form. With J = [φ_q; σ_q], D = diag(α̃ I, α̂ I), ρ_J = [ρ; ρ_s]: A = M + JᵀDJ, and
        # A q̈_{i+1} = M q̈_i − JᵀDρ_J is M q̈_{i+1} = M q̈_i − JᵀΔΛ_{i+1} with ΔΛ_{i+1} = D(J q̈_{i+1} + ρ_J)
        # the increment of [λ; λ̂] (eqs. 17-18). Eliminating q̈_{i+1}: K ΔΛ_{i+1} = J q̈_i + ρ_J with
        # K = D⁻¹ + J M⁻¹ Jᵀ, where J q̈₀ + ρ_J = ρ_J − J M⁻¹c and, by the definition of ΔΛ_i, J q̈_i + ρ_J
        # = D⁻¹ΔΛ_i for i ≥ 1. The same iterates as the matrix form (Woodbury's identity), but the
        # multipliers are solved for directly instead of as α times a residual of size 1/α.
        m = graph.m
        jac = ca.vertcat(phi_q, sigma_q)
        minv = ca.SX(graph.inv_mass_dm)
        minv_jt = ca.mtimes(minv, jac.T)
        inv_penalty = np.array([1.0 / g.alpha_geometric] * m + [1.0 / g.alpha_servo] * k)
        matrix = ca.SX(_constant(np.diag(inv_penalty))) + ca.mtimes(jac, minv_jt)
        qdd0 = -ca.mtimes(minv, c)
        pre = {"k": matrix, "rhs": ca.vertcat(graph.rho, graph.rho_s) + ca.mtimes(jac, qdd0)}
        if kind == "eq13":
            pre.update({"minv_jt": minv_jt, "qdd0": qdd0, "bias_forces": c, "phi_q": phi_q})
        P = graph.prelude(pre | recovery)
        step = ca.solve(P["k"], P["rhs"], LINSOL_SPD)
        multipliers = step
        for _ in range(iterations - 1):
            step = ca.solve(P["k"], ca.DM(inv_penalty) * step, LINSOL_SPD)
            multipliers = multipliers + step
        if kind == "eq13":
            x = P["qdd0"] - ca.mtimes(P["minv_jt"], multipliers)  # q̈_N
        size = m + k
        export.linear_solvers.append(
            f"'{LINSOL_SPD}' (sparse LDL^T) on the {size}x{size} multiplier matrix D^-1 + J M^-1 J^T, "
            f"{iterations} solve(s)"
        )
        lam, lam_hat = multipliers[:m], multipliers[m:]
    bounds = graph.bounds
    if kind == "projected" and l > k:
        # More inputs than servo-constraints: as controllers.Penalty, always the weighted distribution of the
        # fit ½uᵀGu + gᵀu, G = HᵀPH, g = servo_map λ̂ (codegen.structured.penalty_bounded_terms).
        return bounds.weighted(P["bounded_hessian"], ca.mtimes(P["bounded_servo_map"], lam_hat),
                               PENALTY_SECONDARY_WEIGHT)
    if kind == "projected":
        size = P["normal"].shape[0]
        rhs = -ca.mtimes(P["normal_map"], lam_hat)
        export.linear_solvers.append(f"'{LINSOL_SPD}' on the {size}x{size} normal equations of the projected recovery")
        u0 = ca.solve(P["normal"], rhs, LINSOL_SPD)[:l]
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


def _bounded_projected(graph: _Graph, u0: ca.MX, lam_hat: ca.MX) -> ca.MX:
    """Projected recovery, no more inputs than servo-constraints: u0 if within the limits, else the same fit
    ½uᵀGu + gᵀu (G = HᵀPH, g = servo_map λ̂, codegen.structured.penalty_bounded_terms) bounded, lexicographic."""
    bounds, model = graph.bounds, graph.model
    if not bounds.bounded:
        return u0
    terms = penalty_bounded_terms(model, graph.params)
    bounds.check_nonsingular(terms["hessian"], "the projected recovery's fit H^T P H")
    lam_sx = ca.SX.sym("lam_hat", graph.k)
    outputs = [_symmetric(terms["hessian"]), ca.mtimes(terms["servo_map"], lam_sx)]
    graph.export.distribution.append(
        "u = the projected recovery if within the limits; otherwise (a Switch, evaluated only then) the same fit "
        "1/2 u^T G u + g^T u, G = H^T P H, g = H^T P sigma_q^T lambda_hat (codegen.structured.penalty_bounded_terms) "
        "over lower <= u <= upper: its unbounded minimiser -G^-1 g (SX Cholesky) if within, else the QP"
    )

    def branch(inputs, extra):
        hessian, gradient = bounds.sx_call("projected_terms", [*model.inputs, lam_sx], outputs, [*inputs, *extra])
        return bounds.full_rank(hessian, gradient)

    return bounds.after_unbounded(u0, [lam_hat], branch)


def _bounded_fit(graph: _Graph, u0: ca.MX, gradient: ca.MX) -> ca.MX:
    """eq12/eq13: u0 if within the limits, else their least squares in H u bounded (G = HᵀH): lexicographic,
    or weighted (PENALTY_SECONDARY_WEIGHT) with more inputs than servo-constraints, as controllers.Penalty."""
    bounds, model, l = graph.bounds, graph.model, graph.l
    if not bounds.bounded:
        return u0
    H = graph.sx["input_matrix"]
    hth = ca.mtimes(H.T, H)
    weighted = l > graph.k
    if not weighted:
        bounds.check_nonsingular(hth, "H^T H")
    graph.export.distribution.append(
        f"u = the {graph.gains.recovery} recovery if within the limits; otherwise (a Switch, evaluated only then) its "
        "least squares 1/2 u^T H^T H u + g^T u over lower <= u <= upper: "
        + ("weighted toward the preferred values, (H^T H + mu I) u = -g + mu u_pref, mu = PENALTY_SECONDARY_WEIGHT * "
           "tr(H^T H)/l (Cholesky), if within, else the QP with that Hessian" if weighted else
           "its unbounded minimiser (SX Cholesky) if within, else the QP")
    )

    def branch(inputs, extra):
        (hessian,) = bounds.sx_call("fit_terms", list(model.inputs), [_symmetric(hth)], inputs)
        if weighted:
            return bounds.weighted(hessian, extra[0], PENALTY_SECONDARY_WEIGHT)
        return bounds.full_rank(hessian, extra[0])

    return bounds.after_unbounded(u0, [gradient], branch)


def _box_projection(graph: _Graph, u: ca.MX) -> ca.MX:
    """eq15/kappa: explicit maps; bounded, the input within the limits closest to theirs (G = I): a clip."""
    if not graph.bounds.bounded:
        return u
    graph.export.distribution.append(
        f"u = the {graph.gains.recovery} recovery clipped onto the limits (its bounded form min 1/2 |u - u_rec|^2, "
        "G = I, as acroboter.recovery.InputRecovery.least_squares: the box projection, fmin/fmax)"
    )
    return graph.bounds.clip(u)


def _recovery_prelude(graph: _Graph) -> dict[str, ca.SX]:
    """The state-dependent matrices of the input recovery (everything but λ̂), as SX."""
    T, kind, l = graph.sx, graph.gains.recovery, graph.l
    H, sigma_q = T["input_matrix"], T["sigma_q"]
    if kind == "projected" and graph.l > graph.k:
        terms = penalty_bounded_terms(graph.model, graph.params)
        graph.export.linear_solvers.append(
            f"SX Cholesky of the {graph.l}x{graph.l} matrix G + mu I of the weighted input distribution "
            "(G = H^T P H, codegen.structured.penalty_bounded_terms, P through an SX Cholesky of phi_q M^-1 phi_q^T)"
        )
        graph.export.distribution.append(
            f"{graph.l} inputs for {graph.k} servo-constraints: as controllers.Penalty, always the weighted "
            "distribution of the projected recovery's fit 1/2 u^T G u + g^T u, G = H^T P H, g = H^T P sigma_q^T "
            "lambda_hat: (G + mu I) u = -g + mu u_pref (Cholesky), mu = PENALTY_SECONDARY_WEIGHT * tr(G)/l"
            + (", if within the limits; otherwise the QP with Hessian G + mu I" if graph.bounds.bounded else "")
        )
        return {"bounded_hessian": _symmetric(terms["hessian"]), "bounded_servo_map": terms["servo_map"]}
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


def _projected_prelude(graph: _Graph) -> dict[str, ca.SX]:
    """min over (u, Δλ) of |L⁻¹(H u − φ_qᵀΔλ + σ_qᵀλ̂)|² with M = L Lᵀ, by its normal equations.

    With W = L⁻¹[H, −φ_qᵀ] (independent constraint rows only: redundant rows add no reaction direction)
    the normal equations are (WᵀW) x = −(Wᵀ L⁻¹ σ_qᵀ) λ̂ for x = (u, Δλ); WᵀW is factored by LDLᵀ.
    """
    export, T, lay = graph.export, graph.sx, graph.model.layout
    redundant = set(lay.redundant_rows)
    rows = [i for i in range(graph.m) if i not in redundant]
    inv_chol = ca.SX(_constant(graph.inv_chol))
    weighted = ca.mtimes(inv_chol, ca.horzcat(T["input_matrix"], -T["phi_q"][rows, :].T))
    normal = ca.mtimes(weighted.T, weighted)
    normal_map = ca.mtimes(weighted.T, ca.mtimes(inv_chol, T["sigma_q"].T))
    sv = np.linalg.svd(graph.nominal(weighted), compute_uv=False)
    ratio = sv[-1] / sv[0]
    size = normal.shape[0]
    dropped = f" ({len(redundant)} redundant constraint rows left out)" if redundant else ""
    if ratio < RANK_TOL:
        # Still rank deficient: a tiny Tikhonov term on the diagonal picks the small-norm Δλ; u (fixed
        # by the fit) moves by O(1e-12) relative.
        normal = normal + TIKHONOV * ca.trace(normal) / size * ca.SX.eye(size)
        export.notes.append(
            f"projected recovery: L^-1 [H, -phi_q^T]{dropped} is rank deficient (smallest/largest singular value "
            f"{ratio:.1e} at the nominal configuration), so its normal equations carry a Tikhonov term "
            f"{TIKHONOV:g} * trace/size on the diagonal."
        )
    else:
        export.notes.append(
            f"projected recovery: L^-1 [H, -phi_q^T]{dropped} has full column rank (smallest/largest singular "
            f"value {ratio:.1e} at the nominal configuration): plain normal equations, no Tikhonov term."
        )
    return {"normal": normal, "normal_map": normal_map}


# --- Input limits: acroboter.distribution's bounded distribution, in the graph ----------------------------
#
# Every branch mirrors BoundedInputs (acroboter/distribution.py) step by step:
#   1. non-redundant inputs: the unbounded u (computed as before) if it is within the limits;
#   2. the unbounded minimiser of the distribution's objective (lexicographic or weighted), if within;
#   3. otherwise the strictly convex box QP with the Hessian of step 2.
# The later steps sit in CasADi Switch nodes (Function.if_else): the C evaluates only the branch taken,
# so a step whose limits are not reached costs a few comparisons more than an unbounded one.

QP_PLUGIN = "qrqp"  # CasADi's own active-set QP: generates plain C (its runtime is inlined), no heap
QP_OPTIONS = {
    "print_header": False, "print_iter": False, "print_info": False,
    # A failed QP: the C step returns nonzero (the generated code is the same either way); evaluating
    # StepExport.function from Python raises, as the controllers raise DistributionError.
    "error_on_fail": True,
    # The QP is divided by G's scale tr(G)/l (unit mean eigenvalue), so these are relative to the inputs' size.
    "constr_viol_tol": 1e-12, "dual_inf_tol": 1e-12,
}
# Non-redundant inputs: the distribution's Hessian must be nonsingular at the nominal configuration, its
# smallest/largest eigenvalue this far above acroboter.distribution.RANK_TOLERANCE (which is relative to
# the mean eigenvalue, never above the largest: the check is the stricter one).
SINGULAR_MARGIN = 1e3


def _symmetric(matrix: ca.SX) -> ca.SX:
    return 0.5 * (matrix + matrix.T)


def _scale_and_weight(hessian: ca.SX, weight: float) -> tuple[ca.SX, ca.SX]:
    """(scale, μ) = (tr(G)/l, weight·tr(G)/l), or (1, 1) if tr(G) <= 0 (G = 0), as BoundedInputs; NaN stays NaN."""
    mean = ca.trace(hessian) / hessian.shape[0]
    positive, zero = mean > 0, mean <= 0
    return (ca.if_else(positive, mean, ca.if_else(zero, 1.0, np.nan)),
            ca.if_else(positive, weight * mean, ca.if_else(zero, 1.0, np.nan)))


class _Bounds:
    """The bounded distribution's pieces of one step's graph (limits and preferred values baked in)."""

    def __init__(self, graph: _Graph):
        self.graph = graph
        self.lower, self.upper, self.preferred = graph.export.spec.input_limits()
        self.l = graph.l
        self.bounded = bool(np.isfinite(self.lower).any() or np.isfinite(self.upper).any())
        self._count = 0
        self._qp_solver = None
        self.used_qp = False

    def name(self, what: str) -> str:
        self._count += 1
        return f"{self.graph.export.name}_{what}_{self._count}"

    def sx_call(self, what: str, sx_inputs: list[ca.SX], sx_outputs: list[ca.SX], args: list[ca.MX]) -> list[ca.MX]:
        fn = ca.Function(self.name(what), sx_inputs, [ca.densify(o) for o in sx_outputs], {"cse": True})
        out = fn(*[ca.densify(a) for a in args])
        return list(out) if isinstance(out, tuple) else [out]

    def switch(self, what: str, condition: ca.MX, args: list[ca.MX], when_true, when_false) -> ca.MX:
        """when_true(args) if condition else when_false(args), only the selected branch evaluated."""
        symbols = [ca.MX.sym(f"a{i}", a.sparsity()) for i, a in enumerate(args)]
        name = self.name(what)
        f_true = ca.Function(f"{name}_true", symbols, [ca.densify(when_true(symbols))])
        f_false = ca.Function(f"{name}_false", symbols, [ca.densify(when_false(symbols))])
        return ca.Function.if_else(name, f_true, f_false)(condition, *args)

    # -- elementwise limits --

    def within(self, u):
        """1 if every finite limit holds (NaN fails, as in BoundedInputs.within_limits), else 0."""
        x = ca.SX.sym("u", self.l)
        checks = [x[i] >= self.lower[i] for i in range(self.l) if np.isfinite(self.lower[i])]
        checks += [x[i] <= self.upper[i] for i in range(self.l) if np.isfinite(self.upper[i])]
        cond = checks[0]
        for check in checks[1:]:
            cond = ca.logic_and(cond, check)
        return self.sx_call("within", [x], [cond], [u])[0]

    def clip(self, u):
        x = ca.SX.sym("u", self.l)
        entries = []
        for i in range(self.l):
            e = x[i]
            if np.isfinite(self.lower[i]):
                e = ca.fmax(e, self.lower[i])
            if np.isfinite(self.upper[i]):
                e = ca.fmin(e, self.upper[i])
            entries.append(e)
        return self.sx_call("clip", [x], [ca.vertcat(*entries)], [u])[0]

    # -- the QP --

    def qp(self, hessian: ca.MX, gradient: ca.MX, start: ca.MX) -> ca.MX:
        """min ½xᵀHx + gᵀx, lower <= x <= upper (CasADi's qrqp), clipped onto the limits as Python does.

        Started at `start` (step 2's u2) clipped, with the bounds it violates as the initial active set
        (multiplier guesses ±1): the minimiser is unique, the start only saves iterations."""
        if self._qp_solver is None:
            l = self.l
            self._qp_solver = ca.conic(f"{self.graph.export.name}_qp", QP_PLUGIN,
                                       {"h": ca.Sparsity.dense(l, l), "a": ca.Sparsity(0, l)}, QP_OPTIONS)
        self.used_qp = True
        x = ca.SX.sym("u", self.l)
        signs = []
        for i in range(self.l):
            sign = ca.SX(0)
            if np.isfinite(self.lower[i]):
                sign = ca.if_else(x[i] < self.lower[i], -1.0, sign)
            if np.isfinite(self.upper[i]):
                sign = ca.if_else(x[i] > self.upper[i], 1.0, sign)
            signs.append(sign)
        (lam0,) = self.sx_call("active_guess", [x], [ca.vertcat(*signs)], [start])
        result = self._qp_solver(h=hessian, g=gradient, lbx=ca.DM(self.lower), ubx=ca.DM(self.upper),
                                 x0=self.clip(start), lam_x0=lam0)["x"]
        return self.clip(result)

    def finish(self, u2: ca.MX, qp_args: list[ca.MX], qp_terms) -> ca.MX:
        """Step 2's u2 if within the limits, else the QP; qp_terms(qp_args) -> (H, g), in the QP branch."""
        if not self.bounded:
            return u2
        return self.switch("bounded", self.within(u2), [u2, *qp_args], lambda a: a[0],
                           lambda a: self.qp(*qp_terms(a[1:]), a[0]))

    # -- the three forms of step 2 --

    def full_rank(self, hessian: ca.MX, gradient: ca.MX) -> ca.MX:
        """Lexicographic, G nonsingular (no internal forces): u2 = −G⁻¹g, QP Hessian G (divided by tr(G)/l)."""
        l = self.l
        g, f = ca.SX.sym("G", l, l), ca.SX.sym("g", l)
        u2 = self.sx_call("unbounded", [g, f], [-cholesky_solve(_symmetric(g), f)], [hessian, gradient])[0]

        def terms(a):
            scale, _ = _scale_and_weight(g, 0.0)
            return self.sx_call("qp_terms", [g, f], [_symmetric(g) / scale, f / scale], a)

        return self.finish(u2, [hessian, gradient], terms)

    def weighted(self, hessian: ca.MX, gradient: ca.MX, weight: float) -> ca.MX:
        """(G + μI) u2 = −g + μ u_pref by Cholesky, μ = weight · tr(G)/l (1 if G = 0); the QP has the same
        Hessian."""
        l = self.l
        g, f = ca.SX.sym("G", l, l), ca.SX.sym("g", l)
        scale, mu = _scale_and_weight(g, weight)
        hess = _symmetric(g) + mu * ca.SX.eye(l)
        grad = f - mu * ca.DM(self.preferred)
        u2, hq, gq = self.sx_call("weighted", [g, f], [-cholesky_solve(hess, grad), hess / scale, grad / scale],
                                  [hessian, gradient])
        return self.finish(u2, [hq, gq], lambda a: a)

    def internal(self, servo_map: ca.MX, target: ca.MX) -> ca.MX:
        """Lexicographic with internal forces (MLM, more inputs than servo-constraints), E full row rank.

        Python's eigen split of G = EᵀE keeps the range of Eᵀ and sets the null space Z to u_pref:
        u2 = E⁺e + ZZᵀu_pref = u_pref + Eᵀ(EEᵀ)⁻¹(e − E u_pref), ZZᵀ = I − Eᵀ(EEᵀ)⁻¹E. QP Hessian
        G + μZZᵀ, gradient −Eᵀe − μZZᵀu_pref, μ = SECONDARY_WEIGHT · tr(G)/l (tr(G) = |E|_F²).
        """
        l, k = self.l, self.graph.k
        e_map, e = ca.SX.sym("E", k, l), ca.SX.sym("e", k)
        gram = ca.mtimes(e_map, e_map.T)
        pref = ca.DM(self.preferred)
        u2 = pref + ca.mtimes(e_map.T, cholesky_solve(gram, e - ca.mtimes(e_map, pref)))
        u2 = self.sx_call("internal", [e_map, e], [u2], [servo_map, target])[0]

        def terms(a):
            hess = _symmetric(ca.mtimes(e_map.T, e_map))
            projector = _symmetric(ca.SX.eye(l) - ca.mtimes(e_map.T, cholesky_solve(gram, e_map)))
            scale, mu = _scale_and_weight(hess, SECONDARY_WEIGHT)
            gradient = -ca.mtimes(e_map.T, e) - mu * ca.mtimes(projector, pref)
            return self.sx_call("internal_qp", [e_map, e], [(hess + mu * projector) / scale, gradient / scale], a)

        return self.finish(u2, [servo_map, target], terms)

    def after_unbounded(self, u0: ca.MX, extra: list[ca.MX], branch) -> ca.MX:
        """Python's step 1: the unbounded u0 if within the limits, else branch(step inputs, extra)."""
        if not self.bounded:
            return u0
        inputs = self.graph.inputs
        n_in = len(inputs)
        return self.switch("limits", self.within(u0), [u0, *inputs, *extra], lambda a: a[0],
                           lambda a: branch(a[1 : 1 + n_in], a[1 + n_in :]))

    def check_nonsingular(self, hessian: ca.SX, what: str) -> float:
        """Smallest/largest eigenvalue of the (SX) Hessian at the nominal configuration; refuse if singular."""
        eigenvalues = np.linalg.eigvalsh(_symmetric_numeric(self.graph.nominal(hessian)))
        ratio = eigenvalues[0] / eigenvalues[-1] if eigenvalues[-1] > 0 else 0.0
        if not ratio > SINGULAR_MARGIN * RANK_TOLERANCE:
            raise ExportError(
                f"cannot bound the inputs: {what} is singular at the nominal configuration (smallest/largest "
                f"eigenvalue {ratio:.1e}); the exported distribution expects internal forces only where there are "
                "more inputs than servo-constraints (the Python controller's eigen split handles this case)"
            )
        return ratio


def _symmetric_numeric(matrix: np.ndarray) -> np.ndarray:
    return 0.5 * (matrix + matrix.T)


def _fmt_limit(value: float) -> str:
    return "inf" if value == np.inf else ("-inf" if value == -np.inf else f"{value:g}")


def _limits_block(export: StepExport) -> list[str]:
    """The header's account of the input limits, the distribution and the QP baked into the step."""
    lower, upper, preferred = export.spec.input_limits()
    lines = ["  input limits (baked in as constants from the spec's [[actuators]] limits and preferred; change them by "
             "re-exporting):"]
    for i, act in enumerate(export.spec.actuators):
        lines.append(f"    u[{i}] {act.name} ({act.kind}): [{_fmt_limit(lower[i])}, {_fmt_limit(upper[i])}], "
                     f"preferred {preferred[i]:g}")
    if not export.distribution:
        lines.append("  bounded distribution: none (no finite limit, and no more inputs than servo-constraints): u is "
                     "the unbounded solution")
        return lines
    lines.append("  bounded distribution (as acroboter.distribution.BoundedInputs; the Python controller's u, also "
                 "where a limit binds):")
    lines += [f"    - {text}" for text in export.distribution]
    if export.qp_used:
        lines.append(
            f"    - QP: CasADi '{QP_PLUGIN}' (primal-dual active set on the KKT system, sparse QR), generated inline "
            f"with its runtime: min 1/2 x^T H x + g^T x, lower <= x <= upper, H strictly convex, H and g divided by "
            f"tr(G)/l (unit mean eigenvalue), tolerances {QP_OPTIONS['constr_viol_tol']:g} "
            f"(bounds) and {QP_OPTIONS['dual_inf_tol']:g} (stationarity), started from step 2's minimiser clipped "
            "with the bounds it violates as the initial active set, then clipped onto the limits as Python does; "
            "no heap (work in w/iw, small structs on the stack). Its runtime includes <stdio.h> and <stdarg.h> for "
            "printing that is compiled out (CASADI_SNPRINTF undefined): no stdio function is referenced"
        )
    lines.append(f"    - weights: PENALTY_SECONDARY_WEIGHT = {PENALTY_SECONDARY_WEIGHT:g}, SECONDARY_WEIGHT = "
                 f"{SECONDARY_WEIGHT:g}, relative to G's scale tr(G)/l (its mean eigenvalue: a sum of the diagonal, no "
                 "eigenvalue solver), as acroboter.distribution")
    lines.append("    - the C returns u only: which inputs hold a limit (the controller's limit_state) is not reported")
    return lines


def _comment_block(export: StepExport) -> str:
    spec, lay, g = export.spec, export.layout, export.gains
    n, ns, l = lay.n, lay.n_signals, lay.l
    f = export.function
    sz_arg, sz_res, sz_iw, sz_w = f.sz_arg(), f.sz_res(), f.sz_iw(), f.sz_w()
    method = export.method
    if export.iterations is None:
        what = "mlm: method of Lagrange multipliers (paper eq. 4)"
    elif export.iterations == 1:
        what = "penalty: penalty method (paper eqs. 8-13)"
    else:
        what = f"{method}: iterative penalty method, {export.iterations} iterations (paper eqs. 16-19)"
    spec_file = export.spec_path.name if export.spec_path is not None else "(in memory)"
    lines = [
        f"{export.name}: one complete control step of the ACROBOTER inverse-dynamics controller.",
        "",
        f"Generated by `python -m codegen.export_step` with CasADi {ca.__version__}. Do not edit: re-export.",
        f"  spec:        '{spec.name}' ({spec_file})",
        f"  model hash:  {spec.model_hash()}",
        f"  method:      {what}",
    ]
    lines.append(f"  formulation: {export.system} ({SYSTEM_TEXT[export.system]})")
    if export.iterations is not None:
        lines.append(f"  recovery:    {g.recovery}" + (f" (kappa = {g.kappa!r})" if g.recovery == "kappa" else ""))
    lines += [
        "  gains (baked in as constants; change them by re-exporting, e.g. --kp 6):",
        f"    kp = {g.kp!r} 1/s, kd = {g.kd!r} 1/s   (servo error dynamics s^2 + 2 kd s + kp^2)",
    ]
    if export.iterations is not None:
        lines.append(
            f"    alpha_geometric = {g.alpha_geometric!r}, alpha_servo = {g.alpha_servo!r}, "
            f"omega = {g.omega!r} 1/s, mu = {g.mu!r}"
        )
    lines += ["  linear solvers (CasADi linsol plugins, generated inline; no LAPACK):"]
    lines += [f"    - {s}" for s in export.linear_solvers]
    lines += [f"  note: {note}" for note in export.notes]
    lines += _limits_block(export)
    lines += [
        "",
        "Call (casadi_real = double, casadi_int = long long int); all arrays are dense column vectors:",
        f"  int {export.name}(const casadi_real** arg, casadi_real** res, casadi_int* iw, casadi_real* w, int mem);",
        f"    arg[0] = q   [{n}]  generalized coordinates (per body r, u, v, w; then winch cable lengths)",
        f"    arg[1] = qd  [{n}]  their time derivatives",
        f"    arg[2] = s   [{ns}]   signals: moving anchor positions (3 each), then x_d, y_d, z_d, yaw_d",
        f"    arg[3] = sd  [{ns}]   their first time derivatives",
        f"    arg[4] = sdd [{ns}]   their second time derivatives",
        f"    res[0] = u   [{l}]   inputs",
        f"  Work sizes ({export.name}_work() or the macros in {export.name}.h): sz_arg = {sz_arg}, "
        f"sz_res = {sz_res}, sz_iw = {sz_iw}, sz_w = {sz_w};",
        "  arg and res must have sz_arg and sz_res slots (entries past the inputs/outputs are scratch).",
        "  No heap, no globals written: pass mem = 0; re-entrant if each thread has its own iw and w.",
        "  The linear solvers keep small fixed-size arrays on the stack.",
        f"  Returns 0 on success, nonzero if the bounded QP ({QP_PLUGIN}) did not converge (then u is not valid).",
        "",
        "Layout:",
    ]
    lines += [f"  q[{i}]  {name}" for i, name in enumerate(lay.coordinates)]
    lines += [f"  s[{i}]  {name}" for i, name in enumerate(lay.signals)]
    lines += [f"  u[{i}]  {name}" for i, name in enumerate(lay.inputs)]
    wrapped = []
    for line in lines:  # keep the block readable: wrap long lines, indented under their first word
        indent = " " * (len(line) - len(line.lstrip()) + 4)
        if line.startswith("  int "):  # the C prototype stays on one line
            wrapped.append(line)
            continue
        wrapped += textwrap.wrap(line, 112, subsequent_indent=indent, break_on_hyphens=False) or [""]
    body = "\n".join(f" * {line}".rstrip() for line in wrapped)
    return "/*\n" + body + "\n */\n"


def write_step(export: StepExport, out_dir: Path) -> list[Path]:
    """Write <name>.c and <name>.h into out_dir (deterministic bytes for the same inputs)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    cg = ca.CodeGenerator(f"{export.name}.c", {"with_header": True})
    cg.add(export.function)
    cg.generate(str(out_dir) + "/")
    comment = _comment_block(export)
    written = []
    for suffix in (".c", ".h"):
        path = out_dir / f"{export.name}{suffix}"
        path.write_text(comment + path.read_text())
        written.append(path)
    return written


def export_step(spec_path: Path, method: str, out_dir: Path | None = None, mlm_system: str = "reduced",
                penalty_system: str = "auto", **gain_overrides) -> list[Path]:
    """Load a spec, build the step with the spec's gains (plus overrides) and write its C and header."""
    spec = load_spec(spec_path)
    gains = Gains.from_spec(spec, **gain_overrides)
    export = build_step(spec, method, gains, spec_path=Path(spec_path), mlm_system=mlm_system,
                        penalty_system=penalty_system)
    out_dir = out_dir if out_dir is not None else Path("embedded") / f"{spec.name}_{method}"
    return write_step(export, out_dir)
