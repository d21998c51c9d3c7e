"""`plan(...)`: the fastest timing of a crane's path under its input limits with a margin, certified, as a
`Plan` (the response of `Crane.plan` and `acroboter plan`; docs/planning.md).

Steps: the statics along the path (a need at rest beyond the limits: StaticLimitError, no timing can help);
the best uniform slowdown of the path's own timing (bisection, the same dynamics: a feasible start and an
upper bound); the time-optimal problem (acroboter.planning.retiming); the trajectory sampled from its
solution; the certificate (the trajectory flown by MLM on the own plant, acroboter.planning.checks): an
input beyond the limits less the margin by more than CERTIFICATE_TOLERANCE of the span is a PlanningError,
never a silent result.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..control.path import DesiredPath, SampledTrajectory, TrajectoryError, TrajectoryPath, motion_time_scale
from ..control.trajectory_file import write_trajectory_csv
from ..model.spec import MAX_CONTROL_STEPS
from .checks import SETTLE_AFTER_END_S, Certificate, certify, check_statics
from .edges import EdgeRetiming
from .geometry import PathGeometry
from .ideal_motion import IdealDynamics, PlanningError, check_retimable
from .limits import CHECK_STEP_S, INPUT_TOLERANCE, active_intervals, margin_achieved, tightened, worst_beyond
from .retiming import OPTIMAL, Retiming, Solution
from .shaping import SHAPED_STATUS, SHAPERS, ShapedRetiming, corner_swing
from .windows import WindowedRetiming

# The certificate: the closed loop samples the path at the control rate and holds its input in between, so
# its inputs stray from the ideal ones the plan bounds, most where σ̈ jumps; that is what the margin is for.
# The certificate fails when a flown input goes beyond the limits themselves (by more than this fraction of
# the span: round-off), and reports the margin the flight achieved.
CERTIFICATE_TOLERANCE = 1e-9
# Samples of the written trajectory per second (and every node of the optimiser's grid).
SAMPLE_RATE_HZ = 100.0
DEFAULT_INTERVALS = 120
# The receding window (acroboter.planning.windows): phases solved together; paths with more phases than this are
# planned by the window unless the caller asks for the whole path (window = 0).
DEFAULT_WINDOW = 2
# What a waypoint path's corners are: "rest" (every edge rest to rest, the swing included: acroboter.planning.edges)
# or "swing" (the swing carried over, the edges optimised together).
CORNERS = ("rest", "swing")  # and "shaped", the corners of a shaper's plan (carried over, shaped edge by edge)
# The two samples at a node of the grid, one on each side (s).
NODE_GAP_S = 1e-6
# Solves again with the bounds moved in where the inputs leave them between the nodes (solve_within_bounds).
TIGHTEN_ROUNDS = 2
# A bound on the tracked point's speed or acceleration holds on the written samples to this relative tolerance
# (rounding; the optimiser keeps it geometry.KINEMATIC_SLACK inside at its nodes).
KINEMATIC_TOLERANCE = 1e-9


class PlanFailure(PlanningError):
    """A plan was computed but is not what was asked: a solve that did not reach the optimum (the timing returned
    is a fallback), a bound it does not hold, or (CertificateError) a failed certificate. `plan` is the Plan, its
    `failures` say why (the CLI writes it into failed/plan/ and exits 3; a caller may look at it, never fly it
    unawares)."""

    def __init__(self, message: str, plan: Plan):
        super().__init__(message)
        self.plan = plan


class CertificateError(PlanFailure):
    """The plan's certificate failed (its `certificate.failure` says why)."""


