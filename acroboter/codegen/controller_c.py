"""The stateful exported controller (issue 23 item 1): estimator, integral action and control step as C.

    acroboter export-step --stateful [--spec ...] [--method ...] [--ki ...] [--out DIR]

writes four files for the robot's real-time computer:

- <name>_functions.c/.h: CasADi's CodeGenerator output (plain C, libm only, no heap) of the algebra:
  the control step of acroboter.codegen.export_step with the integral z = ∫σ dt as a sixth input (k_I z in
  ρ_s) and the commanded acceleration q̈ as a second output (`<name>_core`), and the estimator's pieces
  of acroboter.sim.sensing.Estimator, each one SX function with shared subexpressions: max |φ| over the
  independent rows, the minimal-norm Gauss–Newton step φ_qᵀ(φ_q φ_qᵀ)⁻¹φ, the unmeasured coordinates'
  least-squares step (a_Uᵀa_U)⁻¹a_Uᵀφ, the rate correction φ_qᵀ(φ_q φ_qᵀ)⁻¹φ̇ and σ (SX Cholesky, as
  codegen.structured.cholesky_solve);
- <name>.c/.h: a small hand-written wrapper (acroboter.codegen.controller_text) with a state struct and
  three calls, init(state, q0), step(state, y, t, signals, u) and reset(state): the estimator's loop
  (fixed iteration counts), the α-β filter, the delay carried over with the commanded accelerations,
  the integral by the trapezoid rule with its anti-windup, then the core step. All buffers (the work
  arrays of the generated functions included, sized here) are in the state struct: no heap, no globals.

Without a [sensing] section (or with an ideal one, as acroboter.sim.sensing.make_estimator) the
measurements are the state itself, y = [q; q̇], and no estimator runs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import casadi as ca
import numpy as np

from ..model.layout import nominal_coordinates
from ..model.schema import Sensing
from ..model.sensing_layout import is_ideal, measured_groups, measured_indices
from ..model.settings import Gains
from ..model.spec import Spec, load_spec
from .export_step import ExportError, build_step, step_name
from .generate import INPUT_NAMES
from .step_graph import StepExport
from .structured import cholesky_solve, independent_rows
from .symbolic import build_symbolic_model

RANK_TOLERANCE = 1e-9  # as acroboter.sim.sensing.RANK_TOLERANCE

__all__ = ["ControllerExport", "build_controller", "controller_files", "controller_name", "export_controller"]


@dataclass
class ControllerExport:
    """Everything the wrapper's text needs: the core step, the estimator's functions and numbers."""

    name: str  # C prefix of the API and stem of <name>.c/.h
    step: StepExport  # the core: (u, qdd) = core(q, qd, s, sd, sdd, z)
    sensing: Sensing | None  # None: the measurements are the state [q; qd]
    coordinates: list[str]  # the layout's coordinate names
    measured: np.ndarray  # coordinate index per measurement (estimator only)
    unmeasured: np.ndarray
    groups: list[tuple[str, str, float, float]]  # per measurement: group, unit, noise, quantisation step
    rows: list[int]  # independent constraint rows (the projection's)
    period: float
    alpha: float = 0.0
    beta: float = 0.0
    functions: list[ca.Function] = field(default_factory=list)
    work: tuple[int, int, int, int] = (0, 0, 0, 0)  # max sz_arg, sz_res, sz_iw, sz_w over the functions

    @property
    def estimator(self) -> bool:
        return self.sensing is not None

    @property
    def delay(self) -> int:
        return self.sensing.delay_periods if self.sensing is not None else 0

    @property
    def iterations(self) -> int:
        return self.sensing.projection_iterations if self.sensing is not None else 0


def controller_name(spec: Spec, method: str, recovery: str) -> str:
    """C prefix of the stateful controller: the step's name with _controller for _step."""
    return step_name(spec, method, recovery).removesuffix("_step") + "_controller"


def _unit(name: str) -> str:
    vector = name.rpartition(".")[2][:1]
    return "1 (unitless)" if vector in "uvw" else "m"


