"""The fastest timing of a path under the input limits: a time-optimal control problem over the path parameter σ
(acroboter.planning.geometry), solved by direct shooting with IPOPT (casadi.Opti; L-BFGS, else the exact Hessian).

Decision variables: the duration T_j of each phase (each edge of a waypoint path; a user trajectory is one phase)
and, on a grid of intervals of T_j / N_j per phase, the path acceleration σ̈ held over each interval (or, smooth,
linear). The state x = (q, q̇, σ, σ̇) is the integration of the ideal motion's dynamics from the static start
(acroboter.planning.ideal_motion: σ ≡ 0 for the servo-constraints, so the connector's swing is integrated as the
internal dynamics it is, not assumed at rest; RK4, `substeps` steps per interval). Single shooting: the internal
dynamics are stable and damped, and with the redundant natural coordinates as variables (multiple shooting)
IPOPT wandered. Constraints:

- each phase ends where it should (σ = its end) and, at a corner of a waypoint path, at rest (σ̇ = 0);
  the path ends at rest (σ̇ = 0) unless the path itself is at rest there (g' = 0);
- σ̇ ≥ 0 (the path is not run backwards);
- every input with a finite limit within its limits tightened by the margin (acroboter.planning.limits),
  at the start and the end of every RK4 step;
- optionally the tracked point's speed, acceleration and jerk bounded at every node.

Objective: T. The uniform slowdown of the path's own timing that is just feasible (a bisection with the
same dynamics) is the starting guess: it is feasible, so the solution can only be faster.
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from ..process.cores import usable_cores
from ..process.interrupts import interrupt_pending
from .geometry import PathGeometry, point_bounds
from .ideal_motion import IdealDynamics, PlanningError, SolveFailed, inputs_at, rk4_step
from .limits import best_spare, beyond_bounds, spare_constraints
from .servo_lag import CORNER_LAG_SHARE, lag_bounds, lag_substeps

# The uniform slowdown's check: interval of the integration (s) and RK4 steps per interval.
CHECK_INTERVAL_S = 0.1
CHECK_SUBSTEPS = 2
# Slowdown factors the bisection searches (the path's own timing x factor).
MAX_SLOWDOWN = 1000.0
BISECTION_RELATIVE = 1e-3
# When to stop: the timing feasible (constraints to 1e-8), complementary, and the duration no longer
# changing (relative 1e-7 over 5 iterations). The dual error is left out on purpose: inputs that reach their
# limits together (the three winches of a symmetric lift) make the multipliers non-unique, and IPOPT's dual
# error then stalls far from zero while the duration has long converged.
ACCEPTABLE = {"acceptable_tol": 1e3, "acceptable_iter": 5, "acceptable_constr_viol_tol": 1e-8,
              "acceptable_compl_inf_tol": 1e-6, "acceptable_obj_change_tol": 1e-7}
# IPOPT's answers that are its optimum; any other (a fallback kept, out of iterations) is reported as not planned.
OPTIMAL = ("Solve_Succeeded", "Solved_To_Acceptable_Level")
# A solve that fails (Error_In_Step_Computation on the tests' lift at 8 intervals, where IPOPT's monotone barrier
# update stalled) is tried again with these options: the adaptive barrier solved it (46 iterations, 0.8637 s where
# the fallback kept 1.164 s; measured 2026-12-06).
RETRY = {"mu_strategy": "adaptive"}
# A solve is first tried with L-BFGS: an iteration then costs no exact Hessian of the single-shooting chain (3/4 of
# a solve's time). The lift at 8, 24, 48 intervals: 6.9, 16, 136 s against 13, 157, 805 s, the durations 2.3e-5,
# 3e-7, 6e-7 apart. The paper's path at [5, 60] N: 7 of 10 edges in 10-694 iterations, no faster in all (2026-12-07).
# Not solved in LBFGS_ITER_FACTOR times the iterations given, at most LBFGS_MAX_ITER: the exact Hessian, then RETRY.
LBFGS = {"hessian_approximation": "limited-memory"}
LBFGS_ITER_FACTOR, LBFGS_MAX_ITER = 3, 250
# The longest RK4 step of the problem's integration (s).
MAX_STEP_S = 0.1
# An edge planned to end at rest (acroboter.planning.edges) ends with every coordinate within this of the static
# configuration there and every rate within this per second (m and unit vectors: a centimetre, a centimetre per
# second).
REST_TOL = 1e-2
# With a tolerance, at most this times the lag bound: a corner's swing drives the next edge's lag unseen (drawn path 0
# at 0.1 mm flew its third edge at 0.176 mm with a 10 mm box, 0.108 mm with 1 mm: docs/planning.md, 2026-12-07).
REST_TOL_PER_LAG_BOUND = 10.0
# The fewest intervals a phase (an edge of a waypoint path) gets.
MIN_PHASE_INTERVALS = 6


class SolveCancelled(Exception):
    """A solve stopped because the plan was stopped (Ctrl-C in the main thread while edges are solved on others)."""


def _stopper(cancelled: threading.Event):
    """IPOPT's iteration callback: a Ctrl-C (SIGTERM, SIGHUP) received meanwhile, or `cancelled` set (the main thread
    stopped while this solve runs on another), stops the solve (the exception ends it as User_Requested_Stop; the
    signal is raised as CasADi returns, acroboter.process.interrupts). Without a Python callback no Python runs
    inside the solve, and Ctrl-C waited for its end (8-11 s)."""
    def stop(iteration: int) -> None:
        if interrupt_pending() or cancelled.is_set():
            raise KeyboardInterrupt
    return stop


@dataclass
class Solution:
    """The optimiser's answer on its grid: node times, states (nodes x (2n + 2)), τ̈ per interval, the inputs
    at the start of every RK4 step (steps x l) with their times, IPOPT's status and the wall time."""

    duration: float
    times: np.ndarray
    states: np.ndarray
    tau_dd: np.ndarray
    input_times: np.ndarray
    inputs: np.ndarray
    status: str
    iterations: int
    solve_s: float
    uniform_slowdown: float  # the best uniform slowdown factor of the path's own timing (feasible)
    uniform_duration: float
    windows: list[dict] = field(default_factory=list)  # per solve: phases, intervals, RK4 steps, iterations, s
    tau_ddd: np.ndarray | None = None  # the jerk of τ per interval (τ̈ linear over it; zeros: τ̈ held)

    def __post_init__(self):
        if self.tau_ddd is None:
            self.tau_ddd = np.zeros_like(self.tau_dd)


