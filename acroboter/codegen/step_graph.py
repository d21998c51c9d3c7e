"""The shared state while one exported control step's MX graph is built (acroboter.codegen.export_step).

What every method's graph starts from: the model terms as sparse SX, the constant mass matrix and its
Cholesky factor's inverse, the step's MX inputs, the penalty and servo right-hand sides, the prelude that
turns SX expressions into one casadi.Function called on the MX inputs, and the bounded distribution's
pieces (acroboter.codegen.step_qp). ExportError and StepExport are defined here, below every part of the
export.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path

import casadi as ca
import numpy as np
from scipy.linalg import cholesky, solve_triangular

from ..model.controller_parameters import runtime_size, runtime_view
from ..model.layout import Layout, nominal_coordinates
from ..model.settings import Gains
from ..model.spec import Spec
from .emit_c import INPUT_NAMES
from .step_qp import Bounds
from .symbolic import SymbolicModel

LINSOL_SPD = "ldl"  # sparse LDLᵀ, static ordering, no pivoting: fine for symmetric positive definite
LINSOL_GENERAL = "qr"  # sparse Householder QR: any nonsingular square matrix
# Model terms the step needs, in the order of the wrapped SX function's outputs.
TERMS = (
    "bias_forces", "phi", "phi_q", "phi_dot", "gamma",
    "sigma", "sigma_q", "sigma_dot", "gamma_s", "input_matrix",
)


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
    integral: bool = False  # stateful export: z = ∫σ dt is a sixth input and the step also returns q̈
    # The Python controllers' fast path (acroboter.codegen.fast_step): the gains and z are a run-time input p
    # (codegen.solver_terms's parameter vector) and the limits and preferred values another; no QP in the C.
    parametric: bool = False
    linear_solvers: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    distribution: list[str] = field(default_factory=list)  # how the input limits are honoured (header)
    qp_used: bool = False


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


def constant(matrix: np.ndarray) -> ca.DM:
    """A numeric matrix as a sparse DM, dropping round-off entries of its block structure."""
    matrix = matrix.copy()
    matrix[np.abs(matrix) < 1e-15 * np.abs(matrix).max()] = 0.0
    return ca.sparsify(ca.DM(matrix))


class StepGraph:
    """Shared state while one step's MX graph is built.

    `prelude(outputs)` turns SX expressions of (q, qd, s, sd, sdd) into one casadi.Function (the model
    terms and everything assembled from them, with common subexpressions shared, as straight-line C)
    and returns its outputs called on the step's MX inputs. The linear solves and the few products
    between them stay in MX.
    """

    def __init__(self, export: StepExport, model: SymbolicModel):
        """With export.integral (the stateful controller, acroboter.codegen.controller_c): a sixth input z
        (the servo-constraints' integral, per row) enters ρ_s as k_I z, as in the Python controllers."""
        self.export, self.model, self.gains = export, model, export.gains
        lay = model.layout
        self.n, self.m, self.k, self.l, ns = lay.n, lay.m, lay.k, lay.l, lay.n_signals
        self.sx = sx_terms(model)
        self.mass = constant_mass_matrix(model)
        chol = cholesky(self.mass, lower=True)
        self.inv_chol = solve_triangular(chol, np.eye(self.n), lower=True)  # L⁻¹, M = L Lᵀ
        self.mass_dm = constant(self.mass)
        self.inv_mass_dm = constant(self.inv_chol.T @ self.inv_chol)
        self.inputs = [ca.MX.sym("q", self.n), ca.MX.sym("qd", self.n)]
        self.inputs += [ca.MX.sym(name, ns) for name in ("s", "sd", "sdd")]
        self.sx_inputs = list(model.inputs)  # what the SX pieces (prelude, bounded terms) are functions of
        self.input_names = list(INPUT_NAMES)
        g, T = self.gains, self.sx
        # ρ = γ + 2Ωμ φ̇ + Ω² φ (geometric penalty); ρ_s = γ_s + 2 k_D σ̇ + k_P² σ (servo error dynamics)
        self.rho = T["gamma"] + 2.0 * g.omega * g.mu * T["phi_dot"] + g.omega**2 * T["phi"]
        self.rho_s = T["gamma_s"] + 2.0 * g.kd * T["sigma_dot"] + g.kp**2 * T["sigma"]
        self.params = ca.DM(g.parameter_vector(self.k))  # codegen.solver_terms's p, as constants (z = 0)
        self.qdd: ca.MX | None = None  # the commanded acceleration, set by the method (stateful export)
        self.limits_input: ca.MX | None = None  # parametric: [lower; upper; preferred], a run-time input
        self.outputs: dict[str, ca.MX] = {}  # parametric: further outputs a method adds (MLM's rcond)
        if export.parametric:
            self._parametric(export)
        if export.integral:
            z = ca.SX.sym("z", self.k)
            self.sx_inputs.append(z)
            self.input_names.append("z")
            self.inputs.append(ca.MX.sym("z", self.k))
            self.rho_s = self.rho_s + g.ki * z  # + k_I z, as codegen.solver_terms.servo_and_constraint_rates
            self.params = ca.vertcat(ca.SX(ca.DM(g.parameter_vector(0))), z)  # p with the symbolic z
        self.bounds = Bounds(self)
        if export.parametric:  # no QP in the C: u of step 1 or 2; the caller checks it against the limits
            self.bounds.bounded = False
            self.bounds.preferred_input = self.limits_input[2 * self.l :]

    @property
    def wants_qdd(self) -> bool:
        """Does the step report q̈ (the stateful controller's estimator, the fast path's controller.qdd)?"""
        return self.export.integral or self.export.parametric

    def _parametric(self, export: StepExport) -> None:
        """Gains and z from a run-time input p = [k_P, k_D, α̃, α̂, Ω, μ, k_I, z] (model.controller_parameters), in
        the graph as SX (self.gains: the runtime parameters symbols, the others the concrete settings) and as MX
        (mx_gain); ρ and ρ_s as the baked export writes them, plus k_I z."""
        if export.integral:
            raise ExportError("internal: the parametric step carries z in p; it is not the stateful export")
        size = runtime_size(self.k)
        p = ca.SX.sym("p", size)
        concrete = self.gains
        view = runtime_view(p, self.k)
        self.gains = dataclasses.replace(concrete, **view.scalars)
        self.concrete_gains = concrete
        self.sx_inputs.append(p)
        self.input_names.append("p")
        self.inputs.append(ca.MX.sym("p", size))
        self.limits_input = ca.MX.sym("limits", 3 * self.l)
        g, T = self.gains, self.sx
        z = view.z
        self.rho = T["gamma"] + 2.0 * g.omega * g.mu * T["phi_dot"] + g.omega**2 * T["phi"]
        self.rho_s = T["gamma_s"] + 2.0 * g.kd * T["sigma_dot"] + g.kp**2 * T["sigma"] + g.ki * z
        self.params = p

    def mx_gain(self, name: str):
        """A gain where the graph is MX (between the solves): its number, or the parametric input's entry."""
        if not self.export.parametric:
            return getattr(self.gains, name)
        return runtime_view(self.inputs[-1], self.k).scalars[name]

    def prelude(self, outputs: dict[str, ca.SX]) -> dict[str, ca.MX]:
        names = list(outputs)
        fn = ca.Function(
            f"{self.export.name}_terms", self.sx_inputs, [outputs[k] for k in names],
            self.input_names, names, {"cse": True},
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
        fn = ca.Function("nominal", self.sx_inputs, [ca.densify(expr)])
        extra = [np.zeros(self.k)] if self.export.integral else []
        if self.export.parametric:
            extra = [self.concrete_gains.parameter_vector(self.k)]
        return np.array(fn(q0, zeros_q, s0, zeros_s, zeros_s, *extra).full())

