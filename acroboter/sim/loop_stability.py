"""Why a closed loop diverges when nothing saturates: the stability of the sampled loop and of the crane's zero
dynamics, linearised at a state of the run.

Both in the coordinates of the constraint manifold at the state: an orthonormal basis N of null(φ_q), d position
and d velocity coordinates (the directions that break a constraint are the plant's Baumgarte terms' to damp).

- **Zero dynamics.** The ideal motion under exact inverse dynamics (MLM's q̈, the servo-constraints met exactly,
  no sampling) linearised: its eigenvalues λ. The servo law's own poles are stable by the gains; an eigenvalue with
  Re λ > 0 is the crane's internal motion (the connector's swing, the unit's unprescribed rotations) growing
  while the servo-constraints hold. No exact inverse dynamics holds such a crane on that path, at any rate.
- **The sampled loop.** The method's input computed at the state and held over the control period while the plant
  integrates it (the own plant, the model's parameters, the spec's RK4 step): the one-period map's Jacobian Φ, its
  eigenvalues μ. ρ = max |μ| > 1 is a mode growing by ln ρ / T per second at |arg μ| / (2πT) Hz, with the
  continuous motion stable: the hold over the period destabilises it (a faster control rate or lower gains).

Both by central differences of the generated functions (DIFFERENCE_STEP); the controller without limits (the law
itself, not where a limit holds it). Used when a run diverges (acroboter.sim.simulation.simulate) and by the fuzz
over generated cranes (acroboter.studies.generated_cranes), which found both: crane_219's zero dynamics grow at
8.8 1/s, crane_2 and crane_206 hold a 4-4.6 Hz mode that the 50 Hz loop grows at 0.43-0.56 1/s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

DIFFERENCE_STEP = 1e-6  # of the tangent coordinates (m, m/s; natural coordinates are lengths and unit vectors)
# Growth rates (1/s) above which a mode counts as unstable: far above the differences' round-off (~1e-4 1/s) and
# below any divergence a run of the path's length would show (e^(0.01 * 55) = 1.7).
UNSTABLE_GROWTH = 0.01


@dataclass(frozen=True)
class LoopStability:
    """The two linearisations at time `t`: growth rates (1/s, > 0 grows) and frequencies (Hz) of their least stable
    modes. `exact`: the method inverts the dynamics exactly (MLM, the penalty methods' projected recovery), so the
    zero dynamics are its continuous loop's; for the other recoveries only the sampled loop is theirs
    (zero_dynamics_growth is then the crane's under MLM, nan where MLM cannot run)."""

    t: float
    zero_dynamics_growth: float
    zero_dynamics_hz: float
    sampled_growth: float
    sampled_hz: float
    rate_hz: float
    exact: bool = True

    @property
    def cause(self) -> str | None:
        """'zero dynamics', 'sampled loop' (an exact method), 'loop' (an inexact recovery) or None (both stable)."""
        if self.exact and self.zero_dynamics_growth > UNSTABLE_GROWTH:
            return "zero dynamics"
        if self.sampled_growth > UNSTABLE_GROWTH:
            return "sampled loop" if self.exact else "loop"
        return None

    def describe(self, horizon: float | None = None) -> str | None:
        """The cause in words, with the fix; None when the loop is stable here, or, given `horizon` (s: when the run
        diverged), when its mode grows less than e-fold over it (then it did not end the run)."""
        cause = self.cause
        growth = self.zero_dynamics_growth if cause == "zero dynamics" else self.sampled_growth
        if cause is None or (horizon is not None and growth * max(horizon - self.t, 0.0) < 1.0):
            return None
        if cause == "zero dynamics":
            return (f"the crane's zero dynamics are unstable at t = {self.t:.2f} s: with the servo-constraints met "
                    f"exactly its internal motion grows there at {self.zero_dynamics_growth:.3g} 1/s"
                    f"{_at(self.zero_dynamics_hz)}, which no exact inverse dynamics (MLM, the projected penalty "
                    "recovery) holds at any control rate; a task with other servo-constraints, another geometry, or "
                    "the penalty methods' inexact 'kinetic' recovery may")
        if cause == "sampled loop":
            return (f"the sampled loop is unstable at t = {self.t:.2f} s: the crane's motion is stable in continuous "
                    f"time, but held over the {1e3 / self.rate_hz:.3g} ms control period a mode{_at(self.sampled_hz)} "
                    f"grows at {self.sampled_growth:.3g} 1/s; a faster control rate (controller.rate_hz) or lower "
                    "gains")
        return (f"the closed loop is unstable at t = {self.t:.2f} s: with this recovery's inexact fit a "
                f"mode{_at(self.sampled_hz)} grows at {self.sampled_growth:.3g} 1/s; the exact 'projected' recovery "
                "or MLM")


def _at(hz: float) -> str:
    return f" at {hz:.3g} Hz" if hz > 1e-3 else " (not oscillating)"


def loop_stability(model, path, gains, method: str, q: np.ndarray, qd: np.ndarray, t: float) -> LoopStability:
    """Both linearisations of module docstring at (q, q̇, t), for `method` ('mlm', 'penalty', 'iterative-N') with
    `gains` on the model's crane. The controllers without limits (the spec's preferred values for spare inputs)."""
    from ..control.controllers import SingularSystemError, make_controller, unbounded
    from .plants import setup_default

    spec = model.spec
    free = unbounded(spec)
    controller = make_controller(method, model, path, gains, limits=free)
    try:
        exact_law = controller if method == "mlm" else make_controller("mlm", model, path, gains, limits=free)
    except SingularSystemError:
        exact_law = None  # MLM cannot run on this crane: its zero dynamics stay unknown
    plant = setup_default(model, path)
    period = 1.0 / spec.controller.rate_hz
    steps = max(1, round(period / spec.simulation.step))
    h = period / steps
    n = model.layout.n
    phi_q = model.term("phi_q", q, qd, *path.signal_arrays(t))
    basis = np.linalg.svd(phi_q)[2][np.linalg.matrix_rank(phi_q):].T  # N: n x d, orthonormal
    d = basis.shape[1]

    def ideal(dq, dqd):
        exact_law.reset()
        exact_law.compute(q + dq, qd + dqd, t)
        return basis.T @ exact_law.qdd

    def one_period(dq, dqd):
        controller.reset()
        u = np.array(controller.compute(q + dq, qd + dqd, t), copy=True)
        x = plant.initial_state(q + dq, qd + dqd)
        for j in range(steps):
            plant.step(x, t + j * h, u, h)
        return np.concatenate([basis.T @ x[:n], basis.T @ x[n : 2 * n]])

    flow = _jacobian(one_period, basis, 2 * d)
    mu = np.linalg.eigvals(flow)
    largest = mu[int(np.argmax(np.abs(mu)))]
    worst = complex(float("nan"), 0.0)
    if exact_law is not None:
        try:
            rows = _jacobian(ideal, basis, d)
            lam = np.linalg.eigvals(np.block([[np.zeros((d, d)), np.eye(d)], [rows]]))
            worst = lam[int(np.argmax(lam.real))]
        except SingularSystemError:
            pass
        exact_law.reset()
    controller.reset()
    return LoopStability(
        t=float(t),
        zero_dynamics_growth=float(worst.real),
        zero_dynamics_hz=float(abs(worst.imag) / (2 * math.pi)),
        sampled_growth=float(math.log(max(abs(largest), 1e-300)) / period),
        sampled_hz=float(abs(np.angle(largest)) / (2 * math.pi * period)),
        rate_hz=float(spec.controller.rate_hz),
        exact=method == "mlm" or gains.recovery == "projected",
    )


def _jacobian(function, basis: np.ndarray, rows: int) -> np.ndarray:
    """d function / d (tangent position, tangent velocity) by central differences: `rows` x 2d."""
    d = basis.shape[1]
    out = np.zeros((rows, 2 * d))
    for i in range(2 * d):
        step = np.zeros(2 * d)
        step[i] = DIFFERENCE_STEP
        dq, dqd = basis @ step[:d], basis @ step[d:]
        out[:, i] = (function(dq, dqd) - function(-dq, -dqd)) / (2 * DIFFERENCE_STEP)
    return out
