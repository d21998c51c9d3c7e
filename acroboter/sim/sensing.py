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
from ..model.layout import build_layout, nominal_coordinates
from ..model.schema import Sensing, SpecError, _Strict
from ..model.sensing_layout import PROJECTION_ACCEPT, PROJECTION_TOLERANCE, is_ideal, measured_indices, sample_checks
from ..model.spec_checks import sensing_problems
from ..model.spec_errors import format_pydantic
from .cable_events import SimulationError

__all__ = ["ACCEPTED", "COASTING", "LOST", "PROJECTION_TOLERANCE", "REASONS", "Estimator", "SensingError",
           "check_measurable", "describe", "is_ideal", "measured_indices", "resolve"]

# A column-rank deficit of φ_q on the unmeasured coordinates: singular values below this × the largest.
RANK_TOLERANCE = 1e-9
OVERRIDE_KEYS = ("noise", "quantization", *Sensing.model_fields)  # groups, delay_periods, seed, ...
CHECK_KEYS = ("max_speed", "max_axis_rate", "max_coast_periods")  # the sample checks' settings
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
    if isinstance(sensing, Mapping) and is_ideal(spec, build_layout(spec), chosen):
        given = [key for key in CHECK_KEYS if key in sensing]
        if given:  # an ideal sensing is the state: nothing is checked, the setting would do nothing
            raise SpecError(source, [(f"sensing.{given[0]}", (
                "an ideal sensing (every coordinate, no noise, no quantisation, no delay) is the plant's state: no "
                "sample is checked; give some noise, quantisation or delay, or leave the sample checks out"))])
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


# The estimator's status after an update (Estimator.status, est.status in C), and why a sample was rejected
# (Estimator.reason, est.reason in C).
ACCEPTED, COASTING, LOST = 0, 1, 2
REASONS = ("accepted", "not finite", "a unit axis off unit length", "further from its prediction than the crane can "
           "move in a period", "the projection did not converge", "not confirmed by the sample before it",
           "the estimate turned non-finite")


