"""The Python controllers' fast path (issue 23 item 2): one method's whole control step as ONE compiled function.

    (u, qdd, within, rcond) = <name>(q, qd, s, sd, sdd, p, limits)

is the exported step of acroboter.codegen.export_step (the same MX graph: model terms and their assembly as one
SX function with shared subexpressions, CasADi's generated sparse LDLᵀ / QR, the input recovery and, with more
inputs than servo-constraints, the distribution's closed-form step 2) with two differences:

- the gains and the integral z are a run-time input, p = [k_P, k_D, α̃, α̂, Ω, μ, k_I, z]: the parameter vector
  the generated model functions read (acroboter.model.controller_parameters), so the controller passes the model's
  own p buffer and one library serves every gain set (a study's sweep, integral action on and off); κ (the kappa
  recovery only) is baked in and part of the library's key;
- the input limits and preferred values are a run-time input, limits = [lower; upper; preferred] (±inf for none),
  and there is no QP in the C: `within` is 1 when u lies within the limits (step 1 or 2 of
  acroboter.control.distribution), 0 otherwise or for a NaN, and then the controller computes that step on its
  reference path (control/fast_path.py), which distributes it exactly as it always did (DAQP, limit_state, the
  saturation judgement).

q̈ is the commanded acceleration (controller.qdd: the estimator's prediction); MLM's rcond is the exact reciprocal
1-norm condition number of its Schur system, from the inverse solved with the same QR factorization as y (the
reference estimates it with LAPACK's gecon, a lower bound on the condition number); the penalty methods report 1.

The C is generated into the cache on first use (acroboter.runtime.fast_library), keyed by what determines it (the
spec's model hash, the code generator's files, CasADi's version, method, recovery, formulation, κ), and compiled
like the model library (-O2 -fPIC, no fast-math).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path

import casadi as ca

from ..model.c_templates import render, templates_digest
from ..model.fingerprint import codegen_hash
from ..model.settings import Gains
from ..model.spec import Spec
from .export_step import FAST_OUTPUTS, build_step

__all__ = ["FAST_OUTPUTS", "FastStep", "build_fast_step", "fast_key", "fast_name", "write_fast_step"]

# Version of the fast step's interface (inputs, outputs): part of the key.
FAST_INTERFACE = 1
# The code generator's files that shape the step's C (beside codegen_hash's).
STEP_SOURCES = ("export_step.py", "step_graph.py", "step_methods.py", "step_qp.py", "fast_step.py", "solver_terms.py")


@dataclass
class FastStep:
    name: str  # C symbol, file stem and library name
    function: ca.Function
    has_qdd: bool  # False: MLM with more inputs than servo-constraints (its q̈ needs the reference's least squares)
    system: str


def fast_name(spec: Spec, method: str, recovery: str, key: str) -> str:
    return f"{spec.name}_fast_{method.replace('-', '_')}_{recovery}_{key[:12]}"


def fast_key(spec: Spec, method: str, gains: Gains, penalty_system: str = "auto") -> str:
    """SHA-256 of everything the fast step's C depends on (the gains and limits are run-time inputs; κ is not)."""
    h = hashlib.sha256()
    here = Path(__file__).resolve().parent
    kappa = repr(gains.kappa) if gains.recovery == "kappa" else "-"
    h.update(f"fast {FAST_INTERFACE}\n{spec.model_hash()}\n{codegen_hash()}\n{method}\n{gains.recovery}\n{kappa}\n"
             f"{penalty_system}\n".encode())
    for name in STEP_SOURCES:
        h.update(name.encode() + b"\n" + (here / name).read_bytes())
    h.update(templates_digest())
    return h.hexdigest()


def build_fast_step(spec: Spec, method: str, gains: Gains, name: str, penalty_system: str = "auto") -> FastStep:
    """The fast path's function of `method` (ExportError where the export cannot build it: the caller keeps the
    reference path and says why)."""
    export = build_step(spec, method, gains, name=name, penalty_system=penalty_system, parametric=True)
    # MLM with internal forces: the graph has no q̈ (the reference takes λ from a least squares on demand).
    has_qdd = not (export.iterations is None and export.system == "servo_least_squares")
    return FastStep(name, export.function, has_qdd, export.system)


def write_fast_step(fast: FastStep, folder: Path) -> Path:
    """<name>.c into `folder` (CasADi's CodeGenerator, deterministic bytes for the same inputs)."""
    folder.mkdir(parents=True, exist_ok=True)
    cg = ca.CodeGenerator(f"{fast.name}.c")
    cg.add(fast.function)
    cg.generate(str(folder) + "/")
    path = folder / f"{fast.name}.c"
    (folder / f"{fast.name}_path.c").write_text(path_source(fast.name))
    comment = (f"/* {fast.name}: the Python controllers' fast path (acroboter.codegen.fast_step), formulation "
               f"{fast.system}.\n * Generated into the cache with CasADi {ca.__version__}: do not edit. */\n")
    path.write_text(comment + path.read_text())
    return path


def path_source(name: str) -> str:
    """<name>_flat(table, t, out): acroboter.control.path.DesiredPath.flat in C, statement for statement (the same
    IEEE operations in the same order: the same bits), from the path's numbers in `table` (control/fast_path.py
    path_table); <name>_run(table, t, signals, arg, res, iw, w): the signals at t into `signals`, then the step."""
    return render("fast_step_path.c", NAME=name, PATH=render("path.c", NAME=name, API=""))
