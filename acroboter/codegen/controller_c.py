"""The stateful exported controller (issue 23 item 1): estimator, integral action and control step as C.

    acroboter export-step --stateful [--spec ...] [--method ...] [--ki ...] [--out DIR]

writes four files for the robot's real-time computer:

- <name>_functions.c/.h: CasADi's CodeGenerator output (plain C, libm only, no heap) of the algebra:
  the control step of acroboter.codegen.export_step with the integral z = ∫σ dt as a sixth input (k_I z in
  ρ_s) and the commanded acceleration q̈ as a second output (`<name>_core`), and the estimator's pieces
  of acroboter.sim.sensing.Estimator, each one SX function with shared subexpressions: max |φ| over the
  independent rows, the minimal-norm Gauss–Newton step φ_qᵀ(φ_q φ_qᵀ)⁻¹φ, the unmeasured coordinates'
  least-squares step (a_Uᵀa_U)⁻¹a_Uᵀφ, the rate correction φ_qᵀ(φ_q φ_qᵀ)⁻¹φ̇ and σ (SX Cholesky, as
  codegen.solver_terms.cholesky_solve);
- <name>.c/.h: the hand-written wrapper (acroboter/c/controller.c and .h, the estimator's
  estimator.c, the path's path.c, filled in by acroboter.codegen.controller_text) with a state struct and
  init(state, q0, signals), step(state, y, t, signals, u), reset(state), reinit(state) and path(t, signals):
  the estimator with its sample checks (fixed iteration counts), the α-β filter, the delay carried over with
  the commanded accelerations, the integral by the trapezoid rule with its anti-windup, the core step and
  the command's checks (the safe command where it cannot be trusted). All buffers (the work arrays of the
  generated functions included, sized here) are in the state struct: no heap, no globals.

Without a [sensing] section (or with an ideal one, as acroboter.sim.fast_estimator.make_estimator) the
measurements are the state itself, y = [q; q̇], and no estimator runs.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import casadi as ca
import numpy as np

from ..model.layout import nominal_coordinates
from ..model.schema import Sensing
from ..model.sensing_layout import is_ideal, measured_groups, measured_indices
from ..model.settings import Gains, command_bounds
from ..model.spec import Spec, load_spec
from .emit_c import INPUT_NAMES
from .estimator_c import EstimatorExport, build_estimator
from .export_step import ExportError, build_step, step_name
from .solver_terms import independent_rows
from .stack_usage import measure_stack
from .step_graph import StepExport
from .symbolic import build_symbolic_model

RANK_TOLERANCE = 1e-9  # as acroboter.sim.sensing.RANK_TOLERANCE
# CasADi's generated C under -Wall -Wextra (tests/test_c_sources.py): every function has the same signature
# (arg, res, iw, w, mem), most leave some unused; and gcc 12's -Warray-bounds flags casadi_copy's zero fill in the
# bounded QP's Switch branch after constant propagation (a destination it sizes [0, 0]; -Wstringop-overflow says the
# same), a path the sizes CasADi checked never take (closed loops ran clean under ASan and UBSan, docs/controller.md).
GENERATED_PRAGMAS = """#if defined(__GNUC__)
#pragma GCC diagnostic ignored "-Wunused-parameter"
#pragma GCC diagnostic ignored "-Warray-bounds"
#pragma GCC diagnostic ignored "-Wstringop-overflow"
#endif
"""

__all__ = ["ControllerExport", "build_controller", "controller_files", "controller_name", "export_controller"]


@dataclass
class ControllerExport:
    """Everything the wrapper's text needs: the core step, the estimator (None: y is the state), the numbers."""

    name: str  # C prefix of the API and stem of <name>.c/.h
    step: StepExport  # the core: (u, qdd, saturated) = core(q, qd, s, sd, sdd, z)
    sensing: Sensing | None  # None: the measurements are the state [q; qd]
    estimator: EstimatorExport | None
    coordinates: list[str]  # the layout's coordinate names
    groups: list[tuple[str, str, float, float]]  # per measurement: group, unit, noise, quantisation step
    period: float
    start_q: np.ndarray  # the spec's static equilibrium at the path's start: the header's <name>_q0
    path_numbers: np.ndarray  # the spec's path as acroboter.control.fast_path.path_table's numbers (<name>_path)
    command_low: np.ndarray  # the limits intersected with the sanity bound (acroboter.model.settings)
    command_high: np.ndarray
    n_constraints: int  # rows of phi (init's check)
    functions: list[ca.Function] = field(default_factory=list)
    work: tuple[int, int, int, int] = (0, 0, 0, 0)  # max sz_arg, sz_res, sz_iw, sz_w over the controller's own

    @property
    def measured(self) -> np.ndarray:
        return self.estimator.measured if self.estimator else np.zeros(0, dtype=np.intp)

    @property
    def unmeasured(self) -> np.ndarray:
        return self.estimator.unmeasured if self.estimator else np.zeros(0, dtype=np.intp)

    @property
    def rows(self) -> list[int]:
        return self.estimator.rows if self.estimator else []

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
                     spec_path: Path | None = None, mlm_system: str = "reduced", penalty_system: str = "auto", *,
                     start_q: np.ndarray | None = None, path_numbers: np.ndarray | None = None) -> ControllerExport:
    """Build the core step (with z, q̈ and the saturation judgement), σ, φ and the estimator's SX functions for
    `sensing` (resolved, e.g. acroboter.sim.sensing.resolve; None: the state is measured). `start_q` (the static
    equilibrium) and `path_numbers` (acroboter.control.fast_path.path_table of the spec's path) become the header's
    constants: the library computes them (acroboter.api.crane.Crane.export_controller)."""
    if start_q is None or path_numbers is None:
        raise ExportError("the stateful controller needs its start state and the path's numbers: export it through "
                          "the library (Crane.export_controller, or `acroboter export-step --stateful`)")
    name = controller_name(spec, method, gains.recovery)
    step = build_step(spec, method, gains, spec_path=spec_path, name=f"{name}_core", mlm_system=mlm_system,
                      penalty_system=penalty_system, stateful=True)
    model = build_symbolic_model(spec)
    lay = model.layout
    if sensing is not None and is_ideal(spec, lay, sensing):
        sensing = None  # every coordinate, exactly, no delay: the plant's state, as make_estimator
    low, high = command_bounds(spec)
    q, qd, s, sd, sdd = model.inputs
    functions = [step.function,
                 ca.Function(f"{name}_sigma", list(model.inputs), [ca.densify(ca.SX(model.sigma))], list(INPUT_NAMES),
                             ["sigma"], {"cse": True}),
                 ca.Function(f"{name}_phi", [q, s], [ca.densify(ca.SX(model.phi))], ["q", "s"], ["phi"],
                             {"cse": True})]
    work = tuple(max(getattr(f, attr)() for f in functions) for attr in ("sz_arg", "sz_res", "sz_iw", "sz_w"))
    estimator, groups = None, []
    if sensing is not None:
        index, noise, steps = measured_indices(spec, lay, sensing)
        if len(set(index.tolist())) != index.size:
            raise ExportError("a coordinate is measured twice: each coordinate belongs to at most one sensing group")
        unmeasured = np.setdiff1d(np.arange(lay.n), index)
        if unmeasured.size:
            a = ca.SX(model.phi_q)[independent_rows(model), :]
            _check_measurable(model, a[:, unmeasured.tolist()], [lay.coordinates[i] for i in unmeasured])
        estimator = build_estimator(spec, sensing, name, model)
        names = measured_groups(spec, sensing)
        groups = [(names[j], _unit(lay.coordinates[i]), float(noise[j]), float(steps[j])) for j, i in enumerate(index)]
        functions += estimator.functions
    return ControllerExport(name, step, sensing, estimator, list(lay.coordinates), groups,
                            1.0 / spec.controller.rate_hz, np.asarray(start_q, dtype=float),
                            np.asarray(path_numbers, dtype=float), low, high, lay.m, functions,
                            work)  # type: ignore[arg-type]


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
    from .controller_text import render_controller
    from .step_c import _comment_block as comment_block

    out_dir.mkdir(parents=True, exist_ok=True)
    stem = f"{export.name}_functions"
    cg = ca.CodeGenerator(f"{stem}.c", {"with_header": True})
    for function in export.functions:
        cg.add(function)
    cg.generate(str(out_dir) + "/")
    step_comment = comment_block(export.step, header=f"{stem}.h").replace(
        "/*\n", f"/*\n * The generated functions of {export.name} (the controller's calls: {export.name}.h): the core "
        f"step below, {export.name}_sigma, {export.name}_phi and the estimator's.\n *\n", 1)
    for suffix in (".c", ".h"):
        path = out_dir / f"{stem}{suffix}"
        path.write_text(step_comment + (GENERATED_PRAGMAS if suffix == ".c" else "") + path.read_text())
    functions_text = (out_dir / f"{stem}.c").read_text()
    header, source = render_controller(export, functions_text)
    (out_dir / f"{export.name}.h").write_text(header)
    (out_dir / f"{export.name}.c").write_text(source)
    # the stack each call needs, by the compiler at hand (the header names it; none: the header says so)
    entries = [f"{export.name}_{call}" for call in ("init", "step", "reset", "reinit", "path")]
    measured = measure_stack(out_dir, [f"{export.name}.c", f"{stem}.c"], entries)
    if measured is not None:
        (out_dir / f"{export.name}.h").write_text(render_controller(export, functions_text, measured)[0])
    return [out_dir / f for f in controller_files(export.name)]


def export_controller(spec_path: Path, method: str, out_dir: Path, mlm_system: str = "reduced",
                      penalty_system: str = "auto", sensing: Sensing | None = None, *, start_q: np.ndarray,
                      path_numbers: np.ndarray, **gain_overrides) -> list[Path]:
    """Load a spec, build the stateful controller with the spec's gains (plus overrides) and sensing
    (default the spec's [sensing] section) and write its four files."""
    spec = load_spec(spec_path)
    gains = Gains.from_spec(spec, **gain_overrides)
    export = build_controller(spec, method, gains, spec.sensing if sensing is None else sensing,
                              spec_path=Path(spec_path), mlm_system=mlm_system, penalty_system=penalty_system,
                              start_q=start_q, path_numbers=path_numbers)
    return write_controller(export, out_dir)
