"""Initial state: the static equilibrium at the start of the path (docs/model.md §9).

Unknowns (q, λ, u); equations: force balance c(q, 0) + φ_qᵀ λ = H u, the geometric constraints
φ(q, s0) = 0 and the servo-constraints σ(q, s0) = 0 with the targets at the path's start. For a
symmetric crane the spec's nominal configuration already solves this; for a general one the
solve moves the connector and the cable lengths until the held unit is in balance.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from ..control.path import DesiredPath
from ..model.layout import body_rotation, nominal_coordinates
from ..model.spec import PositionTask, YawTask
from ..runtime.compiled import CompiledModel


class EquilibriumError(RuntimeError):
    """No static equilibrium at the start of the path (within EQUILIBRIUM_EVALUATIONS, or to a residual
    of 1e-8): the message names the spec and what to check."""


# The solve gives up after this many evaluations of its residual (a spec whose start has no equilibrium must say
# so quickly: about 6 s on the 2-core VM). A count, not a clock: a wall-clock limit (5 s until 2026-12-06)
# rejected generated crane_211, whose solve takes 187,064 evaluations (4.5 s), on a loaded machine and accepted it
# on an idle one; the same spec now gets the same answer everywhere.
EQUILIBRIUM_EVALUATIONS = 250_000
# From a neighbouring equilibrium (solve_equilibrium's `near`): a few Levenberg–Marquardt steps' worth.
NEAR_EVALUATIONS = 2_000


class _OutOfEvaluations(Exception):
    pass


@dataclass
class Equilibrium:
    """The static equilibrium at the start of a path, at rest (`Crane.equilibrium()`): the natural
    coordinates `q` (in `crane.coordinates` order), the constraint multipliers `multipliers` (λ), the
    `inputs` u that hold it (in `crane.inputs` order: N, N·m) and the largest `residual` of the force
    balance, the constraints and the servo-constraints there."""

    q: np.ndarray
    multipliers: np.ndarray
    inputs: np.ndarray
    residual: float


def start_targets(model: CompiledModel) -> tuple[np.ndarray, float]:
    """Where the tracked point and yaw start: the spec's nominal configuration."""
    spec = model.spec
    position = next(t for t in spec.task if isinstance(t, PositionTask))
    body = spec.body(position.body)
    start_point = np.array(body.initial_position) + body_rotation(body.initial_yaw_deg) @ np.array(position.point)
    yaw_task = next((t for t in spec.task if isinstance(t, YawTask)), None)
    start_yaw = math.radians(spec.body(yaw_task.body).initial_yaw_deg) if yaw_task else 0.0
    return start_point, start_yaw


def desired_path(model: CompiledModel) -> DesiredPath:
    start_point, start_yaw = start_targets(model)
    return DesiredPath(model.spec, model.layout, start_point, start_yaw)


def solve_equilibrium(model: CompiledModel, path: DesiredPath, tol: float = 1e-14,
                      near: Equilibrium | None = None) -> Equilibrium:
    """The static equilibrium at the start of `path` (see Equilibrium); `near`: one at a neighbouring place to
    start from (a continuation along a path: a few iterations where the nominal configuration takes a dozen, and
    the same branch of the yaw's servo-constraint, which holds at ψ and at ψ + π, as the neighbour's)."""
    lay = model.layout
    n, m, l = lay.n, lay.m, lay.l
    s0, sd0, sdd0 = path.signal_arrays(0.0)
    zero = np.zeros(n)
    terms = model.functions["model_terms"]
    out = terms.outputs

    budget = [math.inf]  # evaluations left, set when the iterative solve starts

    def residual(z: np.ndarray) -> np.ndarray:
        budget[0] -= 1
        if budget[0] < 0:
            raise _OutOfEvaluations
        q, lam, u = z[:n], z[n : n + m], z[n + m :]
        model.set_inputs(q, zero, s0, sd0, sdd0)
        terms.call()
        balance = out["bias_forces"] + out["phi_q"].T @ lam - out["input_matrix"] @ u
        return np.concatenate([balance, out["phi"], out["sigma"]])

    def nominal_start() -> np.ndarray:
        q0 = nominal_coordinates(model.spec, lay)
        # Multipliers and inputs that best balance the nominal configuration: a good first guess.
        model.set_inputs(q0, zero, s0, sd0, sdd0)
        terms.call()
        reactions = np.hstack([out["phi_q"].T, -out["input_matrix"]])
        return np.concatenate([q0, np.linalg.lstsq(reactions, -out["bias_forces"], rcond=None)[0]])

    def solved_from(z0: np.ndarray, evaluations: int) -> np.ndarray | None:
        if np.abs(residual(z0)).max() <= tol:
            return z0
        budget[0] = evaluations
        try:
            sol = least_squares(residual, z0, method="lm" if n + m + lay.k >= n + m + l else "trf",
                                xtol=1e-15, ftol=1e-15, gtol=1e-15, max_nfev=200 * z0.size)
        except _OutOfEvaluations:
            return None
        finally:
            budget[0] = math.inf
        return sol.x

    z0 = None
    if near is not None:  # a neighbour's equilibrium, given a few iterations' worth of evaluations (else: nominal)
        z0 = solved_from(np.concatenate([near.q, near.multipliers, near.inputs]), NEAR_EVALUATIONS)
        if z0 is not None and not np.abs(residual(z0)).max() <= 1e-8:
            z0 = None  # (the redundant-constraint crane's multipliers stalled LM from its neighbour at s = 0.13)
    if z0 is None:
        z0 = solved_from(nominal_start(), EQUILIBRIUM_EVALUATIONS)
    if z0 is None:
        raise EquilibriumError(
            f"no static equilibrium found at the start of the path for spec '{model.spec.name}' within "
            f"{EQUILIBRIUM_EVALUATIONS:,} evaluations of its residual: check the initial positions, cable lengths "
            "and the task"
        )
    if lay.l > lay.k:  # more inputs than servo-constraints: the internal forces as the distribution sets them
        z0 = _nearest_preferred(residual, z0, n + m, np.asarray(model.spec.input_limits()[2], dtype=float))
    r = np.abs(residual(z0)).max()
    if not np.isfinite(r) or r > 1e-8:
        raise EquilibriumError(
            f"no static equilibrium found at the start of the path for spec '{model.spec.name}' "
            f"(largest residual {r:.3g}): check the initial positions, cable lengths and the task"
        )
    return Equilibrium(q=z0[:n].copy(), multipliers=z0[n : n + m].copy(), inputs=z0[n + m :].copy(), residual=r)


