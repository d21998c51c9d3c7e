"""`plan --tolerance`: the fastest timing within the limits less the margin whose flight stays within a position
error the user sets, every method asked for (docs/planning.md, "A tolerance").

How it is found. A time-optimal timing is bang-bang in σ̈, and a controller that holds its input between samples
follows a jump of the acceleration worst; even a smooth timing is followed with a lag, the sampled servo law's
(acroboter.planning.servo_lag: ë + 2kd ė + kp² e = −(T/2)·E u̇, E u̇ the servo-constraint jerk the ideal inputs'
change causes). So the timing is made smooth (σ̈ continuous, linear per interval, 0 at every corner) and that
lag model's error is a constraint of the time-optimal problem, bounded by the tolerance: one solve. The
certificate then flies the plan with each method, the limits applied. The model leaves things out (the plant
between samples, the sampled feedback), so where a flight's error exceeds the tolerance the model's bound is
narrowed by the ratio (and MODEL_NARROWING more) and the problem solved again, at most TOLERANCE_ROUNDS times;
what is left is "tolerance not met", exit 3, with the gains that would meet it.

The controller's clock is not the plan's. A timing whose acceleration jumps is flown almost exactly when its jumps
fall on the controller's samples and worst when they fall just after one: the default crane's 0.1 m lift planned
time-optimally and slowed 1.64x flew at 0.33 mm, slowed 1.66x at 0.024 mm (MLM, 2026-12-06). So every flight
that judges a tolerance is flown with the trajectory started at each of CLOCK_OFFSETS of a control period after a
sample (held at rest before), and the worst counts: a plan meets its tolerance whatever the phase of the clock.

What it is compared with (in the summary): the time-optimal timing (no lag bound, σ̈ held: its duration and its
flown error), and the best uniform slowdown of that timing whose flights meet the same tolerance (the slowdown
factor on a ladder of UNIFORM_LADDER, refined by bisection to UNIFORM_RESOLUTION; the error of a bang-bang timing
is not monotonic in the factor, the jumps falling at other places of the sample period, so this is the first
factor of the ladder that meets it, refined).
"""

from __future__ import annotations

import math

import numpy as np

from ..control.path import SampledTrajectory, TrajectoryPath, sped_up
from ..model.ranges import sampled_gain_problems
from .checks import certify
from .ideal_motion import PlanningError
from .planner import CertificateError, Plan, PlanFailure, plan
from .shaping import SHAPERS
from .windows import bisect_factor

TOLERANCE_ROUNDS = 4
# A round whose flight missed narrows the model's bound by the flight's excess and this much more.
MODEL_NARROWING = 0.97
# The uniform slowdown that meets the tolerance: factors 1, 1.25, 1.25², ... up to UNIFORM_MAX, then bisection.
UNIFORM_LADDER = 1.25
UNIFORM_MAX = 64.0
UNIFORM_RESOLUTION = 1e-2
# Where the trajectory starts within a control period (fractions of it): see the module.
CLOCK_OFFSETS = (0.0, 0.25, 0.5, 0.75)
# A delayed trajectory rests until this long before its start (s): its first jump of σ̈ stays a jump.
HOLD_GAP_S = 1e-6


def delayed(trajectory: SampledTrajectory, delay: float) -> SampledTrajectory:
    """The trajectory started `delay` seconds late, at rest at its first position until then."""
    if delay <= 0:
        return trajectory
    rest = np.zeros((2, trajectory.position.shape[1]))
    start = np.repeat(trajectory.position[:1], 2, axis=0)
    return SampledTrajectory(np.concatenate([[0.0, delay - HOLD_GAP_S], trajectory.times + delay]),
                             np.vstack([start, trajectory.position]), np.vstack([rest, trajectory.velocity]),
                             np.vstack([rest, trajectory.acceleration]))


