"""The checks around a retiming: the statics along the path before it (a need at rest beyond the limits is
one no timing can help), and after it the certificate: the planned trajectory flown by the spec's controllers
(MLM by default, every method asked for) at the spec's rate on the own plant with the limits applied, as a run
flies it: it fails where a flight diverges or the limits do not let a controller meet its task (saturated).
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field

import numpy as np

from ..control.controllers import Gains, make_controller
from ..control.path import DesiredPath
from ..sim.records import Scenario
from ..sim.simulation import setup_default, simulate
from ..sim.statics import EquilibriumError, solve_equilibrium
from .geometry import PathGeometry
from .ideal_motion import PlanningError
from .limits import beyond_bounds, margin_achieved

# Places along the path where the statics are checked (besides every waypoint of a spec path).
STATIC_SAMPLES = 101
# The static needs of this many (crane, path) pairs are kept for the process: a plan to a tolerance plans the same
# path three times or more, and each check took 5 s of equilibrium solves (the lift, 2026-12-07). Keyed by the
# model's hash, a redundant crane's preferred inputs and the path's samples, so a changed crane or path is solved
# again (clear_static_needs forgets them all).
NEEDS_KEPT = 8
_NEEDS: dict[tuple[str, bytes, bytes], np.ndarray] = {}
_NEEDS_LOCK = threading.Lock()


class StaticLimitError(PlanningError):
    """A place on the path where holding the load at rest already needs an input beyond its limits (or beyond
    them less the margin): no timing can help."""


class _AtRest:
    """The path frozen at σ, at rest: what solve_equilibrium reads (signal_arrays(0))."""

    def __init__(self, geometry: PathGeometry, sigma: float):
        self.g = geometry.evaluate([sigma])[0][0]

    def signal_arrays(self, t: float):
        return self.g, np.zeros_like(self.g), np.zeros_like(self.g)


def static_needs(model, geometry: PathGeometry) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(τ, tracked point position, the inputs that hold the load at rest there) along the path."""
    taus = np.linspace(0.0, geometry.end, STATIC_SAMPLES)
    if geometry.edges:  # every corner
        taus = np.unique(np.concatenate([taus, np.arange(geometry.end + 1)]))
    g, _, _ = geometry.evaluate(taus)
    # the model's hash leaves out the run-time settings; of those, the preferred inputs choose the internal force at
    # rest of a crane with more inputs than servo-constraints (solve_equilibrium), and only there
    lay = model.layout
    preferred = np.asarray(model.spec.input_limits()[2], float).tobytes() if lay.l > lay.k else b""
    key = (model.spec.model_hash(), preferred, g.tobytes())
    with _NEEDS_LOCK:
        kept = _NEEDS.get(key)
    if kept is None:
        needs, last = [], None
        for tau in taus:
            try:  # each place from the one before (a continuation: a few iterations each, the same branch)
                last = solve_equilibrium(model, _AtRest(geometry, float(tau)), near=last)
            except EquilibriumError as err:
                raise StaticLimitError(f"no static equilibrium at {geometry.place(float(tau))}: {err}") from None
            needs.append(last.inputs)
        kept = np.array(needs)
        with _NEEDS_LOCK:  # the dict is the process's (two cranes planned in two threads); two threads may both
            # solve one key: the same answer, kept once
            if key not in _NEEDS and len(_NEEDS) >= NEEDS_KEPT:
                _NEEDS.pop(next(iter(_NEEDS)))
            _NEEDS[key] = kept
    return taus, g[:, geometry.point_rows], kept.copy()


def clear_static_needs() -> None:
    """Forget every kept static need (static_needs): the next check solves its path again."""
    with _NEEDS_LOCK:
        _NEEDS.clear()


def check_statics(model, geometry: PathGeometry, lower, upper, low, high, margin: float) -> np.ndarray:
    """StaticLimitError at the first place where the inputs at rest are beyond the limits, else at the first where
    they are beyond them less the margin (with the largest margin that would leave room); returns the static needs
    (places x inputs)."""
    lay = model.layout
    taus, points, needs = static_needs(model, geometry)
    # the limits themselves first, anywhere on the path: where they are exceeded no margin can help, so a place
    # that only misses the margin must not be named before it
    for beyond_limits in (True, False):
        for k, u in enumerate(needs):
            for i, value in enumerate(u):
                tol = 1e-9 * max(1.0, abs(value))
                raw = value > upper[i] + tol or value < lower[i] - tol
                tight = value > high[i] + tol or value < low[i] - tol
                if not (raw if beyond_limits else tight):
                    continue
                unit, name = lay.input_units[i], lay.inputs[i]
                where = geometry.place(float(taus[k]), points[k])
                if raw:
                    limit = upper[i] if value > upper[i] else lower[i]
                    raise StaticLimitError(f"no timing can help: at {where} holding the load at rest needs {name} = "
                                           f"{value:.4g} {unit}, beyond its limit {limit:.4g} {unit}; raise the limit "
                                           "or change the path there")
                bound = high[i] if value > high[i] else low[i]
                room = worst_static_margin(needs, lower, upper)
                raise StaticLimitError(f"no timing can help with a margin of {100 * margin:.4g} %: at {where} holding "
                                       f"the load at rest needs {name} = {value:.5g} {unit}, beyond {bound:.5g} {unit} "
                                       f"(its limits less the margin); the statics along the path leave a margin of at "
                                       f"most {100 * max(room, 0.0):.3g} %: give a smaller --margin or wider limits")
    return needs


