"""The estimator of acroboter.sim.sensing as C: one text (acroboter/c/estimator.c and estimator_state.h)
for the stateful exported controller (acroboter.codegen.controller_c, its functions static) and the fast path's
compiled estimator (here, its functions extern, bound by acroboter.runtime.fast_library):

    void <name>_estimator_start(<name>_estimator* e, const double* q0)
    void <name>_estimator_reinit(<name>_estimator* e)
    void <name>_estimator_applied(<name>_estimator* e, const double* qdd)
    int  <name>_estimator_update(<name>_estimator* e, const double* y, const double* sig_m, const double* sig_t)

are Estimator.reset (its estimator part), reinit, applied and update, statement for statement: the sample's checks
(finite, unit axes, within its gate of the prediction; re-acquisition from two agreeing samples), the prediction of
the unmeasured coordinates, the projection onto φ(q, t) = 0 (the unmeasured coordinates' least squares, then
minimal-norm Gauss–Newton steps) and its convergence check, the α-β filter, the rate correction onto φ_q q̇ = −φ_t
and the delay carried forward. The algebra is CasADi SX functions (max-free φ rows, SX Cholesky): fixed iteration
counts, no heap.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass
from pathlib import Path

import casadi as ca
import numpy as np

from ..model.c_templates import render, templates_digest
from ..model.fingerprint import codegen_hash
from ..model.schema import Sensing
from ..model.sensing_layout import (
    PROJECTION_ACCEPT,
    PROJECTION_TOLERANCE,
    SampleChecks,
    measured_indices,
    sample_checks,
)
from ..model.spec import Spec
from .solver_terms import cholesky_solve, independent_rows
from .symbolic import build_symbolic_model

__all__ = ["EstimatorExport", "OFFSET_FIELDS", "build_estimator", "estimator_key", "estimator_text",
           "write_estimator"]

# The struct fields the fast path reads through <name>_offsets (acroboter.runtime.fast_library), in this order.
OFFSET_FIELDS = ("qm", "qdm", "xf", "vf", "q", "qd", "acc", "pred", "q_good", "violation", "jump", "k", "started",
                 "coasted", "prev_valid", "status", "reason", "rejected", "distrust")


@dataclass
class EstimatorExport:
    name: str
    n: int
    n_signals: int
    measured: np.ndarray
    unmeasured: np.ndarray
    rows: list[int]
    period: float
    alpha: float
    beta: float
    delay: int
    iterations: int
    predict: bool
    checks: SampleChecks
    functions: list[ca.Function]
    work: tuple[int, int, int, int]


def estimator_key(spec: Spec, sensing: Sensing) -> str:
    h = hashlib.sha256(f"estimator 2\n{spec.model_hash()}\n{codegen_hash()}\n{sensing.model_dump_json()}\n"
                       f"{spec.controller.rate_hz!r}\n".encode())
    h.update((Path(__file__).resolve()).read_bytes())
    h.update(templates_digest())
    return h.hexdigest()


def build_estimator(spec: Spec, sensing: Sensing, name: str, model=None) -> EstimatorExport:
    """The estimator's SX functions (named <name>_phi_rows, _projection_step, _rate_correction, _unmeasured_step)
    and numbers for `sensing` on `spec` (`model`: its symbolic model, if built already)."""
    model = model if model is not None else build_symbolic_model(spec)
    lay = model.layout
    index, _, _ = measured_indices(spec, lay, sensing)
    unmeasured = np.setdiff1d(np.arange(lay.n), index)
    rows = independent_rows(model)
    period = 1.0 / spec.controller.rate_hz
    pole = math.exp(-period / sensing.velocity_filter_s)
    q, qd, s, sd, _ = model.inputs
    phi = ca.SX(model.phi)[rows, 0]
    a = ca.SX(model.phi_q)[rows, :]
    gram = ca.mtimes(a, a.T)

    def min_norm(b):  # aᵀ(a aᵀ)⁻¹ b, as Estimator._min_norm
        return ca.densify(ca.mtimes(a.T, cholesky_solve(gram, b)))

    functions = [
        ca.Function(f"{name}_phi_rows", [q, s], [ca.densify(phi)], ["q", "s"], ["phi"], {"cse": True}),
        ca.Function(f"{name}_projection_step", [q, s], [min_norm(phi)], ["q", "s"], ["dq"], {"cse": True}),
        ca.Function(f"{name}_rate_correction", [q, qd, s, sd], [min_norm(ca.SX(model.phi_dot)[rows, 0])],
                    ["q", "qd", "s", "sd"], ["dqd"], {"cse": True}),
    ]
    if unmeasured.size:
        au = a[:, unmeasured.tolist()]
        step_u = cholesky_solve(ca.mtimes(au.T, au), ca.mtimes(au.T, phi))  # as Estimator._least_squares
        functions.append(ca.Function(f"{name}_unmeasured_step", [q, s], [ca.densify(step_u)], ["q", "s"],
                                     ["dq_unmeasured"], {"cse": True}))
    work = tuple(max(getattr(f, attr)() for f in functions) for attr in ("sz_arg", "sz_res", "sz_iw", "sz_w"))
    return EstimatorExport(name, lay.n, lay.n_signals, index, unmeasured, rows, period, 1.0 - pole * pole,
                           (1.0 - pole) ** 2, sensing.delay_periods, sensing.projection_iterations,
                           bool(sensing.predict_delay), sample_checks(spec, lay, sensing), functions,
                           work)  # type: ignore[arg-type]


def _array(kind: str, name: str, values, size: int) -> str:
    """A static const array (none when it would be empty: the template reads it only where its count is > 0)."""
    body = ", ".join(values)
    return f"static const {kind} {name}[{size}] = {{{body}}};\n" if size and body else ""


def estimator_text(e: EstimatorExport, api: str = "static") -> tuple[str, str]:
    """(the struct's typedef, the numbers and the functions) as C; `api`: the entry points' storage class."""
    c = e.checks
    struct = render("estimator_state.h", NAME=e.name, N=e.n, DELAY1=e.delay + 1, NY1=max(e.measured.size, 1),
                    NU1=max(e.unmeasured.size, 1), M1=max(len(e.rows), 1), SZ_ARG=max(e.work[0], 1),
                    SZ_RES=max(e.work[1], 1), SZ_IW=max(e.work[2], 1), SZ_W=max(e.work[3], 1))
    numbers = {"API": api, "N": e.n, "NS": e.n_signals, "NY": e.measured.size, "NU": e.unmeasured.size,
               "M": len(e.rows), "NA": len(c.axes), "ITERATIONS": e.iterations, "DELAY": e.delay,
               "PREDICT": int(e.predict), "T": repr(e.period), "ALPHA": repr(e.alpha), "BETA": repr(e.beta),
               "TOLERANCE": repr(PROJECTION_TOLERANCE), "ACCEPT": repr(PROJECTION_ACCEPT), "MAX_COAST": c.max_coast}
    lines = [f"#define EST_{key} {value}" for key, value in numbers.items()]
    arrays = (_array("casadi_int", "est_measured", map(str, e.measured), e.measured.size)
              + _array("double", "est_gate", map(repr, map(float, c.gate)), c.gate.size)
              + _array("casadi_int", "est_unmeasured", map(str, e.unmeasured), e.unmeasured.size)
              + _array("casadi_int", f"est_axes[{len(c.axes)}]", (f"{{{a}, {b}, {d}}}" for a, b, d in c.axes), 3)
              + _array("double", "est_axis_tol", map(repr, map(float, c.axis_tolerance)), len(c.axes)))
    code = "\n".join(lines) + "\n" + arrays + "\n" + render("estimator.c", NAME=e.name)
    return struct, code


def _source(e: EstimatorExport) -> str:
    struct, code = estimator_text(e, api="")
    offsets = "\n".join(f"  out[{i + 1}] = (long long)offsetof({e.name}_estimator, {field});"
                        for i, field in enumerate(OFFSET_FIELDS))
    return render("fast_estimator.c", NAME=e.name, STRUCT=struct, CODE=code, OFFSETS=offsets)


def write_estimator(e: EstimatorExport, folder: Path) -> None:
    """<name>_functions.c/.h (CasADi) and <name>.c (the estimator) into `folder`: deterministic bytes."""
    folder.mkdir(parents=True, exist_ok=True)
    cg = ca.CodeGenerator(f"{e.name}_functions.c", {"with_header": True})
    for function in e.functions:
        cg.add(function)
    cg.generate(str(folder) + "/")
    (folder / f"{e.name}.c").write_text(_source(e))
