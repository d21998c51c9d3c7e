"""Measurement instead of state: the sensors' model and the estimator the controller reads (docs/sensing.md).

A `[sensing]` section (or `Crane.simulate(sensing=...)`, `acroboter run --sensing-*`) names groups of
measured natural coordinates, each with Gaussian noise (standard deviation, m or unitless) and a
quantisation step, a delay in whole control periods and a seed. Each control period the sensor
samples the plant's q (only the measured coordinates), and the estimator turns the measurement of
`delay_periods` periods ago into what the controller reads:

- positions: the measured coordinates, the unmeasured ones predicted from the last estimate, then
  projected onto φ(q, t) = 0 by Gauss–Newton with the minimal-norm correction
  Δq = −φ_qᵀ (φ_q φ_qᵀ)⁻¹ φ over the independent rows (the generated `phi`, `phi_q`);
- velocities: a critically damped α-β filter of the projected positions (both poles at
  exp(−T/τ), τ = velocity_filter_s) whose prediction uses the acceleration the controller
  commanded over the period (`applied`), made consistent with φ_q q̇ = −φ_t by the minimal-norm
  correction −φ_qᵀ (φ_q φ_qᵀ)⁻¹ φ̇ (the generated `phi_dot` at the filtered rates);
- with a delay (and predict_delay, the default): the estimate carried forward over the delay with
  the accelerations commanded since the measurement, projected again at the control instant.

Well posed when the unmeasured coordinates are determined by the constraints: the columns of
φ_q that belong to them have full column rank (checked at the spec's nominal configuration;
`check_measurable`). An ideal sensing (every coordinate measured, no noise, no quantisation, no
delay) is the plant's state itself: `is_ideal`, and the closed loop then runs without the estimator.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np
from pydantic import ValidationError
from scipy.linalg.lapack import dpotrf, dpotrs

from ..control.path import DesiredPath
from ..model.layout import nominal_coordinates
from ..model.schema import Sensing, SpecError, _Strict
from ..model.sensing_layout import PROJECTION_TOLERANCE, is_ideal, measured_indices
from ..model.spec_checks import sensing_problems
from ..model.spec_errors import format_pydantic
from .cable_events import SimulationError

__all__ = ["PROJECTION_TOLERANCE", "Estimator", "FastEstimator", "SensingError", "check_measurable", "describe",
           "is_ideal", "make_estimator", "measured_indices", "resolve"]

# A column-rank deficit of φ_q on the unmeasured coordinates: singular values below this × the largest.
RANK_TOLERANCE = 1e-9
OVERRIDE_KEYS = ("noise", "quantization", *Sensing.model_fields)  # groups, delay_periods, seed, ...
# An estimate further than this from the plant's state (m; unitless for the axes) is not the crane's: a failure
# that follows it is the measurements' doing, and its message says so (`Estimator.trouble`).
ESTIMATE_LIMIT = 0.5


class SensingError(SimulationError):
    """A run that cannot start because the controller's estimate of the state, made from the measurements, is
    nowhere near the plant's state: the sensing's noise, quantisation or delay is the cause (exit 3)."""


def describe(sensing: Sensing) -> str:
    """The sensing's settings that make an estimate differ from the state: 'positions noise 1e+06, delay 2
    periods' (or 'no noise, quantisation or delay')."""
    parts = [f"{g.name} noise {g.noise:g}" + (f" quantisation {g.quantization:g}" if g.quantization else "")
             for g in sensing.groups if g.noise or g.quantization]
    if sensing.delay_periods:
        parts.append(f"delay {sensing.delay_periods} control period(s)")
    return ", ".join(parts) or "no noise, quantisation or delay"


class _SensingOnly(_Strict):
    sensing: Sensing


def default_groups(spec) -> list[dict]:
    """Every coordinate measured, exactly: 'positions' (each body's r), 'axes' (u, v, w), 'lengths'
    (winch cables); the groups an override refers to when the spec has no [sensing] section."""
    groups = [{"name": "positions", "coordinates": [f"{b.name}.r" for b in spec.bodies]},
              {"name": "axes", "coordinates": [f"{b.name}.{a}" for b in spec.bodies for a in "uvw"]}]
    winches = [f"{c.name}.length" for c in spec.cables if c.winch is not None]
    if winches:
        groups.append({"name": "lengths", "coordinates": winches})
    return groups