class Estimator:
    """The sensor and the estimator of one run: `estimate(q_plant, t)` -> (q̂, q̇̂) for the controller; the sensor
    alone is `sample(q_plant)` (the measurement y the estimator reads now), the estimator alone `update(y, t)`.

    Each sample is checked before it is used (docs/sensing.md, "Bad samples"): finite, each fully measured unit
    axis of unit length, each coordinate within its gate of the prediction (max_speed or max_axis_rate times the
    period, 10 noise σ and a quantisation step, widened by each period coasted), and the projection converged. A
    rejected sample leaves the prediction as the estimate (`status` COASTING); after more than max_coast_periods in
    a row the estimate is LOST until two consecutive samples that agree within their gates re-acquire it.

    Preallocated; per call: one normal draw, the Gauss–Newton steps (`phi`, `phi_q` through the
    compiled bindings, a Cholesky factorisation of φ_q φ_qᵀ by LAPACK), the α-β update and one
    `phi_dot` for the velocity correction."""

    def __init__(self, model, path: DesiredPath, sensing: Sensing):
        spec, lay = model.spec, model.layout
        self.model, self.path, self.sensing = model, path, sensing
        self.index, self.noise, self.step = measured_indices(spec, lay, sensing)
        self.checks = sample_checks(spec, lay, sensing)
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
        # one block, as the C struct's: qm, qdm (the estimate at the measurement's time), xf, vf (the filter), q, qd
        # (the estimate handed to the controller, overwritten every call); one sum tells whether all are finite
        self._state = np.zeros(6 * n)
        self._qm, self._qdm, self._xf, self._vf, self.q, self.qd = (self._state[i * n : (i + 1) * n] for i in range(6))
        self._pred, self._q_good = np.zeros(n), np.zeros(n)  # this update's prediction; qm of the last accepted
        self._y_prev, self._dy = np.zeros(nm), np.zeros(nm)
        self.predict = sensing.predict_delay
        self._r = np.zeros(n)
        na = self.checks.axes.shape[0]
        self._axes_y, self._axes_n = np.zeros((na, 3)), np.zeros(na)
        m = self.rows.size
        self._a, self._g, self._b, self._x = np.zeros((m, n)), np.zeros((m, m)), np.zeros(m), np.zeros(n)
        self.unmeasured = np.setdiff1d(np.arange(n), self.index)
        nu = self.unmeasured.size
        self._au, self._h, self._xu = np.zeros((m, nu)), np.zeros((nu, nu)), np.zeros(nu)
        self._k = self._ks = 0
        self._started = self._prev_valid = False
        self.coasted = 0  # samples rejected in a row (capped at max_coast + 1)
        self.distrust = 0  # +2 per rejected sample, -1 per accepted: a fault that keeps coming back loses the estimate
        self.status, self.reason, self.rejected = ACCEPTED, 0, -1  # of the last update (REASONS[reason])
        self.jump = 0.0  # the last sample's largest |y − prediction| / gate
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

    def sample(self, q_plant: np.ndarray) -> np.ndarray:
        """The sensor at this control instant: q_plant sampled into the delay line; returns the measurement the
        estimator reads now (taken delay_periods ago; a view, overwritten delay + 1 calls later)."""
        d = self.delay
        slot = self._ks % (d + 1)
        self._sample(q_plant, self._ring[slot])
        self._ks += 1
        return self._ring[self._ks % (d + 1)] if d else self._ring[slot]

    def reset(self, q0: np.ndarray) -> None:
        """A new run from rest at q0: the delay line holds measurements of q0 (the crane at rest
        before the start), the filter starts at the projected q0 with zero rates."""
        self._reset_sensor(q0)
        self.q[:] = q0
        self.qd[:] = 0.0
        self._qm[:] = self._xf[:] = self._q_good[:] = self._pred[:] = q0
        self._qdm[:] = self._vf[:] = 0.0
        self._acc[:], self._k = 0.0, 0
        self._started = self._prev_valid = False
        self.coasted, self.status, self.reason, self.rejected, self.jump, self.distrust = 0, ACCEPTED, 0, -1, 0.0, 0
        self.last_violation = 0.0

    def _reset_sensor(self, q0: np.ndarray) -> None:
        self.rng = np.random.default_rng(self.sensing.seed)
        for slot in self._ring:
            self._sample(q0, slot)
        self._ks = 0

    def reinit(self) -> None:
        """Restart the filter from the next sample (a restart mid-motion): its positions taken as they come (no
        gate), the rates from zero; the estimate so far is the unmeasured coordinates' prior (the last accepted one
        if it is not finite); the commanded accelerations and the delay line are kept."""
        if not np.isfinite(self._qm).all():
            self._qm[:] = self._q_good
        self._qdm[:] = self._vf[:] = 0.0
        self._xf[:] = self._qm
        self._started = self._prev_valid = False
        self.coasted, self.status, self.reason, self.rejected, self.distrust = 0, ACCEPTED, 0, -1, 0

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

    def applied(self, qdd: np.ndarray | None) -> None:
        """The acceleration the controller commanded at this instant (its model's q̈): the filter's
        prediction over the period that follows this instant's measurement (None or not finite: 0, a command that
        was not applied)."""
        slot = self._acc[(self._k - 1) % (self.delay + 1)]
        if qdd is None or not math.isfinite(np.add.reduce(qdd)):
            slot[:] = 0.0
        else:
            slot[:] = qdd

    def estimate(self, q_plant: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Sample the plant at t; the estimate from the measurement of delay_periods ago, carried
        forward to t with the commanded accelerations (predict_delay) or as it is."""
        self.update(self.sample(q_plant), t)
        return self.q, self.qd

    def _check(self, y: np.ndarray, lost: bool) -> tuple[int, int]:
        """(reason, y index) of the sample's first failed check ((0, -1): none); sets jump, y_prev, prev_valid."""
        checks, reason, rejected = self.checks, 0, -1
        if not math.isfinite(np.add.reduce(y)):  # NaN and ±inf survive a sum (a finite overflow is refused too)
            bad = np.flatnonzero(~np.isfinite(y))
            reason, rejected = 1, int(bad[0]) if bad.size else 0
        elif checks.axes.size:
            a = self._axes_y
            np.take(y, checks.axes, out=a)
            np.multiply(a, a, out=a)
            norm = self._axes_n
            np.add(a[:, 0], a[:, 1], out=norm)
            norm += a[:, 2]
            np.sqrt(norm, out=norm)
            norm -= 1.0
            np.abs(norm, out=norm)
            if not (norm <= checks.axis_tolerance).all():
                reason, rejected = 2, int(checks.axes[int(np.argmin(norm <= checks.axis_tolerance)), 0])
        valid, dy = reason == 0, self._dy
        self.jump = 0.0
        if valid and lost and not self._prev_valid:  # re-acquiring needs the sample before it
            reason = 5
        elif valid and (lost or self._started):
            if lost:  # re-acquiring: the sample must agree with the one before it
                np.subtract(y, self._y_prev, out=dy)
                np.abs(dy, out=dy)
                dy /= checks.gate
            else:
                np.take(self._pred, self.index, out=dy)
                np.subtract(y, dy, out=dy)
                np.abs(dy, out=dy)
                dy /= checks.gate if not self.coasted else checks.gate * (1.0 + self.coasted)
            j = int(dy.argmax())
            self.jump = float(dy[j])
            if self.jump > 1.0:
                reason, rejected = (5 if lost else 3), j
        if valid:
            self._y_prev[:] = y
        self._prev_valid = valid
        return reason, rejected

    def update(self, y: np.ndarray, t: float) -> int:
        """The estimator alone: the measurement y (taken delay_periods ago) -> the estimate at t in `q`, `qd`;
        returns `status` (ACCEPTED, COASTING on the prediction through a rejected sample, LOST)."""
        d, T = self.delay, self.period
        slot = self._k % (d + 1)
        acc = self._acc[slot]  # q̈ commanded at instant k − d − 1: over the period that ends at the measurement
        self._k += 1
        q, qd, pred = self._qm, self._qdm, self._pred  # the estimate at the measurement's time
        pred[:] = q
        if self._started:  # the prediction: the unmeasured coordinates' prior, the measured ones' check
            pred += T * qd + (0.5 * T * T) * acc
        lost = self._lost()
        reason, rejected = self._check(y, lost)
        q[:] = pred
        if reason == 0:
            q[self.index] = y
        signals = self.path.flat(max(t - d * T, 0.0))
        self.project(q, signals)
        if reason == 0 and not self.last_violation <= PROJECTION_ACCEPT:
            reason, rejected = 4, -1
            q[:] = pred
            self.project(q, signals)
        accepted = reason == 0
        # velocities: α-β filter of the projected positions (re-acquired: the positions from the sample, the
        # coasted rates kept), then onto φ_q q̇ = −φ_t
        if not self._started:
            self._xf[:] = q
            self._vf[:] = 0.0
            self._started = True
        elif accepted and lost:
            self._xf[:] = q
        else:  # after coasting, the innovation built up over 1 + coasted periods: the rate's share scaled down
            xf, vf, r = self._xf, self._vf, self._r
            xf += T * vf + (0.5 * T * T) * acc  # prediction with the commanded acceleration
            vf += T * acc
            np.subtract(q, xf, out=r)
            xf += self.alpha * r
            vf += (self.beta / (T * (1.0 + self.coasted))) * r
        qd[:] = self._vf
        self._consistent_rates(qd)
        out_q, out_qd = self.q, self.qd
        out_q[:], out_qd[:] = q, qd
        if d and self.predict:  # carried forward over the d periods since the measurement
            for j in range(1, d + 1):
                a = self._acc[(slot + j) % (d + 1)]  # instants k − d … k − 1
                out_q += T * out_qd + (0.5 * T * T) * a
                out_qd += T * a
            self.project(out_q, self.path.flat(t))
            self._consistent_rates(out_qd)
        self.coasted = 0 if accepted else min(self.coasted + 1, self.checks.max_coast + 1)
        if accepted:
            self.distrust = 0 if lost else max(self.distrust - 1, 0)  # re-acquired: trusted anew
        elif self.distrust <= 4 * self.checks.max_coast:
            self.distrust += 2
        self._settle(reason, rejected, accepted)
        return self.status

    def _lost(self) -> bool:
        """More than max_coast_periods rejected in a row, or a fault that keeps coming back (distrust)."""
        return self.coasted > self.checks.max_coast or self.distrust > 4 * self.checks.max_coast

    def _settle(self, reason: int, rejected: int, accepted: bool) -> None:
        """The update's status; an estimate that turned non-finite goes back to the last accepted one, at rest,
        lost (re-acquired from two agreeing samples)."""
        if not math.isfinite(np.add.reduce(self._state)):
            for v in (self._qm, self._xf, self.q):
                v[:] = self._q_good
            for v in (self._qdm, self._vf, self.qd):
                v[:] = 0.0
            self.last_violation, self.coasted = 0.0, self.checks.max_coast + 1
            reason, rejected, accepted = 6, -1, False
        elif accepted:
            self._q_good[:] = self._qm
        self.reason, self.rejected = reason, rejected
        self.status = ACCEPTED if accepted else (LOST if self._lost() else COASTING)

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