@dataclass
class Plan:
    """A retimed path: `duration` (s), the optimiser's grid (`times`, the path parameter `s` ∈ [0, 1] with its
    rates `sd`, `sdd`), the `trajectory` (a SampledTrajectory for `crane.simulate(trajectory=...)`, `to_csv`
    for `acroboter run --trajectory FILE`), the ideal `inputs` at `input_times` against the `limits` (min, max)
    and the `bounds` kept (the limits less the margin), the `active` intervals (an input on a bound), the
    `margin` asked and `margin_achieved` (fraction of the span), the best uniform slowdown of the path's own
    timing (`uniform_duration`), the `certificate` and the solver's figures (`solve_s`, `iterations`)."""

    duration: float
    path_duration: float
    times: np.ndarray
    s: np.ndarray
    sd: np.ndarray
    sdd: np.ndarray
    trajectory: SampledTrajectory
    input_names: list[str]
    input_units: list[str]
    input_times: np.ndarray
    inputs: np.ndarray
    limits: tuple[np.ndarray, np.ndarray]
    bounds: tuple[np.ndarray, np.ndarray]
    margin: float
    margin_achieved: float
    margin_input: str | None
    active: list[dict]
    uniform_duration: float
    uniform_slowdown: float
    static_margin: float
    solve_s: float
    iterations: int
    intervals: int
    corners: str = "rest"  # a waypoint path's corners: "rest" (edges rest to rest), "swing" or "shaped" (carried over)
    window: int = 0  # phases per window (0: the whole path in one solve)
    phase_duration: float | None = None  # the phase-wise slowdown's duration (the window's warm start)
    solves: list[dict] = field(default_factory=list)  # per solve: phases, intervals, RK4 steps, iterations, s
    end_state: np.ndarray | None = None  # the ideal motion's last state (q, q̇, σ, σ̇): the swing a plan leaves
    certificate: Certificate | None = None
    warnings: list[str] = field(default_factory=list)
    failures: list[str] = field(default_factory=list)  # why this is not the plan asked for (empty: it is)
    max_speed: float | None = None  # the bounds asked for (m/s, m/s², m/s³)
    max_accel: float | None = None
    max_jerk: float | None = None
    peak_jerk: float | None = None  # the tracked point's, on the samples; None when σ̈ jumps (no jerk bound)
    bounds_moved_in: dict = field(default_factory=dict)  # input -> how far the optimiser's bounds were moved in
    tolerance: dict | None = None  # a plan to a flown tolerance: how it was found (acroboter.planning.tolerance)
    shaping: dict | None = None  # an input-shaped timing: the shaper, its modes, each edge's factor (planning.shaping)
    corner_swing: list[dict] = field(default_factory=list)  # a waypoint path: the swing left at each corner

    @property
    def status(self) -> str:
        """"planned", or what failed: "solve failed", "bounds not held", "certificate failed", "tolerance not met"
        (joined by "; ")."""
        if not self.failures:
            return "planned"
        kinds = []
        for text in self.failures:
            kind = ("certificate failed" if text.startswith("the certificate") else
                    "tolerance not met" if text.startswith("the tolerance") else
                    "bounds not held" if text.startswith(("max_", "the planned inputs")) else "solve failed")
            if kind not in kinds:
                kinds.append(kind)
        return "; ".join(kinds)

    def kinematic_peaks(self) -> tuple[float, float]:
        """The written trajectory's peak speed (m/s) and acceleration (m/s²) over its samples."""
        return (float(np.linalg.norm(self.velocities, axis=1).max()),
                float(np.linalg.norm(self.accelerations, axis=1).max()))

    @property
    def positions(self) -> np.ndarray:
        return self.trajectory.position[:, :3]

    @property
    def velocities(self) -> np.ndarray:
        return self.trajectory.velocity[:, :3]

    @property
    def accelerations(self) -> np.ndarray:
        return self.trajectory.acceleration[:, :3]

    @property
    def yaw(self) -> np.ndarray | None:
        return self.trajectory.position[:, 3] if self.trajectory.position.shape[1] == 4 else None

    def to_csv(self, path: str | Path) -> Path:
        """The trajectory as `acroboter run --trajectory FILE` reads it (acroboter.control.trajectory_file)."""
        return write_trajectory_csv(path, self.trajectory)

    def summary(self) -> dict:
        def finite(v):
            return float(v) if math.isfinite(v) else None

        speed, accel = self.kinematic_peaks()
        out = {
            "status": self.status,
            "failures": self.failures,
            "duration_s": self.duration,
            "path_duration_s": self.path_duration,
            "uniform_slowdown_duration_s": self.uniform_duration,
            "uniform_slowdown_factor": self.uniform_slowdown,
            "margin": self.margin,
            "margin_achieved": finite(self.margin_achieved),
            "margin_input": self.margin_input,
            "static_margin": finite(self.static_margin),
            "limits": {name: {"min": finite(lo), "max": finite(hi), "bound_min": finite(blo), "bound_max": finite(bhi),
                              "unit": unit, "planned_min": float(self.inputs[:, i].min()),
                              "planned_max": float(self.inputs[:, i].max())}
                       for i, (name, unit, lo, hi, blo, bhi) in enumerate(zip(
                           self.input_names, self.input_units, *self.limits, *self.bounds, strict=True))},
            "active_limits": self.active,
            "bounds_moved_in": self.bounds_moved_in,
            "max_speed_m_s": self.max_speed, "peak_speed_m_s": speed,
            "max_accel_m_s2": self.max_accel, "peak_accel_m_s2": accel,
            "max_jerk_m_s3": self.max_jerk, "peak_jerk_m_s3": self.peak_jerk,
            "timing": "σ̈ held per interval (bang-bang)" if self.peak_jerk is None else "smooth (σ̈ continuous)",
            "intervals": self.intervals,
            "corners": self.corners,
            "window": self.window,
            "phase_slowdown_duration_s": self.phase_duration,
            "solves": self.solves,
            "iterations": self.iterations,
            "solve_s": self.solve_s,
            "warnings": self.warnings,
        }
        if self.tolerance is not None:
            out["tolerance"] = self.tolerance
        if self.shaping is not None:
            out["shaping"] = self.shaping
        out["corner_swing"] = self.corner_swing
        if self.certificate is not None:
            c = self.certificate
            out["certificate"] = {"method": f"{', '.join(c.flights) or 'mlm'}, own plant, limits applied, "
                                            f"held {c.settle_s:g} s past the end",
                                  "passed": c.failure is None, "failure": c.failure, "flights": c.flights,
                                  "max_position_error_mm": c.max_position_error_mm,
                                  "margin_achieved": finite(c.margin_achieved), "margin_input": c.margin_input,
                                  "beyond_bounds": c.beyond_margin, "tolerance": CERTIFICATE_TOLERANCE}
        return out