def resolve(spec, sensing=None, source: str = "sensing") -> Sensing | None:
    """The sensing a run uses: None -> the spec's section (None without one); False -> none; a
    Sensing; or a mapping of overrides onto the spec's section (or the default groups): `groups`
    (replaces them), `noise` and `quantization` ({group: value}), `delay_periods`, `seed`,
    `velocity_filter_s`, `projection_iterations`. Problems are a SpecError naming the field."""
    if sensing is None:
        return spec.sensing
    if sensing is False:
        return None
    if isinstance(sensing, Sensing):
        chosen = sensing
    elif isinstance(sensing, Mapping):
        unknown = sorted(set(sensing) - set(OVERRIDE_KEYS))
        if unknown:
            raise SpecError(source, [(f"sensing.{unknown[0]}", f"expected one of the known keys "
                                      f"({', '.join(OVERRIDE_KEYS)}), found unknown key '{unknown[0]}'")])
        base = (spec.sensing.model_dump(mode="json") if spec.sensing is not None
                else {"groups": default_groups(spec)})
        data = {**base, **{k: v for k, v in sensing.items() if k not in ("noise", "quantization")}}
        data["groups"] = [dict(g) if isinstance(g, Mapping) else g for g in data["groups"]]
        named = {g.get("name"): g for g in data["groups"] if isinstance(g, dict)}
        for key in ("noise", "quantization"):
            values = sensing.get(key) or {}
            if not isinstance(values, Mapping):
                raise SpecError(source, [(f"sensing.{key}", f"expected a table {{group: value}}, found {values!r}")])
            for group, value in values.items():
                if group not in named:
                    raise SpecError(source, [(f"sensing.{key}.{group}", f"expected one of the groups "
                                              f"{', '.join(map(str, named))}, found '{group}'")])
                named[group][key] = value
        try:
            chosen = _SensingOnly.model_validate({"sensing": data}).sensing
        except ValidationError as err:
            raise SpecError(source, format_pydantic(err, {"sensing": data})) from None
    else:
        raise TypeError(f"sensing: expected None, False, a mapping or a Sensing, found {type(sensing).__name__}")
    problems = sensing_problems(spec, chosen)
    if problems:
        raise SpecError(source, problems)
    return chosen


def _rows(model) -> np.ndarray:
    return np.array(model.manifest["layout"]["independent_constraint_rows"], dtype=np.intp)


def check_measurable(model, sensing: Sensing, q: np.ndarray | None = None, source: str = "sensing") -> None:
    """SpecError unless the constraints determine the unmeasured coordinates (locally, at q: default the
    spec's nominal configuration): φ_q restricted to their columns must have full column rank."""
    spec, lay = model.spec, model.layout
    index, _, _ = measured_indices(spec, lay, sensing)
    unmeasured = np.setdiff1d(np.arange(lay.n), index)
    if not unmeasured.size:
        return
    model.q[:] = nominal_coordinates(spec, lay) if q is None else q
    model.signals[:] = 0.0
    for anchor in spec.anchors:  # moving anchors at their spec positions (φ_q's cable rows see them)
        if anchor.name in lay.anchor_signal:
            j = lay.anchor_signal[anchor.name]
            model.signals[j : j + 3] = anchor.position
    phi_q = model.functions["phi_q"]
    phi_q.call()
    block = phi_q.outputs["phi_q"][_rows(model)][:, unmeasured]
    _, sv, vt = np.linalg.svd(block)
    rank = int(np.count_nonzero(sv > RANK_TOLERANCE * max(sv.max(initial=0.0), 1.0)))
    if rank == unmeasured.size:
        return
    free = vt[rank:]  # motions of the unmeasured coordinates that no constraint sees
    loose = [lay.coordinates[unmeasured[j]] for j in range(unmeasured.size) if np.abs(free[:, j]).max() > 1e-6]
    raise SpecError(source, [("sensing", (
        f"expected the measured coordinates to determine the others through the constraints, found "
        f"{unmeasured.size} unmeasured coordinates with only {rank} independent constraints on them "
        f"({unmeasured.size - rank} free motion(s)); not determined: {', '.join(loose)}. Measure more: each "
        "body's r and two of its axes (the third follows from the orthonormality rows) always suffice, a "
        "winch cable's length follows from its cable row"))])