def clock_flights(model, path, trajectory: SampledTrajectory, q0, methods, bounds,
                  certificate=None, stop_above: float | None = None) -> tuple[float, str | None, dict]:
    """The trajectory flown by each method at each of CLOCK_OFFSETS (the limits applied, as the certificate flies):
    the worst position error (m), the first failure (None: none), and each offset's worst error (mm).
    `certificate`: the plan's own (planner.certify's flights of the same trajectory with the same methods), which
    is the flight at offset 0 and is not flown again. `stop_above` (m): stop at the first flight that fails or errs
    beyond it (a yes-or-no question: the figures then cover the flights flown so far)."""
    spec = model.spec
    lower, upper, _ = spec.input_limits()
    period = 1.0 / spec.controller.rate_hz
    worst, failure, by_offset = 0.0, None, {}

    def misses(why: str | None, error_m: float) -> bool:  # the question `stop_above` asks is answered: no
        return stop_above is not None and (why is not None or error_m > stop_above)

    for fraction in CLOCK_OFFSETS:
        if fraction == 0.0 and certificate is not None:
            flights = [certificate]
        else:
            shifted = delayed(trajectory, fraction * period)
            flown = TrajectoryPath(spec, model.layout, shifted, shifted.duration, float(path.start_yaw))
            # one method at a time when a miss ends the question: the flights after it are not flown
            groups = [(m,) for m in methods] if stop_above is not None else [tuple(methods)]
            flights = []
            for group in groups:
                flights.append(certify(model, flown, q0, shifted.duration, lower, upper, *bounds, group))
                if misses(flights[-1].failure, 1e-3 * flights[-1].max_position_error_mm):
                    break
        error = max(v["max_position_error_mm"] for c in flights for v in c.flights.values())
        by_offset[f"{fraction:g}"] = error
        worst = max(worst, 1e-3 * error)
        failure = failure or next((c.failure for c in flights if c.failure is not None), None)
        if misses(failure, worst):
            break
    return worst, failure, by_offset


def check_plan_options(options: dict, tolerance, certify) -> None:
    """The numbers of a plan request in their ranges (acroboter.model.ranges; a RangeError, a ValueError, before any
    work); a tolerance needs a certificate (it is judged by flying)."""
    from ..model.ranges import MARGIN, PLAN_ACCEL, PLAN_INTERVALS, PLAN_JERK, PLAN_SPEED, PLAN_TOLERANCE, PLAN_WINDOW

    MARGIN.check(options["margin"], "margin")
    PLAN_INTERVALS.check(options["intervals"], "intervals")
    for name, range_ in (("window", PLAN_WINDOW), ("max_speed", PLAN_SPEED), ("max_accel", PLAN_ACCEL),
                         ("max_jerk", PLAN_JERK)):
        if options[name] is not None:
            range_.check(options[name], name)
    shaper = options.get("shaper")
    if shaper is not None and shaper not in SHAPERS:
        raise PlanningError(f"shaper: expected one of {', '.join(SHAPERS)} or None, found {shaper!r}")
    if tolerance is not None:
        PLAN_TOLERANCE.check(tolerance, "tolerance")
        if shaper is not None:
            raise PlanningError("shaper: a shaped timing has no optimiser to hold a tolerance; give one or the other")
        if certify is False:
            raise PlanningError("tolerance: it is judged by flying the plan; it cannot go with certify=False")


def plan_path(model, path, q0, certify, tolerance: float | None = None, **options) -> Plan:
    """planner.plan, or plan_to_tolerance with a tolerance (its methods those `certify` names, MLM for True)."""
    margin, intervals = float(options.pop("margin")), int(options.pop("intervals"))
    if tolerance is None:
        return plan(model, path, q0, margin=margin, intervals=intervals, certify_plan=certify, **options)
    methods = ("mlm",) if certify is True else tuple(certify)
    options.pop("shaper", None)  # None: check_plan_options refuses a shaper with a tolerance
    return plan_to_tolerance(model, path, q0, float(tolerance), methods, margin=margin, intervals=intervals,
                             **options)


