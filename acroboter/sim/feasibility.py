"""Can the desired path be followed within the input limits? Checked before a run.

The ideal motion is the one on which every servo-constraint holds exactly (σ ≡ 0 from the static
start): MLM's inverse dynamics, simulated on the plant, because the internal dynamics (the
connector's swing) are part of it and known only by simulating. It is run with the spec's limits
(MLM through E u = e, acroboter.codegen.solver_terms.mlm_bounded_terms, bounded by acroboter.control.distribution):
while an input within the limits realises the servo-constraint accelerations, the motion is the
ideal one; with more inputs than servo-constraints the distribution looks for such an input among
all that realise them, so redundancy that can absorb a weak winch is not reported as a failure.
The first instant where no input within the limits does is reported, with the input that is held
by its limit, what the unbounded inverse dynamics ask of it, and the limit. Later instants are
no longer the ideal motion; they are counted only as a hint of how much of the path is out of
reach. The check needs at least as many inputs as servo-constraints; MLM's redundant-constraint
singularity does not stop it (E uses the independent constraint rows only).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from ..control.controllers import MLM, Gains, SingularSystemError
from ..control.path import DesiredPath
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


class _InverseDynamics(MLM):
    """MLM through E u = e on the independent constraint rows, within the limits, recording per instant
    whether E u = e was met and, if not, which input was held and what it was asked for."""

    name = "ideal"

    def __init__(self, model, path, gains):
        super().__init__(model, path, gains)
        self.redundant_inputs = True  # always the E u = e route, never the Schur solve
        self.misses: list[tuple[float, int, float, float]] = []  # (t, input, needed, limit)

    def compute(self, q, qd, t, signals=None):
        u = super().compute(q, qd, t, signals)
        B, limits = self.bounded_terms, self.limits
        if not self.limit_state.any():
            return u  # no limit in the way (E u = e unmet without limits is not this check's question)
        residual = float(np.abs(B["servo_map"] @ u - B["servo_target"]).max())
        if residual > RESIDUAL_TOLERANCE * max(1.0, float(np.abs(B["servo_target"]).max())):
            asked = limits.unbounded
            excess = np.where(self.limit_state != 0, np.maximum(limits.lower - asked, asked - limits.upper), -np.inf)
            i = int(np.argmax(excess))
            limit = limits.lower[i] if self.limit_state[i] < 0 else limits.upper[i]
            self.misses.append((float(t), i, float(asked[i]), float(limit)))
        return u


def check_path(model, path: DesiredPath, plant, q0: np.ndarray, duration: float, gains: Gains) -> Feasibility:
    """Sample the ideal motion at the control instants and test each against the spec's limits."""
    spec, lay = model.spec, model.layout
    if lay.k > lay.l:
        return Feasibility(None, 0.0, f"not checked: {lay.k} servo-constraints for {lay.l} inputs, so the path "
                                      "cannot be realised exactly even without limits")
    lower, upper, _ = spec.input_limits()
    if not (np.isfinite(lower).any() or np.isfinite(upper).any()):
        return Feasibility(True, duration, "no input has a limit")
    ideal = _InverseDynamics(model, path, gains)
    try:
        run = simulate(model, path, ideal, plant, q0, duration, spec.controller.rate_hz, spec.simulation.step,
                       allow_divergence=True)
    except (SingularSystemError, SimulationError) as err:
        return Feasibility(None, 0.0, f"not checked: the ideal motion could not be simulated: {err}")
    checked = float(run.t[-1]) if run.t.size else 0.0
    tail = ""
    if run.diverged_at is not None:
        tail = (f"; the motion itself diverges at t = {run.diverged_at:.2f} s ({run.divergence}), "
                "checked until then")
    if not ideal.misses:
        return Feasibility(True if run.diverged_at is None else None, checked,
                           f"feasible: an input within the limits realises the ideal motion at all {run.t.size} "
                           "instants" + tail, instants=run.t.size)
    count = len(ideal.misses)
    t0, i, needed, limit = ideal.misses[0]
    unit = lay.input_units[i]
    return Feasibility(
        False, checked,
        f"not feasible with these limits: at t = {t0:.2f} s {lay.inputs[i]} would need {needed:.4g} {unit}, beyond "
        f"its limit {limit:.4g} {unit} ({count} of {run.t.size} instants of the bounded motion out of reach)" + tail,
        t0, lay.inputs[i], needed, limit, count, run.t.size,
    )