@dataclass
class Part:
    """One solve over consecutive phases (or their committed concatenation): the phases' durations, σ̈ per
    interval, the node states (nodes x (2n + 2)), the inputs at every RK4 step start and at the end."""

    durations: np.ndarray
    tau_dd: np.ndarray
    states: np.ndarray
    inputs: np.ndarray
    status: str
    iterations: int
    windows: list[dict]
    substeps: list[int]  # RK4 steps per interval, per phase
    tau_ddd: np.ndarray | None = None  # the jerk of τ per interval (zeros: τ̈ held)
    lag_end: np.ndarray | None = None  # the lag model's state (e, ė) at the end (a plan to a tolerance)

    def __post_init__(self):
        if self.tau_ddd is None:
            self.tau_ddd = np.zeros_like(self.tau_dd)


def solution_of(part: Part, counts: list[int], solve_s: float, factor: float, uniform_duration: float) -> Solution:
    """The Solution of a whole path's Part (`counts` intervals per phase): its node times and the times of its inputs
    (every RK4 step's start, and the end)."""
    h = np.repeat(part.durations / np.asarray(counts), counts)
    times = np.concatenate([[0.0], np.cumsum(h)])
    per = np.repeat(part.substeps, counts)  # RK4 steps of each interval
    starts = [t0 + np.arange(m) * (dt / m) for t0, dt, m in zip(times[:-1], h, per, strict=True)]
    input_times = np.concatenate([*starts, [times[-1]]])
    return Solution(float(np.sum(part.durations)), times, part.states, part.tau_dd, input_times, part.inputs,
                    part.status, part.iterations, solve_s, factor, uniform_duration, part.windows, part.tau_ddd)


