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
    """Estimator whose `update` is the compiled one (`binding`: acroboter.runtime.fast_library.FastEstimatorBinding)."""

    def __init__(self, model, path: DesiredPath, sensing: Sensing, binding):
        super().__init__(model, path, sensing)
        b, n, d = binding, model.layout.n, self.delay
        self.binding = b
        self._qm, self._qdm, self._xf, self._vf = b.view("qm"), b.view("qdm"), b.view("xf"), b.view("vf")
        self.q, self.qd = b.view("q"), b.view("qd")
        self._pred, self._q_good = b.view("pred"), b.view("q_good")
        self._acc = b.view("acc").reshape(d + 1, n)
        self._fields = {f: b.view(f) for f in ("violation", "jump", "coasted", "status", "reason", "rejected")}
        ns = model.layout.n_signals
        self._sig_m, self._sig_t = np.zeros(3 * ns), np.zeros(3 * ns)
        self._sig_at = (self._sig_m.ctypes.data, self._sig_t.ctypes.data)
        self._flat, self._carry = path.flat, bool(d and self.predict)

    def reset(self, q0: np.ndarray) -> None:
        self._reset_sensor(q0)
        q0 = np.ascontiguousarray(q0, dtype=float)
        self.binding.start(q0.ctypes.data)
        self._read()

    def reinit(self) -> None:
        self.binding.reinit()
        self._read()

    def applied(self, qdd: np.ndarray | None) -> None:
        self.binding.applied(None if qdd is None else np.ascontiguousarray(qdd, dtype=float).ctypes.data)

    def update(self, y: np.ndarray, t: float) -> int:
        d, T = self.delay, self.period
        self._sig_m[:] = self._flat(max(t - d * T, 0.0))
        if self._carry:
            self._sig_t[:] = self._flat(t)
        y = np.ascontiguousarray(y, dtype=float)
        if self.binding.update(y.ctypes.data, *self._sig_at) < 0:  # a generated function failed
            self.q[:] = np.nan
        self._read()
        return self.status

    def _read(self) -> None:
        f = self._fields
        self.last_violation, self.jump = float(f["violation"][0]), float(f["jump"][0])
        self.coasted, self.reason, self.rejected = int(f["coasted"][0]), int(f["reason"][0]), int(f["rejected"][0])
        self.status = (ACCEPTED, COASTING, LOST)[int(f["status"][0])]


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
