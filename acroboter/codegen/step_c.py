"""The C of an exported step (acroboter.codegen.export_step): CasADi's CodeGenerator writes <name>.c and
<name>.h, and a comment block on top of both says what was exported: spec, method, formulation, gains,
linear solvers, input limits and distribution, the call and its work sizes, the layout of q, s and u.
"""

from __future__ import annotations

import textwrap
from pathlib import Path

import casadi as ca
import numpy as np

from ..model.settings import PENALTY_SECONDARY_WEIGHT, SECONDARY_WEIGHT
from .step_graph import StepExport
from .step_qp import QP_OPTIONS, QP_PLUGIN

SYSTEM_TEXT = {
    "reduced": "the (n+m+l) system reduced by the constant M to its (m+l) Schur complement in [lambda; u]",
    "full": "the (n+m+l) system as written",
    "multipliers": "each iteration solves (D^-1 + J M^-1 J^T) dLambda = J qdd_i + rho_J for the increment of "
    "[lambda; lambda_hat], J = [phi_q; sigma_q], D = diag(alpha_geometric, alpha_servo), rho_J = [rho; rho_s]; "
    "by Woodbury's identity the same iterates as A qdd_{i+1} = M qdd_i + f with A = M + J^T D J",
    "matrix": "each iteration solves A qdd_{i+1} = M qdd_i + f, A = M + alpha_geometric phi_q^T phi_q "
    "+ alpha_servo sigma_q^T sigma_q",
    "servo_least_squares": "more inputs than servo-constraints: no Schur system; the servo-constraints' "
    "accelerations E u = e on the constraint manifold (codegen.solver_terms.mlm_bounded_terms), as controllers.MLM",
}


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
    lines.append("  bounded distribution (as acroboter.control.distribution.BoundedInputs; the Python controller's u, "
                 "also where a limit binds):")
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
    lines.append("    - weights, relative to G's scale tr(G)/l (its mean eigenvalue: a sum of the diagonal, no "
                 "eigenvalue solver), as acroboter.control.distribution: mu = SECONDARY_WEIGHT * tr(G)/l "
                 f"(SECONDARY_WEIGHT = {SECONDARY_WEIGHT:g}) on the internal forces in a lexicographic QP; "
                 f"mu = PENALTY_SECONDARY_WEIGHT * tr(G)/l (PENALTY_SECONDARY_WEIGHT = {PENALTY_SECONDARY_WEIGHT:g}) "
                 "in the weighted form (eq12/eq13 with more inputs than servo-constraints only)")
    lines.append("    - the C returns u only: which inputs hold a limit (the controller's limit_state) is not reported")
    return lines


def _comment_block(export: StepExport, header: str | None = None) -> str:
    """The comment on top of the step's C; `header`: the file that declares it (default <name>.h)."""
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
        f"Generated by `acroboter export-step` with CasADi {ca.__version__}. Do not edit: re-export.",
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
    if export.integral:
        lines.append(f"    ki = {g.ki!r} 1/s^3   (integral action: s^3 + 2 kd s^2 + kp^2 s + ki, rho_s + ki z)")
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
        *([f"    arg[5] = z   [{lay.k}]   integral of the servo-constraints, z = int sigma dt (k_I z enters rho_s; "
            "held by the stateful controller)"] if export.integral else []),
        f"    res[0] = u   [{l}]   inputs",
        *([f"    res[1] = qdd [{n}]  the commanded acceleration (the estimator's prediction)",
           "    res[2] = saturated [1]  the anti-windup's saturation judgement (1 saturated, 0 not)"]
          if export.integral else []),
        f"  Work sizes ({export.name}_work(), declared in {header or export.name + '.h'}): sz_arg = {sz_arg}, "
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

