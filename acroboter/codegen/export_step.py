"""Export one controller's complete control step as self-contained C (issue "Embedded control step").

    acroboter export-step [--spec model_spec/acroboter.toml] [--method penalty|mlm|iterative-N]
                                  [--recovery projected|eq12|eq13|eq15|kappa] [--kp ...] [--out DIR]
    (--recovery kinetic, the whole acceleration's fit, runs in the Python controller only: refused, exit 2)

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

The mass matrix of natural coordinates is constant, so its inverse (in the constrained projection P of the
'projected' recovery and of MLM's bounded terms) is a numeric constant in the C as well.

Input limits (the spec's actuator `limits` and `preferred`, baked in as constants like the gains) are
honoured as the Python controllers do (acroboter.control.distribution.BoundedInputs), branch for branch, so the
C gives their u also where a limit binds:
- no more inputs than servo-constraints: the unbounded u above if it is within the limits (bit for bit
  the unbounded export); otherwise, in a CasADi Switch that the C evaluates only then, the recovery's
  least squares ½uᵀGu + gᵀu (projected: G = EᵀE, g = EᵀFλ̂ with E = σ_q P H, F = σ_q P σ_qᵀ,
  codegen.solver_terms.penalty_bounded_terms; MLM: ½|E u − e|², mlm_bounded_terms; eq12/eq13: G = HᵀH), its
  unbounded minimiser if within, else a box QP; eq15/kappa (explicit maps, G = I): the clip onto the limits.
- more inputs than servo-constraints (internal forces, e.g. the four-cable crane): always distributed.
  MLM: lexicographic, u = u_pref + Eᵀ(EEᵀ)⁻¹(e − E u_pref) (Python's eigen split of EᵀE in closed form)
  and, bounded, the QP with Hessian EᵀE + μZZᵀ, ZZᵀ = I − Eᵀ(EEᵀ)⁻¹E, μ = SECONDARY_WEIGHT·tr(EᵀE)/l.
  Penalty methods (projected recovery): the same, with e = e_F = E u_F the servo accelerations of the
  fit's input in the task directions, u_F = −Eᵀ(E G Eᵀ)⁻¹E g by SX Cholesky (BoundedInputs.solve_task).
  eq12/eq13 with redundant inputs, where a limit is in the way: weighted, (HᵀH + μI)u = −g + μ u_pref,
  μ = PENALTY_SECONDARY_WEIGHT·tr(HᵀH)/l.
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
from pathlib import Path

import casadi as ca

from ..model.settings import Gains
from ..model.spec import MAX_ITERATIONS, RECOVERIES, Spec, load_spec
from .emit_c import INPUT_NAMES
from .step_c import write_step
from .step_graph import ExportError, StepExport, StepGraph
from .step_methods import mlm_step, penalty_step
from .symbolic import build_symbolic_model

__all__ = ["ExportError", "StepExport", "build_step", "export_step", "parse_method", "step_name", "write_step"]

MLM_SYSTEMS = ("reduced", "full")
FAST_OUTPUTS = ("u", "qdd", "within", "rcond")  # the parametric step's (acroboter.codegen.fast_step)
PENALTY_SYSTEMS = ("auto", "multipliers", "matrix")


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


def build_step(spec: Spec, method: str, gains: Gains, spec_path: Path | None = None, name: str | None = None,
               mlm_system: str = "reduced", penalty_system: str = "auto", stateful: bool = False,
               parametric: bool = False) -> StepExport:
    """Build the MX function u = step(q, qd, s, sd, sdd) of one method with the given (baked-in) gains.

    stateful (the core of acroboter.codegen.controller_c): (u, q̈) = step(q, qd, s, sd, sdd, z), the
    integral z = ∫σ dt an input (k_I z in ρ_s) and the commanded acceleration q̈ an output (the estimator's
    prediction); integral action is then allowed.

    parametric (the Python controllers' fast path, acroboter.codegen.fast_step): (u, q̈, within, rcond) =
    step(q, qd, s, sd, sdd, p, limits) with the gains and z in p, no QP (see fast_step)."""
    iterations = parse_method(method)
    refuse_unexportable(gains, iterations)
    if penalty_system not in PENALTY_SYSTEMS:
        raise ExportError(f"unknown penalty system '{penalty_system}': choose one of {', '.join(PENALTY_SYSTEMS)}")
    if mlm_system not in MLM_SYSTEMS:
        raise ExportError(f"unknown MLM system '{mlm_system}': choose one of {', '.join(MLM_SYSTEMS)}")
    if gains.ki != 0 and not (stateful or parametric):
        raise ExportError(
            f"integral action (ki = {gains.ki:g}) cannot be exported: the exported step is stateless "
            "(u from q, qd, s, sd, sdd) and the integral z = ∫σ dt with its anti-windup is state the Python "
            "controller holds (docs/integral_action.md): export from a spec without ki (or ki = 0) in its "
            "[controller], or export the stateful controller (export-step --stateful), which holds z"
        )
    model = build_symbolic_model(spec)
    name = name or step_name(spec, method, gains.recovery)
    redundant = model.layout.redundant_rows
    if penalty_system == "auto":
        # Redundant rows make D⁻¹ + J M⁻¹Jᵀ nearly singular (eigenvalues ~ 1/α) and, off the constraint
        # manifold, their multipliers large: λ̂ then carries their round-off (~1e-7 relative in trials).
        penalty_system = "matrix" if redundant else "multipliers"
    system = mlm_system if iterations is None else penalty_system
    export = StepExport(name, None, spec, spec_path, method, iterations, gains, model.layout, system,  # type: ignore[arg-type]
                        integral=stateful, parametric=parametric)
    graph = StepGraph(export, model)
    if stateful:
        stateful_problem(graph, iterations)
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
    graph.bounds.report = stateful and graph.bounds.bounded and gains.ki != 0  # the anti-windup's judgement
    if iterations is None:
        u = mlm_step(graph, mlm_system)
    else:
        u = penalty_step(graph, iterations, penalty_system)
    if parametric:
        export.function = parametric_function(graph, u)
    elif stateful:
        saturated = ca.MX(0.0)
        if graph.bounds.report:  # [u; QP ran; step 2's minimiser] -> u and the saturation judgement
            l = graph.l
            if u.shape[0] != 2 * l + 1:
                raise ExportError(f"internal: the bounded step of {method} did not report its distribution")
            u, saturated = u[:l], graph.bounds.saturation(u[l], u[l + 1 :])
        export.function = ca.Function(name, graph.inputs, [ca.densify(u), ca.densify(graph.qdd), saturated],
                                      graph.input_names, ["u", "qdd", "saturated"])
    else:
        export.function = ca.Function(name, graph.inputs, [ca.densify(u)], list(INPUT_NAMES), ["u"])
    export.qp_used = graph.bounds.used_qp
    return export



def refuse_unexportable(gains: Gains, iterations: int | None) -> None:
    """ExportError, naming the way out, for the settings the exported step has no form of."""
    if gains.recovery not in RECOVERIES:
        raise ExportError(f"unknown input recovery '{gains.recovery}': choose one of {', '.join(RECOVERIES)}")
    if gains.recovery == "kinetic" and iterations is not None:
        raise ExportError(
            "the 'kinetic' recovery (the whole acceleration's fit, kept for cranes whose zero dynamics are unstable) "
            "runs in the Python controller only; export 'projected' (the default) or another recovery, or run the "
            "Python controller (acroboter run --recovery kinetic)")
    if gains.saturation != "qp":
        raise ExportError(
            f"the spec asks saturation = '{gains.saturation}', and the exported step meets limits with the bounded "
            "least squares only: its hysteresis is state between steps that the step does not carry, and its active "
            "set a loop of SVDs the generated C has none of (docs/saturation.md). Set [controller] saturation = "
            "\"qp\" for the export, or run the Python controller (acroboter run --saturation underactuation)")

def parametric_function(graph: StepGraph, u: ca.MX) -> ca.Function:
    """The step's graph as the fast path's function (called by export_step.build_step with parametric=True)."""
    export = graph.export
    l, n = graph.l, graph.n
    if u.shape[0] != l:
        raise ExportError(f"internal: the parametric step of {export.method} returned {u.shape[0]} numbers for {l} "
                          "inputs")
    qdd = graph.qdd if graph.qdd is not None else ca.MX.zeros(n)
    within = graph.bounds.runtime_within(u, graph.limits_input)
    rcond = graph.outputs.get("rcond", ca.MX(1.0))
    return ca.Function(export.name, [*graph.inputs, graph.limits_input],
                       [ca.densify(u), ca.densify(qdd), within, rcond],
                       [*graph.input_names, "limits"], list(FAST_OUTPUTS))


def stateful_problem(graph: StepGraph, iterations: int | None) -> None:
    """Refuse what the stateful controller cannot export yet (ExportError naming the cause and the way out)."""
    bounded, redundant_inputs = graph.bounds.bounded, graph.l > graph.k
    if iterations is None and (redundant_inputs or (bounded and graph.export.system == "full")):
        raise ExportError(
            "the stateful controller needs the commanded acceleration q̈ for its estimator; with MLM it is exported "
            "for the reduced system (--mlm-system reduced) and no more inputs than servo-constraints only (elsewhere "
            "the Python controller's multipliers come from a least squares this export does not generate): export "
            "the penalty or iterative penalty method"
        )


def export_step(spec_path: Path, method: str, out_dir: Path | None = None, mlm_system: str = "reduced",
                penalty_system: str = "auto", **gain_overrides) -> list[Path]:
    """Load a spec, build the step with the spec's gains (plus overrides) and write its C and header."""
    spec = load_spec(spec_path)
    gains = Gains.from_spec(spec, **gain_overrides)
    export = build_step(spec, method, gains, spec_path=Path(spec_path), mlm_system=mlm_system,
                        penalty_system=penalty_system)
    out_dir = out_dir if out_dir is not None else Path("embedded") / f"{spec.name}_{method}"
    return write_step(export, out_dir)