# Redundant inputs: steps of the constrained Gauss–Newton method towards the preferred inputs, and the finite-difference
# step of its Jacobian (relative to each unknown's size).
PREFERRED_ITERATIONS = 30
_FD_STEP = 1e-7


def _nearest_preferred(residual, z: np.ndarray, first_input: int, preferred: np.ndarray) -> np.ndarray:
    """Among the equilibria, the one whose inputs are nearest the spec's preferred values.

    Why: with more inputs than servo-constraints (four winches for the three a position and a level need) the
    equilibria are a family: the cables can pull against each other with any internal force. The least-squares
    solve stops at whichever it reaches first, which on an asymmetric crane can be a winch pushing (a generated
    four-winch crane: −20 N). The controllers' distribution (acroboter.control.distribution) puts the internal
    forces at the preferred values; the start does the same: minimise ½|u − u_pref|² subject to the equilibrium
    equations F(z) = 0, by Gauss–Newton steps on the equality-constrained problem (each the minimum-norm solution
    of its KKT system, the Jacobian by finite differences), from the equilibrium found."""
    size = z.size
    select = np.zeros((size - first_input, size))
    select[:, first_input:] = np.eye(size - first_input)
    for _ in range(PREFERRED_ITERATIONS):
        f, jac = residual(z), _jacobian(residual, z)
        kkt = np.block([[select.T @ select + 1e-12 * np.eye(size), jac.T], [jac, np.zeros((f.size, f.size))]])
        rhs = np.concatenate([-select.T @ (z[first_input:] - preferred), -f])
        delta = np.linalg.lstsq(kkt, rhs, rcond=None)[0][:size]
        z = z + delta
        for _ in range(PREFERRED_ITERATIONS):  # back onto F(z) = 0: minimum-norm Newton steps (the step is linear)
            f = residual(z)
            if np.abs(f).max() <= 1e-12 * max(1.0, np.abs(z).max()):
                break
            z = z - np.linalg.lstsq(_jacobian(residual, z), f, rcond=None)[0]
        if np.abs(delta).max() <= 1e-10 * max(1.0, np.abs(z).max()):
            break
    return z


def _jacobian(residual, z: np.ndarray) -> np.ndarray:
    """∂F/∂z by central differences."""
    columns = []
    for j in range(z.size):
        step = _FD_STEP * max(1.0, abs(z[j]))
        dz = np.zeros(z.size)
        dz[j] = step
        columns.append((residual(z + dz) - residual(z - dz)) / (2 * step))
    return np.column_stack(columns)


def inputs_outside_limits(spec, layout, inputs: np.ndarray) -> list[str]:
    """What a static equilibrium asks of the inputs beyond the spec's limits, one phrase per input ([] when
    every input is within them): e.g. `tension_1 would need -3.2 N, beyond its limit 0 N (a winch cannot
    push)`. The same words as the path's feasibility check (acroboter.sim.feasibility) at t = 0."""
    lower, upper, _ = spec.input_limits()
    found = []
    for i, (actuator, unit) in enumerate(zip(spec.actuators, layout.input_units, strict=True)):
        u = float(inputs[i])
        tol = 1e-9 * max(1.0, abs(u))
        if lower[i] - tol <= u <= upper[i] + tol:
            continue
        limit = lower[i] if u < lower[i] else upper[i]
        pushes = actuator.kind == "winch_tension" and actuator.gain * u < 0
        found.append(f"{layout.inputs[i]} would need {u:.4g} {unit}, beyond its limit {limit:.4g} {unit}"
                     + (" (a winch cannot push)" if pushes else ""))
    return found