class Estimator:
    """The sensor and the estimator of one run: `estimate(q_plant, t)` -> (q̂, q̇̂) for the controller.

    Preallocated; per call: one normal draw, the Gauss–Newton steps (`phi`, `phi_q` through the
    compiled bindings, a Cholesky factorisation of φ_q φ_qᵀ by LAPACK), the α-β update and one
    `phi_dot` for the velocity correction."""

    def __init__(self, model, path: DesiredPath, sensing: Sensing):
        spec, lay = model.spec, model.layout
        self.model, self.path, self.sensing = model, path, sensing
        self.index, self.noise, self.step = measured_indices(spec, lay, sensing)
        self.quantized = self.step > 0
        self._noisy, self._any_quantized = bool(self.noise.any()), bool(self.quantized.any())
        self._steps = self.step[self.quantized]
        self._eps = np.zeros(self.index.size)
        self.period = 1.0 / spec.controller.rate_hz
        self.delay = sensing.delay_periods
        self.iterations = sensing.projection_iterations
        pole = math.exp(-self.period / sensing.velocity_filter_s)
        self.alpha, self.beta = 1.0 - pole * pole, (1.0 - pole) ** 2  # both error poles at `pole`
        self.rows = _rows(model)
        self._every_row = np.array_equal(self.rows, np.arange(lay.m))
        self._phi, self._phi_q, self._phi_dot = (model.functions[f] for f in ("phi", "phi_q", "phi_dot"))
        self._phi_out = self._phi.outputs["phi"]
        self._phi_q_out = self._phi_q.outputs["phi_q"]
        self._phi_dot_out = self._phi_dot.outputs["phi_dot"]
        n, nm = lay.n, self.index.size
        self._ring = np.zeros((self.delay + 1, nm))
        self._acc = np.zeros((self.delay + 1, n))  # commanded q̈ of the last delay + 1 instants (applied)
        self.q = np.zeros(n)  # the estimate handed to the controller (overwritten every call)
        self.qd = np.zeros(n)
        self._qm, self._qdm = np.zeros(n), np.zeros(n)  # the estimate at the measurement's time
        self.predict = sensing.predict_delay
        self._xf, self._vf, self._r = np.zeros(n), np.zeros(n), np.zeros(n)
        m = self.rows.size
        self._a, self._g, self._b, self._x = np.zeros((m, n)), np.zeros((m, m)), np.zeros(m), np.zeros(n)
        self.unmeasured = np.setdiff1d(np.arange(n), self.index)
        nu = self.unmeasured.size
        self._au, self._h, self._xu = np.zeros((m, nu)), np.zeros((nu, nu)), np.zeros(nu)
        self._k = 0
        self._started = False
        self.rng = np.random.default_rng(sensing.seed)
        self.last_violation = 0.0  # max |φ| after the last projection

    # --- the sensor ---------------------------------------------------------------------------------
    def _sample(self, q_plant: np.ndarray, out: np.ndarray) -> None:
        np.take(q_plant, self.index, out=out)
        if self._noisy:
            eps = self._eps
            self.rng.standard_normal(out=eps)
            eps *= self.noise
            out += eps
        if self._any_quantized:
            s = self._steps
            out[self.quantized] = s * np.round(out[self.quantized] / s)

    def reset(self, q0: np.ndarray) -> None:
        """A new run from rest at q0: the delay line holds measurements of q0 (the crane at rest
        before the start), the filter starts at the projected q0 with zero rates."""
        self.rng = np.random.default_rng(self.sensing.seed)
        for slot in self._ring:
            self._sample(q0, slot)
        self.q[:] = q0
        self.qd[:] = 0.0
        self._qm[:] = q0
        self._qdm[:] = 0.0
        self._acc[:] = 0.0
        self._k = 0
        self._started = False

    # --- the estimator -------------------------------------------------------------------------------
    def project(self, q: np.ndarray, signals) -> np.ndarray:
        """q moved onto φ(q, t) = 0 in place; returns q. First the unmeasured coordinates alone, by
        Gauss–Newton on the overdetermined φ(q_measured, q_unmeasured) = 0 (least squares: they are
        what the constraints make of the measurement, whatever their prior), then every coordinate by
        Gauss–Newton with minimal-norm steps (the measurement's noise normal to the manifold removed)."""
        rows = self.rows
        model = self.model
        model.signals[:] = signals
        if self.unmeasured.size:
            for _ in range(self.iterations):
                model.q[:] = q
                self._phi.call()
                self._phi_q.call()
                q[self.unmeasured] -= self._least_squares(self._phi_out)
        for it in range(self.iterations + 1):
            model.q[:] = q
            self._phi.call()
            self.last_violation = float(np.abs(self._phi_out[rows]).max())
            if self.last_violation <= PROJECTION_TOLERANCE or it == self.iterations:
                break
            self._phi_q.call()
            q -= self._min_norm(self._phi_out)
        return q

    def _least_squares(self, b_full: np.ndarray) -> np.ndarray:
        """(a_Uᵀ a_U)⁻¹ a_Uᵀ b over the unmeasured columns a_U of φ_q (full column rank: check_measurable)."""
        a, au, h, b, x = self._a, self._au, self._h, self._b, self._xu
        np.take(self._phi_q_out, self.rows, axis=0, out=a)
        np.take(a, self.unmeasured, axis=1, out=au)
        np.take(b_full, self.rows, out=b)
        np.dot(au.T, au, out=h)
        factor, info = dpotrf(h.T, lower=0, clean=0, overwrite_a=1)
        if info != 0:
            x[:] = np.nan
            return x
        np.dot(au.T, b, out=x)
        y, _ = dpotrs(factor, x, lower=0, overwrite_b=1)
        x[:] = y
        return x

    def _min_norm(self, b_full: np.ndarray) -> np.ndarray:
        """aᵀ (a aᵀ)⁻¹ b with a = φ_q and b over the independent rows: the smallest x with a x = b."""
        g, x = self._g, self._x
        if self._every_row:  # no dependent rows: φ_q and φ as they are
            a, b = self._phi_q_out, self._b
            b[:] = b_full
        else:
            a, b = self._a, self._b
            np.take(self._phi_q_out, self.rows, axis=0, out=a)
            np.take(b_full, self.rows, out=b)
        np.dot(a, a.T, out=g)
        factor, info = dpotrf(g.T, lower=0, clean=0, overwrite_a=1)  # g is symmetric: g.T is its Fortran view
        if info != 0:
            x[:] = np.nan  # φ_q lost rank: a non-finite estimate stops the run with a message
            return x
        y, info = dpotrs(factor, b, lower=0, overwrite_b=1)
        np.dot(a.T, y, out=x)
        return x

    def applied(self, qdd: np.ndarray) -> None:
        """The acceleration the controller commanded at this instant (its model's q̈): the filter's
        prediction over the period that follows this instant's measurement."""
        self._acc[(self._k - 1) % (self.delay + 1)] = qdd

    def estimate(self, q_plant: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Sample the plant at t; the estimate from the measurement of delay_periods ago, carried
        forward to t with the commanded accelerations (predict_delay) or as it is."""
        d, T = self.delay, self.period
        slot = self._k % (d + 1)
        acc = self._acc[slot]  # q̈ commanded at instant k − d − 1: over the period that ends at the measurement
        self._sample(q_plant, self._ring[slot])
        self._k += 1
        measured = self._ring[self._k % (d + 1)] if d else self._ring[slot]  # the oldest: taken d periods ago
        q, qd = self._qm, self._qdm  # the estimate at the measurement's time
        if self._started:  # unmeasured coordinates: predicted from the last estimate
            q += T * qd + (0.5 * T * T) * acc
        q[self.index] = measured
        self.project(q, self.path.flat(max(t - d * T, 0.0)))
        # velocities: α-β filter of the projected positions, then onto φ_q q̇ = −φ_t
        if not self._started:
            self._xf[:] = q
            self._vf[:] = 0.0
            self._started = True
        else:
            xf, vf, r = self._xf, self._vf, self._r
            xf += T * vf + (0.5 * T * T) * acc  # prediction with the commanded acceleration
            vf += T * acc
            np.subtract(q, xf, out=r)
            xf += self.alpha * r
            vf += (self.beta / T) * r
        qd[:] = self._vf
        self._consistent_rates(qd)
        if not (d and self.predict):
            self.q[:], self.qd[:] = q, qd
            return self.q, self.qd
        # carried forward over the d periods since the measurement (the accelerations commanded then)
        out_q, out_qd = self.q, self.qd
        out_q[:], out_qd[:] = q, qd
        for j in range(1, d + 1):
            a = self._acc[(slot + j) % (d + 1)]  # instants k − d … k − 1
            out_q += T * out_qd + (0.5 * T * T) * a
            out_qd += T * a
        self.project(out_q, self.path.flat(t))
        self._consistent_rates(out_qd)
        return out_q, out_qd

    def trouble(self, q_plant: np.ndarray) -> str | None:
        """Why the last estimate handed to the controller cannot stand for the plant's state `q_plant` (the state
        it was made from), naming the sensing; None when it is within ESTIMATE_LIMIT (or the state itself is not
        finite: then nothing can be said)."""
        if not np.isfinite(q_plant).all():
            return None
        finite = bool(np.isfinite(self.q).all())
        off = float(np.abs(self.q - q_plant).max()) if finite else math.inf
        if off <= ESTIMATE_LIMIT:
            return None
        how = f"{off:.3g} away from the plant's state (m; unitless for the axes)" if finite else "not finite"
        return (f"the controller's estimate of the state from the measurements ({describe(self.sensing)}) was {how}: "
                "the sensing is far too coarse for this crane; lower its noise, quantisation or delay "
                "(docs/sensing.md)")

    def _consistent_rates(self, qd: np.ndarray) -> None:
        """qd onto φ_q q̇ = −φ_t in place (minimal-norm) at the q and signals in the model's buffers."""
        self.model.qd[:] = qd
        self._phi_q.call()
        self._phi_dot.call()
        qd -= self._min_norm(self._phi_dot_out)


