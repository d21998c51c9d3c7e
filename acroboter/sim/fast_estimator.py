"""The estimator of a run (`make_estimator`), and the fast path's (docs/fast-path.md): the sensor (noise,
quantisation, the delay line) as acroboter.sim.sensing.Estimator, the estimator itself one compiled call
(acroboter.codegen.estimator_c: the same statements, the same sample checks, its state a C struct whose fields
`reset`, `applied` and the records read)."""

from __future__ import annotations

import numpy as np

from ..control.path import DesiredPath
from ..model.schema import Sensing
from .sensing import ACCEPTED, COASTING, LOST, Estimator, is_ideal

__all__ = ["FastEstimator", "make_estimator"]


class FastEstimator(Estimator):
    """Estimator whose `update` is the compiled one (`binding`: acroboter.runtime.fast_library.FastEstimatorBinding);
    `applied` is Estimator's, into the struct's ring of accelerations (the C's applied, statement for statement)."""

    def __init__(self, model, path: DesiredPath, sensing: Sensing, binding):
        super().__init__(model, path, sensing)
        b, n, d = binding, model.layout.n, self.delay
        self.binding = b
        self._qm, self._qdm, self._xf, self._vf = b.view("qm"), b.view("qdm"), b.view("xf"), b.view("vf")
        self.q, self.qd = b.view("q"), b.view("qd")
        self._pred, self._q_good = b.view("pred"), b.view("q_good")
        self._acc = b.view("acc").reshape(d + 1, n)
        self._scalars, self._ints = b.view("scalars"), b.view("ints")  # [violation, jump]; [started .. distrust]
        ns = model.layout.n_signals
        self._sig_m, self._sig_t = np.zeros(3 * ns), np.zeros(3 * ns)
        self._sig_at = (self._sig_m.ctypes.data, self._sig_t.ctypes.data)
        self._flat, self._carry = path.flat, bool(d and self.predict)
        self._at, self._update = b.at, b.update

    def reset(self, q0: np.ndarray) -> None:
        self._reset_sensor(q0)
        self._k = 0  # Estimator.applied's slot (the struct's k, counted here too)
        q0 = np.ascontiguousarray(q0, dtype=float)
        self.binding.start(self._at, q0.ctypes.data)
        self._read()

    def reinit(self) -> None:
        self.binding.reinit(self._at)
        self._read()

    def update(self, y: np.ndarray, t: float) -> int:
        d, T = self.delay, self.period
        self._sig_m[:] = self._flat(max(t - d * T, 0.0))
        if self._carry:
            self._sig_t[:] = self._flat(t)
        if not (y.dtype == np.float64 and y.flags.c_contiguous):
            y = np.ascontiguousarray(y, dtype=float)
        self._k += 1
        if self._update(self._at, y.ctypes.data, *self._sig_at) < 0:  # a generated function failed
            self.q[:] = np.nan
        self._read()
        return self.status

    def _read(self) -> None:
        self.last_violation, self.jump = self._scalars.tolist()
        _, self.coasted, _, status, self.reason, self.rejected, self.distrust = self._ints.tolist()
        self.status = (ACCEPTED, COASTING, LOST)[status]


def make_estimator(model, path: DesiredPath, sensing: Sensing | None, fast: bool = False) -> Estimator | None:
    """The estimator of a run, or None where the controller reads the plant's state (no sensing, or an
    ideal one: every coordinate, no noise, no quantisation, no delay). fast=True: the compiled estimator
    (FastEstimator), generated and compiled on first use; the Python one where it cannot be built."""
    if sensing is None or is_ideal(model.spec, model.layout, sensing):
        return None
    if fast:
        from ..runtime.fast_library import FastPathUnavailable, load_fast_estimator

        try:
            return FastEstimator(model, path, sensing, load_fast_estimator(model, sensing))
        except FastPathUnavailable:
            pass
    return Estimator(model, path, sensing)
