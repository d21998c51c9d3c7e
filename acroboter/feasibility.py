"""Can the desired path be followed within the input limits? Checked before a run.

The ideal motion is the one on which every servo-constraint holds exactly (σ ≡ 0 from the static
start): MLM's inverse dynamics without limits, simulated on the plant (the internal dynamics,
the connector's swing, are part of it and known only by simulating). At every control instant
of it the question is whether some input within the limits realises the same servo-constraint
accelerations, E u = e (codegen.structured.mlm_bounded_terms; with more inputs than
servo-constraints a family of inputs does, and the bounded one closest to it is tried). The
first instant where none does is reported with the input that is out of its limits and by how
much. The check needs at least as many inputs as servo-constraints; MLM's redundant-constraint
singularity does not stop it (E uses the independent constraint rows only).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from .controllers import MLM, Gains, SingularSystemError, unbounded
from .distribution import BoundedInputs, DistributionError
from .path import DesiredPath
from .plant import SimulationError
from .simulation import simulate

# A bounded input that misses E u = e by less than this (relative to max(1, |e|)) realises the path.
RESIDUAL_TOLERANCE = 1e-6


@dataclass
class Feasibility:
    feasible: bool | None  # None: could not be checked (see message)
    checked_until_s: float
    message: str
    first_infeasible_s: float | None = None
    input: str | None = None
    needed: float | None = None  # the ideal (unbounded) value of that input
    limit: float | None = None  # the limit it crosses
    infeasible_instants: int = 0
    instants: int = 0

    def to_dict(self) -> dict:
        return asdict(self)


class _IdealInverseDynamics(MLM):
    """MLM through E u = e on the independent constraint rows, without limits (see the module docstring)."""

    name = "ideal"

    def __init__(self, model, path, gains):
        super().__init__(model, path, gains, limits=unbounded(model.spec))
        self.redundant_inputs = True  # always the E u = e route, never the Schur solve


def check_path(model, path: DesiredPath, plant, q0: np.ndarray, duration: float, gains: Gains) -> Feasibility:
    """Sample the ideal motion at the control instants and test each against the spec's limits."""
    spec, lay = model.spec, model.layout
    if lay.k > lay.l:
        return Feasibility(None, 0.0, f"not checked: {lay.k} servo-constraints for {lay.l} inputs, so the path "
                                      "cannot be realised exactly even without limits")
    lower, upper, preferred = spec.input_limits()
    if not (np.isfinite(lower).any() or np.isfinite(upper).any()):
        return Feasibility(True, duration, "no input has a limit")
    ideal = _IdealInverseDynamics(model, path, gains)
    try:
        run = simulate(model, path, ideal, plant, q0, duration, spec.controller.rate_hz, spec.simulation.step,
                       allow_divergence=True)
    except (SingularSystemError, SimulationError) as err:
        return Feasibility(None, 0.0, f"not checked: the ideal motion could not be simulated: {err}")
    bounded = BoundedInputs(lower, upper, preferred)
    terms = model.functions["mlm_bounded_terms"]
    out = terms.outputs
    first = None
    count = 0
    for k, t in enumerate(run.t):
        u = run.u[k]
        if bounded.within_limits(u):
            continue
        model.set_inputs(run.q[k], run.qd[k])
        model.signals[:] = path.flat(t)
        model.p[:] = gains.parameter_vector()
        model.parameters_owner = None
        terms.call()
        try:
            best = bounded.solve(out["hessian"], out["gradient"])
        except DistributionError:
            best = np.clip(u, lower, upper)
        residual = float(np.abs(out["servo_map"] @ best - out["servo_target"]).max())
        if residual <= RESIDUAL_TOLERANCE * max(1.0, float(np.abs(out["servo_target"]).max())):
            continue  # redundant inputs: another distribution within the limits realises it
        count += 1
        if first is None:
            excess = np.maximum(lower - u, u - upper)
            i = int(np.argmax(excess))
            first = (float(t), i, float(u[i]), float(lower[i] if u[i] < lower[i] else upper[i]))
    checked = float(run.t[-1]) if run.t.size else 0.0
    tail = ""
    if run.diverged_at is not None:
        tail = (f"; the ideal motion itself diverges at t = {run.diverged_at:.2f} s ({run.divergence}), "
                "checked until then")
    if first is None:
        return Feasibility(True if run.diverged_at is None else None, checked,
                           f"feasible: the ideal inputs stay within the limits at all {run.t.size} instants" + tail,
                           instants=run.t.size)
    t0, i, needed, limit = first
    unit = lay.input_units[i]
    return Feasibility(
        False, checked,
        f"not feasible with these limits: at t = {t0:.2f} s {lay.inputs[i]} would need {needed:.4g} {unit}, beyond "
        f"its limit {limit:.4g} {unit} ({count} of {run.t.size} instants out of reach)" + tail,
        t0, lay.inputs[i], needed, limit, count, run.t.size,
    )