class FastEstimator(Estimator):
    """The fast path's estimator (docs/fast-path.md): the sensor (noise, quantisation, the delay line) as Estimator,
    the estimate from its measurement in one compiled call (acroboter.codegen.estimator_c: the same statements, its
    state block holding the estimate, the filter and the commanded accelerations that `reset` and `applied` write)."""

    def __init__(self, model, path: DesiredPath, sensing: Sensing, binding):
        super().__init__(model, path, sensing)
        b, n, d = binding, model.layout.n, self.delay
        self.binding = b
        self._qm, self._qdm, self._xf, self._vf = b.view("qm"), b.view("qdm"), b.view("xf"), b.view("vf")
        self.q, self.qd = b.view("q"), b.view("qd")
        self._acc = b.view("acc").reshape(d + 1, n)
        self._violation = b.view("violation")
        ns = model.layout.n_signals
        self._sig_m, self._sig_t = np.zeros(3 * ns), np.zeros(3 * ns)
        self._rows_at = [row.ctypes.data for row in self._ring]
        self._sig_at = (self._sig_m.ctypes.data, self._sig_t.ctypes.data)
        self._flat, self._carry = path.flat, bool(d and self.predict)

    def estimate(self, q_plant: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray]:
        d, T = self.delay, self.period
        slot = self._k % (d + 1)
        self._sample(q_plant, self._ring[slot])
        self._k += 1
        self._sig_m[:] = self._flat(max(t - d * T, 0.0))
        if self._carry:
            self._sig_t[:] = self._flat(t)
        code = self.binding.call(self._rows_at[self._k % (d + 1) if d else slot], *self._sig_at, slot,
                                 1 if self._started else 0)
        self._started = True
        if code != 0:  # a generated function failed: a non-finite estimate stops the run with a message
            self.q[:] = np.nan
        self.last_violation = float(self._violation[0])
        return self.q, self.qd


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