def build_controller(spec: Spec, method: str, gains: Gains, sensing: Sensing | None = None,
                     spec_path: Path | None = None, mlm_system: str = "reduced",
                     penalty_system: str = "auto") -> ControllerExport:
    """Build the core step (with z and q̈) and the estimator's SX functions for `sensing` (resolved,
    e.g. acroboter.sim.sensing.resolve; None: the state is measured)."""
    name = controller_name(spec, method, gains.recovery)
    step = build_step(spec, method, gains, spec_path=spec_path, name=f"{name}_core", mlm_system=mlm_system,
                      penalty_system=penalty_system, stateful=True)
    model = build_symbolic_model(spec)
    lay = model.layout
    if sensing is not None and is_ideal(spec, lay, sensing):
        sensing = None  # every coordinate, exactly, no delay: the plant's state, as make_estimator
    rows = independent_rows(model)
    period = 1.0 / spec.controller.rate_hz
    export = ControllerExport(name, step, sensing, list(lay.coordinates), np.zeros(0, dtype=np.intp),
                              np.zeros(0, dtype=np.intp), [], rows, period)
    functions = [step.function]
    q, qd, s, sd, sdd = model.inputs
    sigma = ca.densify(ca.SX(model.sigma))
    functions.append(ca.Function(f"{name}_sigma", list(model.inputs), [sigma], list(INPUT_NAMES), ["sigma"],
                                 {"cse": True}))
    if sensing is not None:
        index, noise, steps = measured_indices(spec, lay, sensing)
        if len(set(index.tolist())) != index.size:
            raise ExportError("a coordinate is measured twice: each coordinate belongs to at most one sensing group")
        export.measured, export.unmeasured = index, np.setdiff1d(np.arange(lay.n), index)
        names = measured_groups(spec, sensing)
        export.groups = [(names[j], _unit(lay.coordinates[i]), float(noise[j]), float(steps[j]))
                         for j, i in enumerate(index)]
        pole = math.exp(-period / sensing.velocity_filter_s)
        export.alpha, export.beta = 1.0 - pole * pole, (1.0 - pole) ** 2  # as Estimator: both poles at `pole`
        phi = ca.SX(model.phi)[rows, 0]
        a = ca.SX(model.phi_q)[rows, :]
        gram = ca.mtimes(a, a.T)

        def min_norm(b):  # aᵀ(a aᵀ)⁻¹ b, as Estimator._min_norm
            return ca.densify(ca.mtimes(a.T, cholesky_solve(gram, b)))

        functions += [
            ca.Function(f"{name}_phi_rows", [q, s], [ca.densify(phi)], ["q", "s"], ["phi"], {"cse": True}),
            ca.Function(f"{name}_projection_step", [q, s], [min_norm(phi)], ["q", "s"], ["dq"], {"cse": True}),
            ca.Function(f"{name}_rate_correction", [q, qd, s, sd], [min_norm(ca.SX(model.phi_dot)[rows, 0])],
                        ["q", "qd", "s", "sd"], ["dqd"], {"cse": True}),
        ]
        if export.unmeasured.size:
            au = a[:, export.unmeasured.tolist()]
            _check_measurable(model, au, [lay.coordinates[i] for i in export.unmeasured])
            step_u = cholesky_solve(ca.mtimes(au.T, au), ca.mtimes(au.T, phi))  # as Estimator._least_squares
            functions.append(ca.Function(f"{name}_unmeasured_step", [q, s], [ca.densify(step_u)], ["q", "s"],
                                         ["dq_unmeasured"], {"cse": True}))
    export.functions = functions
    export.work = tuple(max(getattr(f, attr)() for f in functions)  # type: ignore[assignment]
                        for attr in ("sz_arg", "sz_res", "sz_iw", "sz_w"))
    return export


def _check_measurable(model, au: ca.SX, names: list[str]) -> None:
    """As acroboter.sim.sensing.check_measurable: φ_q's columns of the unmeasured coordinates must have full column
    rank at the spec's nominal configuration (moving anchors at their spec positions), else ExportError."""
    lay, spec = model.layout, model.spec
    signals = np.zeros(lay.n_signals)
    for anchor in spec.anchors:
        if anchor.name in lay.anchor_signal:
            j = lay.anchor_signal[anchor.name]
            signals[j : j + 3] = anchor.position
    fn = ca.Function("measurable", [model.inputs[0], model.inputs[2]], [ca.densify(au)])
    block = np.array(fn(nominal_coordinates(spec, lay), signals).full())
    sv = np.linalg.svd(block, compute_uv=False)
    rank = int(np.count_nonzero(sv > RANK_TOLERANCE * max(sv.max(initial=0.0), 1.0)))
    if rank < len(names):
        raise ExportError(
            f"the [sensing] section measures too little: {len(names)} unmeasured coordinates with only {rank} "
            f"independent constraints on them ({', '.join(names)}); measure each body's r and two of its axes "
            "(docs/sensing.md)"
        )


def controller_files(name: str) -> list[str]:
    return [f"{name}_functions.c", f"{name}_functions.h", f"{name}.c", f"{name}.h"]


def write_controller(export: ControllerExport, out_dir: Path) -> list[Path]:
    """Write <name>_functions.c/.h (CasADi) and <name>.c/.h (the wrapper): deterministic bytes."""
    from .controller_text import header_text, source_text
    from .step_c import _comment_block as comment_block

    out_dir.mkdir(parents=True, exist_ok=True)
    stem = f"{export.name}_functions"
    cg = ca.CodeGenerator(f"{stem}.c", {"with_header": True})
    for function in export.functions:
        cg.add(function)
    cg.generate(str(out_dir) + "/")
    step_comment = comment_block(export.step)
    for suffix in (".c", ".h"):
        path = out_dir / f"{stem}{suffix}"
        path.write_text(step_comment + path.read_text())
    (out_dir / f"{export.name}.h").write_text(header_text(export))
    (out_dir / f"{export.name}.c").write_text(source_text(export))
    return [out_dir / f for f in controller_files(export.name)]


def export_controller(spec_path: Path, method: str, out_dir: Path, mlm_system: str = "reduced",
                      penalty_system: str = "auto", sensing: Sensing | None = None, **gain_overrides) -> list[Path]:
    """Load a spec, build the stateful controller with the spec's gains (plus overrides) and sensing
    (default the spec's [sensing] section) and write its four files."""
    spec = load_spec(spec_path)
    gains = Gains.from_spec(spec, **gain_overrides)
    export = build_controller(spec, method, gains, spec.sensing if sensing is None else sensing,
                              spec_path=Path(spec_path), mlm_system=mlm_system, penalty_system=penalty_system)
    return write_controller(export, out_dir)