class Retiming:
    """The problem for one crane, path and set of bounds; `solve(intervals)` returns a Solution."""

    def __init__(self, dynamics: IdealDynamics, geometry: PathGeometry, q0: np.ndarray, lower: np.ndarray,
                 upper: np.ndarray, substeps: int = 2, max_speed: float | None = None,
                 max_accel: float | None = None, max_jerk: float | None = None, lag: tuple | None = None):
        self.dyn, self.geo = dynamics, geometry
        self.n = dynamics.layout.n
        self.x0 = np.concatenate([q0, np.zeros(self.n)])
        self.lower, self.upper = np.asarray(lower, float), np.asarray(upper, float)
        self.substeps = substeps
        self.max_speed, self.max_accel, self.max_jerk = max_speed, max_accel, max_jerk
        # (bound m, kp, kd, period): the sampled controller's lag kept within the bound (acroboter.planning.servo_lag)
        self.lag = lag
        self.rest_tol = REST_TOL if lag is None else min(REST_TOL, REST_TOL_PER_LAG_BOUND * float(lag[0]))  # the box
        # with a jerk bound or a lag bound the timing is smooth: τ̈ continuous, linear over each interval, 0 where a
        # phase starts and ends (a sampled controller holds its input between samples: a jump of τ̈ is what it
        # follows worst)
        self.smooth = max_jerk is not None or lag is not None
        self.step = rk4_step(dynamics, geometry, substeps)
        _, d_start, _ = geometry.evaluate([0.0])
        _, d_end, _ = geometry.evaluate([geometry.end])
        # must τ̇ be 0 at an end? only where the path's own timing moves there
        self.rest_start = bool(np.abs(d_start).max() > 1e-9)
        self.rest_end = bool(np.abs(d_end).max() > 1e-9)
        self._check_cache: dict[tuple[int, int], ca.Function] = {}  # (intervals, RK4 steps each) -> mapaccum
        self._steps: dict[int, ca.Function] = {}
        self.phase_slowdown: tuple[list[float], float] | None = None  # set by a windowed solve
        self.ipopt: dict = {}  # extra IPOPT options
        # a smooth timing's starting guess from an earlier solve on the same grid (planner.warm_start): σ̈ at each
        # phase's nodes and each phase's duration
        self.warm: tuple[list[np.ndarray], list[float]] | None = None
        # set when the plan is stopped: every solve running on another thread ends at its next iteration
        self.cancelled = threading.Event()
        # independent solves (rest-to-rest edges) run side by side on this many threads: the usable cores
        self.workers = usable_cores()

    # --- the uniform slowdown: a lower-bound check and the starting guess ---------------------------
    def uniform(self, factor: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The ideal motion along the path's own timing slowed by `factor`: node states, inputs at every RK4
        step start (steps x l) and their times (σ̈ held per interval at its value mid-interval)."""
        duration = factor * self.geo.path_duration
        count = max(2, int(math.ceil(duration / CHECK_INTERVAL_S)))
        h = duration / count
        _, rate0, _ = self.geo.own_timing([0.0])
        _, _, acc = self.geo.own_timing((np.arange(count) + 0.5) * h / factor)
        x0 = np.concatenate([self.x0, [0.0, rate0[0] / factor]])
        states, inputs = self.run_grid(x0, acc / factor**2, h, CHECK_SUBSTEPS)
        times = np.arange(inputs.shape[0]) * h / CHECK_SUBSTEPS
        return states, inputs, times

    def run_grid(self, x0: np.ndarray, acc: np.ndarray, h: float, substeps: int,
                 final: bool = False, jerk: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The ideal motion from x0 with σ̈ = acc[i] (+ jerk[i]·t) over interval i of h seconds, `substeps` RK4 steps
        each: (the node states, (count + 1) x (2n + 2); the inputs at every RK4 step start, and at the end if
        `final`, steps x l, with the spare input chosen inside the bounds: fit_spare)."""
        acc = np.asarray(acc, float)
        jerk = np.zeros_like(acc) if jerk is None else np.asarray(jerk, float)
        key = (acc.size, substeps)
        if key not in self._check_cache:
            self._check_cache[key] = self.stepper(substeps).mapaccum(acc.size)
        xs, us, ds, _, _, _ = self._check_cache[key](x0, acc[None, :], jerk[None, :], h)
        states = np.vstack([np.asarray(x0, float)[None, :], np.asarray(xs).T])
        base, directions = np.asarray(us).T, np.asarray(ds).T
        if final:
            u_end, d_end = inputs_at(self.dyn, self.geo, states[-1], acc[-1] + jerk[-1] * h)
            base, directions = np.vstack([base, np.asarray(u_end).T]), np.vstack([directions, np.asarray(d_end).T])
        return states, self.fit_spare(base, directions)

    def fit_spare(self, base: np.ndarray, directions: np.ndarray) -> np.ndarray:
        """The inputs (steps x l, the spare input at 0 in `base`) with the spare input chosen to keep them inside the
        bounds (limits.best_spare); `directions`: their change per unit of the spare input (steps x l)."""
        return best_spare(base, np.asarray(directions)[:, :, None][:, :, : self.dyn.spares], self.lower, self.upper)

    def excess(self, inputs: np.ndarray) -> float:
        """The largest step of any input beyond its (tightened) limits, relative to the limits' span (≤ 0: within)."""
        over = beyond_bounds(inputs, self.lower, self.upper)
        return float(np.max(over)) if over.size else -math.inf

    def kinematic_factor(self, phase: int | None = None) -> float:
        """The smallest slowdown of the path's own timing (or of one phase's) that keeps the tracked point within
        max_speed, max_accel and max_jerk (0 without them): the own timing's peaks divided by f, f² and f³."""
        factor = 0.0
        if self.max_speed is not None or self.max_accel is not None or self.max_jerk is not None:
            speed, accel, jerk = self.geo.own_peaks(phase)
            if self.max_speed is not None:
                factor = max(factor, speed / self.max_speed)
            if self.max_accel is not None:
                factor = max(factor, math.sqrt(accel / self.max_accel))
            if self.max_jerk is not None:
                factor = max(factor, (jerk / self.max_jerk) ** (1.0 / 3.0))
        return factor * (1.0 + BISECTION_RELATIVE)

    def best_uniform(self) -> float:
        """The smallest slowdown factor (within BISECTION_RELATIVE) whose ideal motion keeps every input within
        the tightened limits, by bisection, and the tracked point within max_speed and max_accel;
        PlanningError when none up to MAX_SLOWDOWN does."""
        return max(self._input_uniform(), self.kinematic_factor())

    def _input_uniform(self) -> float:
        low, high = None, 1.0
        while self.excess(self.uniform(high)[1]) > 0:
            low, high = high, 2.0 * high
            if high > MAX_SLOWDOWN:
                raise PlanningError(f"no uniform slowdown of the path up to {MAX_SLOWDOWN:g}x keeps the inputs within "
                                    "the limits with the margin: the path's statics are too close to a limit")
        if low is None:  # the path's own timing is feasible: search faster timings
            low = 1.0
            while self.excess(self.uniform(low)[1]) <= 0:
                high, low = low, low / 2.0
                if low < 1e-3:
                    if self.max_speed is not None or self.max_accel is not None or self.max_jerk is not None:
                        return low  # the kinematic bounds bound it (best_uniform)
                    raise PlanningError("the path is feasible at a thousandth of its own timing: the limits do not "
                                        "bound this motion; give max_speed / max_accel (--max-speed, --max-accel)")
        while high - low > BISECTION_RELATIVE * high:
            mid = 0.5 * (low + high)
            if self.excess(self.uniform(mid)[1]) > 0:
                low = mid
            else:
                high = mid
        return high

    # --- the optimal control problem ----------------------------------------------------------------
    def grid(self, intervals: int) -> list[int]:
        """Intervals per phase: in proportion to the phase's own time, at least MIN_PHASE_INTERVALS."""
        own = np.array([T for _, _, T in self.geo.phases])
        return [max(MIN_PHASE_INTERVALS, int(round(intervals * T / own.sum()))) for T in own]

    def phase_counts(self, intervals: int) -> list[int]:
        """The intervals of each phase in a solve on `intervals` (`grid`)."""
        return self.grid(intervals)

    def solve(self, intervals: int, guess_factor: float | None = None, max_iter: int = 400,
              verbose: bool = False) -> Solution:
        """The fastest timing on `intervals` intervals: the whole path in one problem (`solve_all`; a receding
        window over its phases in acroboter.planning.windows.WindowedRetiming)."""
        started = time.perf_counter()
        factor = self.best_uniform() if guess_factor is None else guess_factor
        uniform_duration = factor * self.geo.path_duration
        counts = self.grid(intervals)
        phases = self.geo.phases
        # RK4 steps per interval: none longer than MAX_STEP_S at the starting guess (the Baumgarte terms and the
        # connector's swing are not resolved by longer ones; RK4 turns unstable near 2.8 / Ω)
        longest = factor * max(T / c for (_, _, T), c in zip(phases, counts, strict=True))
        self.substeps = max(self.substeps, int(math.ceil(longest / MAX_STEP_S)))
        self.step = self.stepper(self.substeps)
        x0 = np.concatenate([self.x0, [0.0, 0.0]])
        part = self.solve_all(x0, counts, factor, uniform_duration, max_iter, verbose)
        duration = float(np.sum(part.durations))
        if duration <= 1.001e-3 * uniform_duration:
            raise PlanningError("the limits do not bound this motion (the fastest timing is as short as allowed): "
                                "give max_speed / max_accel (--max-speed, --max-accel)")
        return solution_of(part, counts, time.perf_counter() - started, factor, uniform_duration)

    def solve_all(self, x0: np.ndarray, counts: list[int], factor: float, uniform_duration: float,
                  max_iter: int = 400, verbose: bool = False) -> Part:
        """Every phase in one problem from the static start, from the best uniform slowdown (or, one phase with a
        warm start, from that)."""
        if self.warm is not None and len(self.geo.phases) == 1:
            return self.solve_phases(x0, [0], counts, self.warm[0][0], self.warm[1][:1], uniform_duration, max_iter,
                                     verbose)
        _, guess_a = self._guess(factor, counts)
        return self.solve_phases(x0, list(range(len(self.geo.phases))), counts, guess_a,
                                 [factor * T for _, _, T in self.geo.phases], uniform_duration, max_iter, verbose)

    def solve_phases(self, x_start: np.ndarray, which: list[int], counts: list[int], guess_a: np.ndarray,
                     guess_T, uniform_duration: float, max_iter: int = 400, verbose: bool = False,
                     substeps: int | None = None, tail_s: float = 0.0, rest_at: np.ndarray | None = None,
                     lag_start: np.ndarray | None = None, retry: bool = True) -> Part:
        """The time-optimal problem over the consecutive phases `which` (indices into the path's phases), from the
        state x_start at the first one's start (σ there, σ̇ = 0 unless the path starts there). The inputs are kept
        at the start of every RK4 step, and at the end of the last phase. `tail_s` > 0: the path then held at rest
        at its corner for tail_s seconds with the inputs within the bounds too (the swing the phases leave must
        not take an input beyond them while the next phase starts: acroboter.planning.windows). `rest_at` (a
        configuration q): the last phase ends there at rest, |q − rest_at|∞ ≤ rest_tol and |q̇|∞ ≤ rest_tol / s
        (acroboter.planning.edges). `lag_start`: the lag model's state at the start (a plan to a tolerance; default
        none: no lag)."""
        n, phases = self.n, self.geo.phases
        substeps = self.substeps if substeps is None else substeps
        step = self.stepper(substeps)
        sub = [counts[j] for j in which]
        N = sum(sub)
        opti = ca.Opti()
        durations = opti.variable(len(which))
        steps = ca.horzcat(*[ca.repmat(durations[i] / c, 1, c) for i, c in enumerate(sub)])
        boundaries = np.concatenate([[0], np.cumsum(sub)])
        A, J, nodes_a = self._accelerations(opti, N, steps, boundaries, guess_a)
        # single shooting: the states are the integration of the dynamics from x_start (the internal dynamics
        # are stable and damped; without the states as variables IPOPT sees a problem in the timing alone, which
        # it solves reliably, where multiple shooting's many redundant states of the natural coordinates made it
        # wander)
        x0 = ca.DM(x_start)
        x_end, inputs, directions, ends, d_ends, servo_rate = step.mapaccum(N)(x0, A, J, steps)
        X = ca.horzcat(x0, x_end)
        for i, j in enumerate(which):  # each phase from its start to its end
            start, stop, _ = phases[j]
            if i > 0:
                opti.subject_to(X[2 * n, boundaries[i]] == start)
            opti.subject_to(X[2 * n, boundaries[i + 1]] == stop)
            if self.geo.edges:  # a corner: at rest
                opti.subject_to(X[2 * n + 1, boundaries[i + 1]] == 0)
        opti.subject_to(X[2 * n + 1, 1:] >= 0)
        final = which[-1] == len(phases) - 1
        if final and self.rest_end:
            opti.subject_to(X[2 * n + 1, N] == 0)
        last, last_direction = inputs_at(self.dyn, self.geo, X[:, N], nodes_a[N])
        u_all, d_all = ca.horzcat(inputs, last), ca.horzcat(directions, last_direction)
        bounded, d_bounded = ca.horzcat(u_all, ends), ca.horzcat(d_all, d_ends)  # each interval's end too
        if tail_s > 0:
            count = max(1, int(math.ceil(tail_s / (substeps * MAX_STEP_S))))
            _, held, d_held, _, _, _ = step.mapaccum(count)(X[:, N], ca.DM.zeros(1, count), ca.DM.zeros(1, count),
                                                         ca.DM.ones(1, count) * (tail_s / count))
            bounded, d_bounded = ca.horzcat(bounded, held), ca.horzcat(d_bounded, d_held)
        if self.dyn.spares:  # some internal force keeps the inputs within the bounds (limits.spare_constraints)
            for expr, low in spare_constraints(bounded, d_bounded, self.lower, self.upper, self.dyn.spare_signs,
                                               self.dyn.spare_at_rest):
                opti.subject_to(expr >= low)
        else:
            for i in range(self.lower.size):
                if math.isfinite(self.upper[i]):
                    opti.subject_to(bounded[i, :] <= self.upper[i])
                if math.isfinite(self.lower[i]):
                    opti.subject_to(bounded[i, :] >= self.lower[i])
        if rest_at is not None:
            # a box on every coordinate and its rate, not one sum of squares: its gradient vanishes at rest, and
            # IPOPT then crawls
            opti.subject_to(opti.bounded(-self.rest_tol, X[:n, N] - rest_at, self.rest_tol))
            opti.subject_to(opti.bounded(-self.rest_tol, X[n : 2 * n, N], self.rest_tol))
        point_bounds(opti, self.geo, X[2 * n, :], X[2 * n + 1, :], nodes_a, J,
                     (self.max_speed, self.max_accel, self.max_jerk))
        if self.lag is not None:
            # each RK4 step of the ideal motion in lag steps short enough for the servo law's poles (twice the guess's
            # length: room for the solve to slow down)
            longest = 2.0 * max(T / (c * substeps) for T, c in zip(guess_T, sub, strict=True))
            z0 = np.zeros(6) if lag_start is None else lag_start
            lag_end = lag_bounds(opti, self.lag, servo_rate, steps, substeps, lag_substeps(longest, *self.lag[1:3], 1),
                                 z0, 1.0 if final else CORNER_LAG_SHARE)
        opti.subject_to(durations >= 1e-3 * uniform_duration / len(phases))
        total = ca.sum1(durations)
        opti.minimize(total)
        opti.set_initial(durations, list(guess_T))
        started = time.perf_counter()
        value, hessian, tried = self._solved(opti, max_iter, verbose, uniform_duration, retry)
        stats = opti.stats()
        record = {"phases": [int(j) for j in which], "intervals": N, "rk4_steps": N * substeps, "substeps": substeps,
                  "iterations": int(stats["iter_count"]), "solve_s": time.perf_counter() - started,
                  "status": stats.get("return_status", ""), "hessian": hessian, "tried": tried}
        chosen = self.fit_spare(np.asarray(value(u_all)).T, np.asarray(value(d_all)).T)
        jerk = np.asarray(value(J)).ravel() if self.smooth else np.zeros(N)
        return Part(np.asarray(value(durations)).ravel(), np.asarray(value(A)).ravel(), np.asarray(value(X)).T,
                    chosen, record["status"], record["iterations"], [record],
                    [substeps] * len(which), jerk,
                    np.asarray(value(lag_end)).ravel() if self.lag is not None else None)

    def _accelerations(self, opti: ca.Opti, N: int, steps, boundaries: np.ndarray, guess_a) -> tuple:
        """The timing's variables: σ̈ at each interval's start (A), its jerk over the interval (J) and σ̈ at each node
        (the last: the end's). Held per interval (J = 0), or with a smooth timing σ̈ at the nodes, linear in between,
        0 where each phase starts and ends. `guess_a`: σ̈ per interval (at a node, a smooth timing starts from the
        mean of its two intervals'), or at the nodes."""
        guess_a = np.asarray(guess_a, float)
        if not self.smooth:
            A = opti.variable(1, N)
            opti.set_initial(A, guess_a[None, :])
            return A, ca.DM.zeros(1, N), [A[min(k, N - 1)] for k in range(N + 1)]
        B = opti.variable(1, N + 1)
        for b in boundaries:
            opti.subject_to(B[int(b)] == 0)
        if guess_a.size == N:
            guess_a = np.concatenate([[0.0], 0.5 * (guess_a[:-1] + guess_a[1:]), [0.0]])
            guess_a[boundaries] = 0.0
        opti.set_initial(B, guess_a[None, :])
        return B[:, :N], (B[:, 1:] - B[:, :N]) / steps, [B[k] for k in range(N + 1)]

    def _solved(self, opti: ca.Opti, max_iter: int, verbose: bool, uniform_duration: float, retry: bool = True):
        """IPOPT on the problem, with its stopping rule (ACCEPTABLE) and the Ctrl-C poll: `value` of the answer.
        Tried with L-BFGS (LBFGS) first; what that does not solve, with the exact Hessian from the same start, then
        once more with RETRY's options (the adaptive barrier) unless `retry` is False. Returns the answer, the Hessian
        that gave it and the attempts before it (Hessian, status, iterations: their time is in the solve's). Out of
        iterations at a point that meets the constraints (exact Hessian) is a feasible timing (reported as not
        optimal by its status); anything else is a PlanningError."""
        tried: list[dict] = []
        for attempt in (LBFGS, {}, RETRY) if retry else (LBFGS, {}):
            opti.callback(_stopper(self.cancelled))  # Ctrl-C within an iteration, not at the solve's end
            iterations = min(LBFGS_ITER_FACTOR * max_iter, LBFGS_MAX_ITER) if attempt is LBFGS else max_iter
            opti.solver("ipopt", {"print_time": False},
                        {"print_level": 5 if verbose else 0, "max_iter": iterations, "tol": 1e-8, "sb": "yes",
                         "constr_viol_tol": 1e-9, **ACCEPTABLE, **self.ipopt, **attempt})
            try:
                return opti.solve().value, "limited-memory" if attempt is LBFGS else "exact", tried
            except RuntimeError as err:
                if self.cancelled.is_set():
                    raise SolveCancelled("the plan was stopped") from None
                stats = opti.stats()
                if attempt is not LBFGS and stats.get("return_status") == "Maximum_Iterations_Exceeded" and \
                        stats["iterations"]["inf_pr"][-1] < 1e-7:
                    return opti.debug.value, "exact", tried
                tried.append({"hessian": "limited-memory" if attempt is LBFGS else "exact",
                              "status": str(stats.get("return_status", err)), "iterations": stats.get("iter_count")})
        first, last = tried[0], tried[-1]
        raise SolveFailed(f"{last['status']} after {last['iterations']} iterations" +
                          (f", also with {RETRY}" if retry else "") +
                          f"; L-BFGS first: {first['status']} after {first['iterations']}", uniform_duration)

    def inputs_on_grid(self, solution: Solution, step_s: float) -> tuple[np.ndarray, np.ndarray]:
        """The ideal inputs along a solution every `step_s` seconds at most (times, steps x l): what lies between the
        optimiser's (coarser) RK4 steps, its timing integrated again from the start the whole way (its node states
        carry its RK4 error: on a jerk-bounded lift an input 1.65 mN past the bound the solve kept, 2026-12-07)."""
        h = np.diff(solution.times)
        m = max(1, int(math.ceil(h.max() / step_s)))
        key = ("chain", h.size, m)
        if key not in self._check_cache:
            self._check_cache[key] = self.stepper(m).mapaccum(h.size)
        _, us, ds, _, _, _ = self._check_cache[key](solution.states[0], solution.tau_dd[None, :],
                                                  solution.tau_ddd[None, :], h[None, :])
        base, directions = np.asarray(us).T, np.asarray(ds).T  # interval by interval, m steps each
        times = (solution.times[:-1, None] + np.arange(m)[None, :] * (h[:, None] / m)).ravel()
        inputs = self.fit_spare(base, directions)
        return np.append(times, solution.times[-1]), np.vstack([inputs, solution.inputs[-1:]])

    def stepper(self, substeps: int) -> ca.Function:
        """One interval with `substeps` RK4 steps (rk4_step), built once per count."""
        if substeps not in self._steps:
            self._steps[substeps] = rk4_step(self.dyn, self.geo, substeps)
        return self._steps[substeps]

    def _guess(self, factor: float, counts: list[int]) -> tuple[np.ndarray, np.ndarray]:
        """The uniform slowdown on the problem's grid: states at the nodes and σ̈ per interval."""
        own_steps = np.concatenate([np.full(c, T / c) for (_, _, T), c in zip(self.geo.phases, counts, strict=True)])
        own_nodes = np.concatenate([[0.0], np.cumsum(own_steps)])
        _, rate0, _ = self.geo.own_timing([0.0])
        _, _, acc = self.geo.own_timing(0.5 * (own_nodes[:-1] + own_nodes[1:]))
        acc = acc / factor**2
        x = np.concatenate([self.x0, [0.0, rate0[0] / factor]])
        rows = [x]
        for a, h in zip(acc, own_steps * factor, strict=True):
            x = np.asarray(self.step(x, a, 0.0, h)[0]).ravel()
            rows.append(x)
        return np.array(rows), acc
