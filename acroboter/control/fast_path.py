"""The fast path of the Python controllers (issue 23 item 2): one compiled function per control step.

FastController wraps a reference controller (acroboter.control.controllers: the per-term path, kept as it is and
what the tests compare against) and shares its buffers and state. A step:

1. q, q̇ and the path's signals into the model's input buffers, the reference's gains (and z) into p, exactly as
   Controller._load; with integral action the reference's own Controller._integrate advances z (one generated
   call more: σ at the state), so z, its reset and the anti-windup are the reference's;
2. one ctypes call of the fast step (acroboter.codegen.fast_step, compiled on first use by
   acroboter.runtime.fast_library): u, the commanded q̈, whether u is within the limits, MLM's reciprocal
   condition number;
3. u is taken when it is within the limits and, for MLM, the estimate of the Schur system's reciprocal 1-norm
   condition number is at least FAST_RCOND_MARGIN × MLM_RCOND_LIMIT (1e-10); otherwise (a limit is in the way, a
   NaN, a nearly singular MLM system) the step is the reference's _compute at the same buffers: the bounded
   distribution (DAQP, limit_state, saturation) and the SingularSystemError are then exactly the reference's.
   The estimate (acroboter.codegen.step_methods.mlm_step: A⁻¹ applied to two fixed probe vectors with the same
   QR as y, two back-substitutions more) is never below the true reciprocal condition number, like gecon's, and
   within about the system's size above it; the margin of 1000 covers that, so a step that gecon would refuse
   reaches gecon. (The exact number, from the whole inverse, cost more than the rest of the step.)

Identical by construction: integral action (the reference's z and anti-windup), limits (the reference's
distribution wherever one binds; within them both take the unbounded u, limit_state 0, not saturated). What
differs is the operation order of the unbounded u: MLM agrees to ~1e-13 relative; the penalty methods solve for
the multipliers directly (the exported step's 'multipliers' formulation, more accurate: u to ~1e-14 of a 40-digit
reference where the reference's A form reaches ~1e-10; acroboter.codegen.export_step, tests/test_export_step.py).
"""

from __future__ import annotations

import numpy as np

from ..model.settings import FAST_RCOND_MARGIN, MLM_RCOND_LIMIT
from ..runtime.fast_library import FastPathUnavailable, load_fast_step
from .path import DesiredPath

__all__ = ["FastController", "make_fast"]


def make_fast(reference, method: str):
    """The fast path around `reference`, or `reference` itself with its `fast_refusal` set where it cannot have one."""
    if getattr(reference, "underactuation", None) is not None:  # docs/saturation.md
        reference.fast_refusal = (f"{reference.name}: the fast path is not available (saturation as underactuation "
                                  "keeps a state, the held inputs and the dwell, that the compiled step does not "
                                  "have); the reference path runs")
        return reference
    try:
        binding = load_fast_step(reference.model, method, reference.gains)
    except FastPathUnavailable as err:
        reference.fast_refusal = f"{reference.name}: the fast path is not available ({err}); the reference path runs"
        return reference
    return FastController(reference, binding)


class FastController:
    """A reference controller's step through one compiled function (see the module docstring).

    Everything not defined here (integral, ki, gains, limits, n, ...) is the reference's."""

    fast_refusal = None

    def __init__(self, reference, binding):  # reference: an acroboter.control.controllers.Controller
        self.reference, self.binding = reference, binding
        self.name = reference.name
        limits, l = reference.limits, reference.l
        binding.limits[:l], binding.limits[l : 2 * l], binding.limits[2 * l :] = (limits.lower, limits.upper,
                                                                                  limits.preferred)
        reference._integrate_in_load = False  # z advances here, before the fast call (and the reference's fallback)
        self._call, self._u, self._within, self._rcond = binding.call, binding.u, binding.within, binding.rcond
        self._fast = False  # whether the last step was the compiled one
        self._rcond_limit = FAST_RCOND_MARGIN * MLM_RCOND_LIMIT
        self._t = 0.0
        self.fast_steps = self.reference_steps = 0
        # the reference's buffers and settings, looked up once (the step is a few microseconds)
        self._q, self._qd, self._signals, self._p = reference._q, reference._qd, reference._signals, reference._p
        self._model, self._flat, self._limits = reference.model, reference.path.flat, reference.limits
        self._ki = reference.ki != 0.0
        # The spec's path (not a user trajectory): its signals are evaluated in the C, in the same call as the step
        table = path_table(reference.path)
        self._path_table = table  # kept alive: the C reads it
        self._run = self._c_flat = None
        if table is not None:
            self._run = binding.path_call(table, self._signals)
            self._c_flat = binding.path_flat(table, self._signals)

    def __getattr__(self, name: str):
        return getattr(self.reference, name)

    def reset(self) -> None:
        self.reference.reset()

    @property
    def limit_state(self):
        return self.reference.limit_state

    def saturation(self) -> bool:
        return self.reference.saturation()

    def compute(self, q, qd, t: float, signals=None):
        """u at (q, q̇, t), as Controller.compute (a view of an internal buffer)."""
        ref = self.reference
        ref._saturated = None
        self._q[:] = q
        self._qd[:] = qd
        if self._model.parameters_owner is not ref:
            self._p[:] = ref._params
            self._model.parameters_owner = ref
        self._t = t
        if signals is None and self._run is not None:  # the path's signals in the C
            if self._ki:
                self._c_flat(t)
                ref._integrate(t)
                self._call()
            else:
                self._run(t)  # one foreign call: the signals at t, then the step
        else:
            self._signals[:] = self._flat(t) if signals is None else signals
            if self._ki:
                ref._integrate(t)
            self._call()
        if self._within[0] == 1.0 and self._rcond[0] >= self._rcond_limit:
            limits = self._limits
            if limits.bounded_step:  # the last step was bounded: nothing is on a limit now
                limits.limit_state[:] = 0
                limits.bounded_step = False
            self._fast = True
            self.fast_steps += 1
            u = self._u
        else:  # a limit in the way, a NaN or a nearly singular MLM system: the reference's step at these buffers
            self._fast = False
            self.reference_steps += 1
            u = ref._compute(self._q, self._qd, t, self._signals)
        if self._ki:
            ref._hold = ref.anti_windup and ref.saturation()
        return u

    def _reference_step(self) -> None:
        """The reference's step at the state still in the buffers (z is not advanced again), for its internals."""
        ref = self.reference
        if self._fast:
            ref._compute(ref._q, ref._qd, self._t, ref._signals)
            self._fast = False

    @property
    def qdd(self):
        """The last step's commanded acceleration q̈."""
        if self._fast and self.binding.has_qdd:
            return self.binding.qdd
        self._reference_step()
        return self.reference.qdd

    @property
    def multipliers(self):
        self._reference_step()
        return self.reference.multipliers


def path_table(path) -> np.ndarray | None:
    """The numbers of the spec's path (acroboter.control.path.DesiredPath) for the C's flat (codegen.fast_step
    path_source); None for any other path (a user trajectory: its signals stay Python's)."""
    if type(path) is not DesiredPath:
        return None
    follow = [v for entry in path._follow for v in entry]
    head = [len(path._t0), path.n_signals, path.layout.path_signal, len(path._follow), path.duration,
            path.start_yaw, path.yaw_turn]
    return np.array([*head, *path._t0, *path._dur, *(v for o in path._origin for v in o),
                     *(v for d in path._delta for v in d), *path._template, *follow], dtype=float)