def plan(model, path: DesiredPath, q0: np.ndarray, margin: float = 0.05, max_speed: float | None = None,
         max_accel: float | None = None, intervals: int = DEFAULT_INTERVALS, certify_plan: bool | tuple = True,
         verbose: bool = False, window: int | None = None, corners: str = "rest", max_jerk: float | None = None,
         lag: tuple | None = None, warm: Plan | None = None, shaper: str | None = None) -> Plan:
    """`corners` (a waypoint path): "rest", every edge from rest to rest, the swing included (acroboter.planning.
    edges); "swing", the swing carried over the corners, the edges optimised together: `window` phases per
    receding window (acroboter.planning.windows), 0 the whole path in one solve, None DEFAULT_WINDOW (a path of at
    most DEFAULT_WINDOW phases is then one solve anyway). `max_jerk` (m/s³): the timing smooth (σ̈ continuous, 0 at
    every corner) with the tracked point's jerk at most that; `lag` (bound m, kp, kd, period s): smooth, with the
    sampled controller's lag within the bound (acroboter.planning.servo_lag; acroboter.planning.tolerance sets it);
    `warm`: an earlier smooth plan of the same path on the same grid, each phase's solve started from it. `shaper`
    (zv, zvd, unshaped): no optimiser; the path's own timing input-shaped edge by edge (acroboter.planning.shaping)."""
    spec, lay = model.spec, model.layout
    if not (isinstance(margin, (int, float)) and 0.0 <= margin < 0.5):
        raise PlanningError(f"margin: expected a fraction from 0 to below 0.5 (0 to 50 %), found {margin!r}")
    lower, upper, _ = spec.input_limits()
    low, high = tightened(lower, upper, margin)
    geometry = PathGeometry(path)
    check_timing_options(geometry, corners, shaper, lag, window)
    check_retimable(spec.name, lay)  # before the statics: such a crane is refused for what it is, not at a place
    needs = check_statics(model, geometry, lower, upper, low, high, margin)
    static_margin, _ = margin_achieved(needs, lower, upper)
    dynamics = IdealDynamics(spec, q0)
    kinematic = {"max_speed": max_speed, "max_accel": max_accel, "max_jerk": max_jerk, "lag": lag}
    problem, corners, window = timing_problem(dynamics, geometry, q0, low, high, corners, window, shaper, kinematic)
    if warm is not None and problem.smooth:
        problem.warm = warm_start(warm, problem.grid(intervals), geometry.end)
    solution, _, grid_inputs, tightened_by, leak = solve_within_bounds(problem, intervals, low, high, list(lay.inputs),
                                                                       list(lay.input_units), verbose, needs)
    trajectory, jerk = sample(geometry, solution, problem.n)
    achieved, where = margin_achieved(np.vstack([solution.inputs, grid_inputs]), lower, upper)
    result = Plan(
        duration=solution.duration, path_duration=geometry.path_duration, times=solution.times,
        s=solution.states[:, -2] / geometry.end, sd=solution.states[:, -1] / geometry.end,
        sdd=node_accelerations(solution) / geometry.end, trajectory=trajectory,
        input_names=list(lay.inputs), input_units=list(lay.input_units), input_times=solution.input_times,
        inputs=solution.inputs, limits=(lower, upper), bounds=(low, high), margin=float(margin),
        margin_achieved=achieved, margin_input=None if where is None else lay.inputs[where],
        active=active_intervals(solution.input_times, solution.inputs, low, high, list(lay.inputs)),
        uniform_duration=solution.uniform_duration, uniform_slowdown=solution.uniform_slowdown,
        static_margin=static_margin, solve_s=solution.solve_s, iterations=solution.iterations,
        intervals=solution.tau_dd.size if shaper else intervals, corners=corners if geometry.edges else "swing",
        window=window,
        phase_duration=None if problem.phase_slowdown is None else problem.phase_slowdown[1],
        solves=solution.windows, end_state=solution.states[-1].copy())
    result.max_speed, result.max_accel, result.max_jerk = max_speed, max_accel, max_jerk
    result.peak_jerk = jerk if problem.smooth else None
    result.bounds_moved_in = {lay.inputs[i]: float(v) for i, v in enumerate(tightened_by) if v > 0}
    if shaper is not None:
        result.shaping = problem.description()
    if geometry.edges:  # the swing left at each corner, against the crane at rest there
        rests = problem if isinstance(problem, EdgeRetiming) else EdgeRetiming(dynamics, geometry, q0, low, high)
        nodes = np.cumsum(problem.phase_counts(intervals)).tolist()  # each edge's last node
        result.corner_swing = corner_swing(rests, solution.times, solution.states, nodes)
    result.failures = unmet(solution, result)
    if leak is not None:
        result.failures.append(leak)
    if certify_plan:
        # what is certified is the written trajectory (its samples, interpolated), as `run --trajectory` flies it
        flown_path = TrajectoryPath(spec, lay, trajectory, trajectory.duration, float(path.start_yaw))
        methods = ("mlm",) if certify_plan is True else tuple(certify_plan)
        result.certificate = certify(model, flown_path, q0, trajectory.duration, lower, upper, low, high, methods)
        c, first = result.certificate, methods[0]
        if c.failure is None and c.margin_achieved < -CERTIFICATE_TOLERANCE:
            c.failure = (f"the certificate failed: flown by {first} on the own plant, the planned trajectory takes "
                         f"{c.margin_input} {100 * -c.margin_achieved:.3g} % of its span beyond its limits; give a "
                         "larger --margin (the closed loop's deviations from the ideal inputs need it)")
        if c.failure is not None:
            result.failures.append(c.failure)
        elif c.beyond_margin > 0:
            result.warnings.append(f"flown by {first}, {c.margin_input} came within {100 * c.margin_achieved:.3g} % "
                                   f"of the span of a limit (the plan keeps {100 * margin:.3g} %): the margin absorbed "
                                   "the closed loop's deviations")
    if result.failures:
        error = CertificateError if result.status == "certificate failed" else PlanFailure
        raise error("; ".join(result.failures), result)
    return result