def plan_to_tolerance(model, path, q0, tolerance: float, methods: tuple[str, ...], compare: bool = True,
                      **options) -> Plan:
    """The plan (see the module) whose flights by each of `methods` stay within `tolerance` (m); `options` as
    planner.plan takes them (margin, max_speed, ...). PlanFailure holding the plan when the rounds do not meet
    it; the plan's `tolerance` says how it was found and, with `compare`, what the time-optimal timing and its
    best uniform slowdown give."""
    if not (isinstance(tolerance, (int, float)) and math.isfinite(tolerance) and tolerance > 0):
        raise PlanningError(f"tolerance: expected a position error in metres > 0, found {tolerance!r}")
    c = model.spec.controller
    period = 1.0 / c.rate_hz
    bound, rounds, result, failure = float(tolerance), [], None, None
    for _ in range(TOLERANCE_ROUNDS):
        try:
            # each round after the first starts from the last one's timing (its solve is a small step from there)
            result = plan(model, path, q0, certify_plan=methods, lag=(bound, c.kp, c.kd, period), warm=result,
                          **options)
            failure = None
        except CertificateError as err:  # saturated or diverged: a larger margin's matter, said as it is
            result, failure = err.plan, err
        except PlanFailure as err:
            if result is None:
                raise
            # a narrower bound's solve failed (a fallback timing, not the optimum): the last round's plan stands,
            # flown beyond the tolerance, and the rounds say why the search stopped
            why = "; ".join(err.plan.failures) or str(err)
            rounds.append({"model_bound_mm": 1e3 * bound, "duration_s": err.plan.duration, "flown_mm": None,
                           "flown_mm_by_clock_offset": {}, "solve_s": err.plan.solve_s, "not_solved": why})
            result.failures.append(f"the round with the model's bound at {1e3 * bound:.4g} mm was not solved: {why}")
            break
        if failure is None:
            flown, failure, by_offset = clock_flights(model, path, result.trajectory, q0, methods, result.bounds,
                                                      result.certificate)
        else:
            flown, by_offset = 1e-3 * max(f["max_position_error_mm"] for f in result.certificate.flights.values()), {}
        rounds.append({"model_bound_mm": 1e3 * bound, "duration_s": result.duration, "flown_mm": 1e3 * flown,
                       "flown_mm_by_clock_offset": by_offset, "solve_s": result.solve_s})
        if failure is not None or flown <= tolerance:
            break
        bound *= MODEL_NARROWING * tolerance / flown
    record = {"asked_mm": 1e3 * tolerance, "flown_mm": 1e3 * flown, "met": flown <= tolerance and failure is None,
              "methods": list(methods), "clock_offsets_periods": list(CLOCK_OFFSETS),
              "how": "σ̈ continuous; the sampled servo law's lag, ë + 2kd ė + kp² e = −(T/2)·E u̇, bounded",
              "rounds": rounds}
    result.tolerance = record
    if compare:
        record.update(compared(model, path, q0, tolerance, methods, result.duration, options))
    if failure is not None:  # saturated or diverged: a larger margin's matter, said as it is
        if not result.failures:
            result.failures.append(f"the certificate failed at a clock offset: {failure}")
        raise CertificateError("; ".join(result.failures), result)
    if flown > tolerance:
        text = (f"the tolerance was not met: flown, the plan's worst position error is {1e3 * flown:.4g} mm against "
                f"{1e3 * tolerance:.4g} mm after {len(rounds)} rounds; {stiffer_gains(model, flown, tolerance)}")
        result.failures.append(text)
        raise PlanFailure("; ".join(result.failures), result)
    return result


def compared(model, path, q0, tolerance: float, methods, duration: float, options: dict) -> dict:
    """The time-optimal timing (σ̈ held, no lag bound) and the best uniform slowdown of it that meets the tolerance:
    their durations and flown errors, and whether the plan to the tolerance is faster."""
    try:
        optimal = plan(model, path, q0, certify_plan=methods, **options)
    except PlanFailure as err:  # its certificate may fail (saturated): its duration is still the reference
        optimal = err.plan
    flown, _, _ = clock_flights(model, path, optimal.trajectory, q0, methods, optimal.bounds, optimal.certificate)
    out = {"time_optimal_duration_s": optimal.duration, "time_optimal_flown_mm": 1e3 * flown}
    factor = uniform_factor(model, path, optimal, q0, tolerance, methods)
    out["uniform_slowdown_factor"] = factor
    out["uniform_slowdown_duration_s"] = None if factor is None else factor * optimal.duration
    out["faster_than_uniform_slowdown"] = factor is None or duration < factor * optimal.duration
    return out


def uniform_factor(model, path, optimal: Plan, q0, tolerance: float, methods) -> float | None:
    """The smallest slowdown of a plan's trajectory (see the module) whose flights stay within the tolerance with
    no step saturated; None if none up to UNIFORM_MAX does."""
    def meets(f: float) -> bool:
        worst, failure, _ = clock_flights(model, path, sped_up(optimal.trajectory, 1.0 / f), q0, methods,
                                          optimal.bounds, stop_above=tolerance)
        return failure is None and worst <= tolerance

    bad, good = None, 1.0
    while not meets(good):
        bad, good = good, good * UNIFORM_LADDER
        if good > UNIFORM_MAX:
            return None
    return 1.0 if bad is None else bisect_factor(meets, bad, good, UNIFORM_RESOLUTION)


def stiffer_gains(model, flown: float, tolerance: float) -> str:
    """What gains would meet the tolerance: the lag's error goes as 1/kp² at a fixed damping ratio kd/kp, within the
    sampled-loop stability bound the spec checks know (acroboter.model.ranges.sampled_gain_problems)."""
    c = model.spec.controller
    scale = math.sqrt(flown / tolerance)
    kp, kd = c.kp * scale, c.kd * scale
    if sampled_gain_problems(kp, kd, c.rate_hz):
        return (f"stiffer gains would be needed (about kp = {kp:.3g}, kd = {kd:.3g} 1/s), but the servo law sampled at "
                f"{c.rate_hz:g} Hz is not stable with them: a faster controller.rate_hz, or a larger tolerance")
    return (f"the spec's gains (kp = {c.kp:g}, kd = {c.kd:g} 1/s) lag too far: about kp = {kp:.3g}, kd = {kd:.3g} "
            f"1/s would (stable sampled at {c.rate_hz:g} Hz), or a larger tolerance")
