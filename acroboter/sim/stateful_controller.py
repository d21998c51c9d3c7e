"""The stateful controller in Python: what the exported C controller's step does (acroboter.codegen.controller_c,
docs/controller.md), statement for statement, so that a run recorded through the library can be replayed through
either and compared:

    ctrl = crane.stateful_controller("penalty", sensing={...}, ki=18.375)
    ctrl.init(result.q[0])
    for t, y in zip(result.time, result.measurements):
        code = ctrl.step(y, t)              # ctrl.u: the command, STEP_CODES[code]: what it means

A step estimates the state from the measurement y (acroboter.sim.sensing.Estimator.update; without an estimator
y = [q; q̇]), advances the integral, computes the command and checks it. It never returns a command outside the
spec's limits or the sanity bound (acroboter.model.settings.command_bounds): a step that cannot produce a
trustworthy one returns the safe command, the last good one (after init, the static command at q0), and a code
that says why.
"""

from __future__ import annotations

import math

import numpy as np

from ..control.controllers import Controller, SingularSystemError
from ..control.path import DesiredPath
from ..model.sensing_layout import PROJECTION_ACCEPT
from ..model.settings import command_bounds
from .sensing import ACCEPTED, LOST, Estimator

__all__ = ["COMMAND_TOLERANCE", "INIT_TOLERANCE", "STEP_CODES", "StatefulController", "check_start"]

# What a step's (or init's) return code means; the C header says the same.
STEP_CODES = {
    0: "ok: the sample was accepted and the command computed from it",
    1: "not initialised: init never succeeded (u is not written)",
    2: "the control step failed (its bounded QP did not converge): u is the safe command",
    3: "the estimate or the command is not finite, or the estimate is off the constraints: u is the safe command",
    4: "the sample was rejected (the estimator's reason says why): the estimate is the prediction, u computed from "
       "it and checked",
    5: "the estimate is lost (more than max_coast_periods samples rejected in a row): u is the safe command until "
       "two consecutive samples agree again",
    6: "the command is outside the limits or the sanity bound: u is the safe command",
    7: "(init) q0 is not a state of the crane: not finite, an axis triple not orthonormal and right-handed, or "
       "the constraints violated by more than INIT_TOLERANCE; nothing changed",
    8: "(init) no command holds the crane at q0 within the limits and the sanity bound; nothing changed",
}
# init's q0: the constraints and each body's axes orthonormal and right-handed to this (m, unitless).
INIT_TOLERANCE = 1e-6
# A command within its bounds to this fraction of max(1, |bound|) (the bounded QP meets a limit to round-off).
COMMAND_TOLERANCE = 1e-9
# A step more than this many periods after the last one does not integrate z over the gap.
MAX_GAP_PERIODS = 10


def check_start(model, q0: np.ndarray, signals: np.ndarray) -> str | None:
    """Why q0 is not a state of the crane at the path's signals (None: it is): finite, every body's (u, v, w)
    orthonormal and right-handed and φ(q0) = 0, each to INIT_TOLERANCE."""
    if not np.isfinite(q0).all():
        return "q0 is not finite"
    for body, offset in model.layout.body_offset.items():
        u, v, w = (q0[offset + 3 * j : offset + 3 * j + 3] for j in (1, 2, 3))
        if not abs(float(np.dot(np.cross(u, v), w)) - 1.0) <= INIT_TOLERANCE:
            return (f"{body}'s axes (u, v, w) are not a right-handed orthonormal triple: (u × v)·w = "
                    f"{float(np.dot(np.cross(u, v), w)):.6g}, expected 1")
    model.q[:] = q0
    model.signals[:] = signals
    phi = model.functions["phi"]
    phi.call()
    worst = float(np.abs(phi.outputs["phi"]).max(initial=0.0))
    if not worst <= INIT_TOLERANCE:
        return f"q0 violates the constraints by {worst:.3g} (m or unitless), more than {INIT_TOLERANCE:g}"
    return None