def check_timing_options(geometry: PathGeometry, corners: str, shaper: str | None, lag,
                         window: int | None = None) -> None:
    """PlanningError for corners or a shaper `plan` cannot take (a shaper shapes each straight edge of the spec's
    waypoint path, with no optimiser to hold a tolerance, and carries the swing over the corners itself)."""
    if corners not in CORNERS:
        raise PlanningError(f"corners: expected one of {', '.join(CORNERS)}, found {corners!r}")
    if shaper is not None and (corners != "rest" or window is not None):
        raise PlanningError(f"shaper: a shaped timing carries the swing over the corners edge by edge; it cannot go "
                            f"with corners={corners!r} or a window (found window={window!r})")
    if shaper is not None and (shaper not in SHAPERS or lag is not None or not geometry.edges):
        raise PlanningError(f"shaper: expected one of {', '.join(SHAPERS)} on the spec's waypoint path, without a "
                            f"tolerance (a shaper shapes each straight edge's timing), found {shaper!r}"
                            + (" with a tolerance" if lag is not None else "")
                            + ("" if geometry.edges else " on a trajectory file"))


def timing_problem(dynamics, geometry, q0, low, high, corners: str, window: int | None, shaper: str | None,
                   kinematic: dict):
    """The problem that finds the timing, with the corners and the window it plans with: a shaped timing
    (ShapedRetiming), rest-to-rest edges (EdgeRetiming), a receding window (WindowedRetiming) or one solve."""
    window = DEFAULT_WINDOW if window is None else int(window)
    if window >= len(geometry.phases):
        window = 0  # the window would be the whole path
    if shaper is not None:
        return ShapedRetiming(dynamics, geometry, q0, low, high, shaper_kind=shaper, **kinematic), "shaped", 0
    if corners == "rest" and geometry.edges:
        return EdgeRetiming(dynamics, geometry, q0, low, high, **kinematic), corners, 0
    if window:
        return WindowedRetiming(dynamics, geometry, q0, low, high, window=window, **kinematic), corners, window
    return Retiming(dynamics, geometry, q0, low, high, **kinematic), corners, window