def worst_static_margin(needs: np.ndarray, lower, upper) -> float:
    """The margin the statics along the path leave (the margin achieved by the inputs at rest)."""
    value, _ = margin_achieved(needs, lower, upper)
    return value


# The certificate flies this long past the trajectory's end, the desired point held there: a servo law still
# catching up when the path stops, or overshooting after it, is farthest off after the end. Measured 2026-12-07 on
# the lift planned to 0.1 mm (limits [24, 29] N, 20 %, 8 intervals): 0.0963 mm on the path, 0.0975 mm 0.138 s
# after its end, 0.0064 mm 1 s after. The lag model bounds the same interval (servo_lag.LAG_SETTLE_TIMES_S, to 1 s).
SETTLE_AFTER_END_S = 1.0


@dataclass
class Certificate:
    """The planned trajectory flown on the own plant from the static start, the limits applied, by each method
    asked for (`flights`: method -> its figures). The arrays and figures are the first method's (MLM by default);
    `failure` is the first failure of any (diverged, or saturated: a step whose task the limits did not let the
    controller meet), None when every flight held. Each flight goes on SETTLE_AFTER_END_S past the trajectory's end
    (`settle_s`), and its figures cover that too (`max_position_error_after_end_mm`: that part alone)."""

    times: np.ndarray
    inputs: np.ndarray  # per control instant
    max_position_error_mm: float
    margin_achieved: float  # fraction of the span (inputs with two finite limits)
    margin_input: str | None
    beyond_margin: float  # the largest excess beyond the tightened limits, fraction of the span (≤ 0: none)
    failure: str | None = None  # why the certificate failed (diverged, saturated, beyond a limit), None if it held
    flights: dict = field(default_factory=dict)  # method -> {max_position_error_mm, margin_achieved, saturated_s, …}
    settle_s: float = SETTLE_AFTER_END_S  # how long every flight went on past the trajectory's end (s)


def certify(model, path: DesiredPath, q0: np.ndarray, duration: float, lower, upper, low, high,
            methods: tuple[str, ...] = ("mlm",), settle_s: float = SETTLE_AFTER_END_S) -> Certificate:
    """The certificate of a planned trajectory of `duration` s, flown `settle_s` past its end (see Certificate); a
    flight that failed is reported with its figures up to there."""
    spec, lay = model.spec, model.layout
    rows = Scenario.from_model(model).position_rows
    first, failure, flights = None, None, {}
    def after_end(t):  # the control instant at the end is not after it (k / rate may be an ulp above the duration)
        return t > duration + 1e-9 * max(1.0, duration)

    for method in methods:
        controller = make_controller(method, model, path, Gains.from_spec(spec), limits=spec.input_limits())
        run = simulate(model, path, controller, setup_default(model, path), q0, duration + settle_s,
                       spec.controller.rate_hz, spec.simulation.step, allow_divergence=True)
        why = None
        if run.diverged_at is not None:
            why = (f"the certificate failed: the planned trajectory flown by {method} diverged at t = "
                   f"{run.diverged_at:.2f} s ({run.divergence})")
        held = np.flatnonzero(run.saturated)
        if why is None and len(held):
            on = [lay.inputs[i] for i in np.flatnonzero(run.limit_state[held[0]] != 0)]
            why = (f"the certificate failed: flown by {method} with the limits applied, the limits did not let the "
                   f"controller meet its task at t = {run.t[held[0]]:.3f} s"
                   f"{' (after the trajectory ends, the point held)' if after_end(run.t[held[0]]) else ''} "
                   f"(on a limit: {', '.join(on) or 'none'}; "
                   f"{len(held) / spec.controller.rate_hz:.3g} s in all); give a larger --margin (the closed loop's "
                   "deviations from the ideal inputs need it)")
        achieved, i = margin_achieved(run.u, lower, upper)
        over = beyond_bounds(run.u, low, high)
        errors = np.linalg.norm(run.sigma[:, rows], axis=1)
        error = 1e3 * float(np.nanmax(errors))
        after = after_end(run.t)
        error_after = 1e3 * float(np.nanmax(errors[after])) if after.any() else None
        flight = Certificate(run.t, run.u, error, achieved, None if i is None else lay.inputs[i],
                             float(over.max()), why)
        flights[method] = {"max_position_error_mm": error, "max_position_error_after_end_mm": error_after,
                           "settle_s": float(settle_s), "margin_achieved": float(achieved),
                           "margin_input": flight.margin_input, "beyond_bounds": flight.beyond_margin,
                           "saturated_s": len(held) / spec.controller.rate_hz, "diverged_at_s": run.diverged_at,
                           "failure": why}
        first = first or flight
        failure = failure or why
    first.failure, first.flights, first.settle_s = failure, flights, float(settle_s)
    return first