class StatefulController:
    """The exported controller's init, step, reset and reinit around a Controller and an Estimator (None: y is the
    state [q; q̇]). `u` holds the last command, `code` the last return code, `q`, `qd` the estimate it used."""

    def __init__(self, model, path: DesiredPath, controller: Controller, estimator: Estimator | None = None):
        lay = model.layout
        self.model, self.path, self.controller, self.estimator = model, path, controller, estimator
        self.n, self.l = lay.n, lay.l
        self.period = 1.0 / model.spec.controller.rate_hz
        self.low, self.high = command_bounds(model.spec)
        self._tol_low = COMMAND_TOLERANCE * np.maximum(1.0, np.abs(self.low))
        self._tol_high = COMMAND_TOLERANCE * np.maximum(1.0, np.abs(self.high))
        self.u, self.u_safe, self.u_static = np.zeros(self.l), np.zeros(self.l), np.zeros(self.l)
        self.q0 = np.zeros(self.n)
        self.q, self.qd = np.zeros(self.n), np.zeros(self.n)
        self._z_kept, self._sigma_kept = np.zeros(lay.k), np.zeros(lay.k)  # the integral before a step
        self.initialised, self.code, self.problem = False, 1, None
        self.strict = False  # True: a singular system raises (acroboter.sim.simulation's divergence) instead of 3

    def signals(self, t: float) -> np.ndarray:
        """The path's [s; ṡ; s̈] at t: what the C controller's caller passes with each step."""
        return np.array(self.path.flat(t))

    def within(self, u: np.ndarray) -> bool:
        """u finite and inside the limits and the sanity bound."""
        return bool(np.isfinite(u).all() and (u >= self.low - self._tol_low).all()
                    and (u <= self.high + self._tol_high).all())

    def init(self, q0: np.ndarray, t0: float = 0.0) -> int:
        """The crane at rest at q0 at time t0: checked (code 7, nothing changed), its static command (the core step at
        rest with the path held at t0) the first safe command (code 8 if there is none), then reset."""
        q0 = np.asarray(q0, dtype=float)
        if q0.shape != (self.n,):
            raise ValueError(f"q0: expected {self.n} coordinates (crane.coordinates' order), found shape {q0.shape}")
        signals = self.signals(t0)
        self.problem = check_start(self.model, q0, signals)
        if self.problem is not None:
            return 7
        n_s = self.model.layout.n_signals
        at_rest = np.concatenate([signals[:n_s], np.zeros(2 * n_s)])
        ctrl = self.controller
        try:
            u = ctrl.compute(q0, np.zeros(self.n), t0, at_rest).copy()
        except SingularSystemError as err:
            self.problem = str(err)
            u = np.full(self.l, np.nan)
        ctrl.reset()
        if not self.within(u):
            self.problem = self.problem or f"the static command at q0 {np.round(u, 6).tolist()} is outside the bounds"
            return 8
        self.q0[:], self.u_static[:] = q0, u
        self.initialised = True
        return self.reset()

    def reset(self) -> int:
        """A new run from rest at init's q0: z = 0, the estimator restarted, the safe command the static one."""
        if not self.initialised:
            return 1
        self.controller.reset()
        if self.estimator is not None:
            self.estimator.reset(self.q0)
        self.u_safe[:] = self.u_static
        self.q[:], self.qd[:] = self.q0, 0.0
        self.code = 0
        return 0

    def reinit(self) -> int:
        """Restart the estimator from the next sample, mid-motion (Estimator.reinit); z and the safe command kept."""
        if not self.initialised:
            return 1
        if self.estimator is not None:
            self.estimator.reinit()
        return 0

    def step(self, y: np.ndarray, t: float, signals: np.ndarray | None = None) -> int:
        """One control period: y the measurement (delay periods old), t the time; the command in `u`; the code."""
        if not self.initialised:
            self.code = 1
            return 1
        y = np.asarray(y, dtype=float)
        size = self.estimator.index.size if self.estimator is not None else 2 * self.n
        if y.shape != (size,):
            raise ValueError(f"y: expected {size} measurements (result.measurement_names' order), found shape "
                             f"{y.shape}")
        inner = getattr(self.controller, "reference", self.controller)  # the fast path's wrapper: its reference's z
        z_kept, sigma_kept = self._z_kept, self._sigma_kept  # restored after a failed step (preallocated)
        z_kept[:], sigma_kept[:], t_kept = inner.integral, inner._sigma_last, inner._t_last
        self.code = self._step(y, t, signals)
        if self.code in (0, 4):
            self.u_safe[:] = self.u
        else:
            self.u[:] = self.u_safe
            inner.integral[:], inner._sigma_last[:], inner._t_last = z_kept, sigma_kept, t_kept
            inner.hold_integral()  # nor over the period that ends at the next step
        return self.code

    def _step(self, y: np.ndarray, t: float, signals) -> int:
        est, ctrl, n = self.estimator, self.controller, self.n
        if not math.isfinite(t) or (signals is not None and not np.isfinite(signals).all()):
            return 3  # the caller's time and path: a step that cannot trust them changes nothing
        if est is None:
            self.q[:], self.qd[:] = y[:n], y[n : 2 * n]
            status = ACCEPTED
        else:
            status = est.update(y, t)
            self.q[:], self.qd[:] = est.q, est.qd
            if status == LOST:
                ctrl.hold_integral()  # nor over the period that ends at the next step
                est.applied(None)
                return 5
            if not (est.last_violation <= PROJECTION_ACCEPT):
                est.applied(None)
                return 3
        if not (np.isfinite(self.q).all() and np.isfinite(self.qd).all()):
            return 3
        if status != ACCEPTED:
            ctrl.hold_integral()
        last = getattr(ctrl, "reference", ctrl)._t_last
        if last is not None and t - last > MAX_GAP_PERIODS * self.period:
            ctrl.hold_integral()  # a gap in the calls is not integrated over
        try:
            u = ctrl.compute(self.q, self.qd, t, signals)
        except SingularSystemError:
            if est is not None:
                est.applied(None)
            if self.strict:
                raise
            return 3
        good = self.within(u)
        if est is not None:
            est.applied(ctrl.qdd if good else None)
        if not good:
            return 3 if not np.isfinite(u).all() else 6
        self.u[:] = u
        return 0 if status == ACCEPTED else 4