def warm_start(warm: Plan, counts: list[int], end: float) -> tuple[list[np.ndarray], list[float]] | None:
    """Each phase's σ̈ at its nodes and its duration in an earlier plan on the grid `counts` (None if its grid is
    another): a later round's starting guess (acroboter.planning.tolerance)."""
    if warm.times.size != sum(counts) + 1:
        return None
    bounds = np.concatenate([[0], np.cumsum(counts)])
    nodes = warm.sdd * end
    return ([nodes[a : b + 1] for a, b in zip(bounds[:-1], bounds[1:], strict=True)],
            [float(warm.times[b] - warm.times[a]) for a, b in zip(bounds[:-1], bounds[1:], strict=True)])


def node_accelerations(solution: Solution) -> np.ndarray:
    """σ̈ at the nodes (each interval's start; the last interval's end last)."""
    last = solution.tau_dd[-1] + solution.tau_ddd[-1] * (solution.times[-1] - solution.times[-2])
    return np.append(solution.tau_dd, last)


def unmet(solution: Solution, plan: Plan) -> list[str]:
    """What keeps the plan from being the one asked for, before its certificate: a solve that did not reach
    IPOPT's optimum (its timing a fallback), a max_speed or max_accel the written samples exceed."""
    out = []
    for record in solution.windows:
        if record.get("replaced") or record.get("status") in (*OPTIMAL, SHAPED_STATUS):
            continue  # a solve an edge's later one replaced (EdgeRetiming.carried) says nothing of the plan
        phases = ", ".join(str(j + 1) for j in record.get("phases", []))
        kept = ("its own timing slowed from rest was kept" if record.get("status") == "quintic_slowdown_kept"
                else f"IPOPT stopped with {record.get('status')}")
        out.append(f"the time-optimal problem of phase(s) {phases} was not solved ({kept}"
                   + (f": {record['reason']}" if record.get("reason") else "") + "): the timing returned is "
                   f"not the fastest ({plan.duration:.4g} s; the best uniform slowdown {plan.uniform_duration:.4g} "
                   "s); try more --intervals or a larger margin")
    speed, accel = plan.kinematic_peaks()
    for name, bound, peak, unit in (("max_speed", plan.max_speed, speed, "m/s"),
                                    ("max_accel", plan.max_accel, accel, "m/s²"),
                                    ("max_jerk", plan.max_jerk, plan.peak_jerk, "m/s³")):
        if bound is not None and peak > bound * (1.0 + KINEMATIC_TOLERANCE):
            out.append(f"{name} not held: the written trajectory reaches {peak:.6g} {unit} against {bound:.6g} "
                       f"{unit} (the bound is kept at the optimiser's nodes; give more --intervals)")
    return out


def solve_within_bounds(problem, intervals: int, low, high, names: list[str], units: list[str], verbose: bool,
                        needs: np.ndarray | None = None):
    """The problem solved, and its inputs on a CHECK_STEP_S grid: (solution, grid times, grid inputs, how far the
    optimiser's bounds were moved in, per input, what is left outside the bounds: a message or None). Where the
    inputs leave the bounds between the optimiser's nodes, the problem is solved again with those bounds moved in
    by the excess and a fifth, at most TIGHTEN_ROUNDS times; not when the bounds moved in leave no room for
    `needs` (the inputs at rest along the path, places x inputs: at a corner, where the crane stops, no timing can
    meet such bounds; the bisection that found that out took 110 s on the paper's path, 2026-12-07)."""
    base_low, base_high = problem.lower.copy(), problem.upper.copy()
    kept = None  # the last solve's (solution, grid times, grid inputs, leak, its bounds)
    for attempt in range(TIGHTEN_ROUNDS + 1):
        try:
            if attempt and needs is not None:
                refuse_static(needs, problem.lower, problem.upper, names, units)
            solution = problem.solve(intervals, verbose=verbose)
        except StaticRefusal as err:
            solution, times, inputs, leak, problem.lower, problem.upper = kept
            leak = f"{leak} (not solved again with the bounds moved in by the excess and a fifth: {err})"
            break
        except PlanningError as err:
            if kept is None:
                raise
            # the bounds moved in left no timing (the statics too close to them): the last solve is the plan, its leak
            # said, never a lost plan
            solution, times, inputs, leak, problem.lower, problem.upper = kept
            leak = f"{leak} (solved again with the bounds moved in by the excess and a fifth, it had no timing: {err})"
            break
        # the inputs at every instant (a CHECK_STEP_S grid), not only where the optimiser looks
        times, inputs = problem.inputs_on_grid(solution, CHECK_STEP_S)
        leak = between_nodes(times, inputs, low, high, names, units, getattr(problem, "stuck", None))
        kept = solution, times, inputs, leak, problem.lower.copy(), problem.upper.copy()
        if leak is None or attempt == TIGHTEN_ROUNDS:
            break
        with np.errstate(invalid="ignore"):
            above = np.nan_to_num(np.max(inputs - high, axis=0), nan=0.0, neginf=0.0)
            below = np.nan_to_num(np.max(low - inputs, axis=0), nan=0.0, neginf=0.0)
        problem.upper = problem.upper - 1.2 * np.maximum(above, 0.0)
        problem.lower = problem.lower + 1.2 * np.maximum(below, 0.0)
    with np.errstate(invalid="ignore"):  # inf - inf: an unbounded side, never moved
        moved = np.maximum(base_high - problem.upper, problem.lower - base_low)
    problem.lower, problem.upper = base_low, base_high
    return solution, times, inputs, np.nan_to_num(moved, nan=0.0), leak


class StaticRefusal(PlanningError):
    """Bounds moved in past an input the path needs at rest: no timing that stops there could keep them."""


def refuse_static(needs: np.ndarray, low, high, names: list[str], units: list[str]) -> None:
    """StaticRefusal when an input at rest somewhere on the path (`needs`, places x inputs) is beyond (low, high)."""
    worst = worst_beyond(needs, low, high)
    if worst is not None:
        k, i, bound = worst
        raise StaticRefusal(f"holding the load at rest needs {names[i]} = {needs[k, i]:.6g} {units[i]} somewhere on "
                            f"the path, beyond {bound:.6g} {units[i]}")


def between_nodes(times: np.ndarray, inputs: np.ndarray, low, high, names: list[str], units: list[str],
                  cause: str | None = None) -> str | None:
    """What to say of planned inputs that leave the bounds (the limits less the margin) between the optimiser's
    nodes by more than INPUT_TOLERANCE of the span (None when they do not): `cause`, when the planner knows it (the
    swing rest-to-rest edges carry over, EdgeRetiming.stuck), else more intervals as the fix."""
    worst = worst_beyond(inputs, low, high, INPUT_TOLERANCE)
    if worst is None:
        return None
    k, i, bound = worst
    where = "with the swing carried over every corner" if cause else "between the optimiser's nodes"
    return (f"the planned inputs leave the bounds {where}: {names[i]} = {inputs[k, i]:.6g} "
            f"{units[i]} at t = {times[k]:.3f} s against {bound:.6g} {units[i]} (the limits less the margin), on a "
            f"{1e3 * CHECK_STEP_S:g} ms grid; " + (cause or "give more --intervals"))


def sample(geometry: PathGeometry, solution: Solution, n: int) -> tuple[SampledTrajectory, float]:
    """The tracked point's motion along the solution: σ(t) is exact between nodes (σ̈ held, or linear), so every
    sample is the path's geometry at the retimed σ. Samples at SAMPLE_RATE_HZ inside each interval and at both sides of
    every node (NODE_GAP_S apart, each with its own interval's acceleration): the interpolant between samples
    then never smears a jump of σ̈ over a whole sample period. Also the tracked point's peak jerk over the samples
    (g'''σ̇³ + 3g''σ̇σ̈ + g'σ⃛; between the jumps of a held σ̈)."""
    nodes, N = solution.times, solution.tau_dd.size
    pieces, owner = [], []
    for k in range(N):
        t0, t1 = nodes[k], nodes[k + 1]
        inner = np.linspace(t0, t1, max(2, int(math.ceil((t1 - t0) * SAMPLE_RATE_HZ)) + 1))
        inner[0] = t0 + (NODE_GAP_S if k > 0 else 0.0)
        inner[-1] = t1 - (NODE_GAP_S if k < N - 1 else 0.0)
        pieces.append(inner)
        owner.append(np.full(inner.size, k))
    times, k = np.concatenate(pieces), np.concatenate(owner)
    keep = np.concatenate([[True], np.diff(times) > 0])
    times, k = times[keep], k[keep]
    dt = times - nodes[k]
    tau0, rate0, a = solution.states[k, 2 * n], solution.states[k, 2 * n + 1], solution.tau_dd[k]
    tau_ddd = solution.tau_ddd[k]  # τ̈ linear over the interval (0: held)
    tau = np.clip(tau0 + rate0 * dt + 0.5 * a * dt**2 + tau_ddd * dt**3 / 6.0, 0.0, geometry.end)
    rate = np.maximum(rate0 + a * dt + 0.5 * tau_ddd * dt**2, 0.0)
    rows, jerk = geometry.signals(tau, rate, a + tau_ddd * dt, tau_ddd)
    ns, p = geometry.n_signals, geometry.layout.path_signal
    pick = [slice(p, p + 4), slice(ns + p, ns + p + 4), slice(2 * ns + p, 2 * ns + p + 4)]
    position, velocity, acceleration = (rows[:, s] for s in pick)
    return SampledTrajectory(times, position, velocity, acceleration), float(np.linalg.norm(jerk, axis=1).max())


def check_plannable(path, rate_hz: float) -> None:
    """TrajectoryError for a path `plan` cannot retime: longer than a run may be (the plan is sampled and certified
    like a run, SETTLE_AFTER_END_S past its end: a 163-byte file ending at t = 1e6 s took 10 GB), or one whose
    tracked point never moves."""
    steps = (path.duration + SETTLE_AFTER_END_S) * rate_hz
    if steps > MAX_CONTROL_STEPS:
        raise TrajectoryError(f"the path lasts {path.duration:g} s, {steps:,.0f} control steps at {rate_hz:g} Hz with "
                              f"the {SETTLE_AFTER_END_S:g} s the certificate flies after it, more than the "
                              f"{MAX_CONTROL_STEPS:,} a run may have: plan a shorter path")
    if motion_time_scale(path, path.duration) == float("inf"):
        raise TrajectoryError("the path's tracked point never moves: nothing to retime (the yaw alone is not "
                              "planned)")
