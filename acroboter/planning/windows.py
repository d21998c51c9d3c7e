"""The receding window over the phases of a long path: WindowedRetiming, a Retiming
(acroboter.planning.retiming) whose `solve` optimises `window` phases at a time.

A waypoint path's phases (its edges) meet at corners where the path speed is 0, but the connector's swing
(q, q̇) carries over from one phase into the next. The whole path in one single-shooting problem has an exact
Hessian over every RK4 step of the path (about a thousand on the default path: minutes per IPOPT iteration).
The window solves phases j .. j + w − 1 together from the committed end state of phase j − 1, commits phase j
(its duration and σ̈; its end state, swing included, is the next window's start), and moves on by one phase;
the last window commits all of its phases. Each window is a small problem: its own phases' RK4 steps and
decision variables, its RK4 steps per interval chosen for its own durations (none longer than MAX_STEP_S;
re-solved with more when the solution's are longer), followed by the path held at rest at its last corner
for WINDOW_TAIL_S with the inputs within the bounds (the swing it leaves must leave the next window a start).

The warm start is the phase-wise slowdown: each edge's own quintic timing slowed by the smallest factor that
keeps the inputs within the bounds from the state the edges before it leave (a bisection per edge, the swing
carried over); it is feasible, so its duration is a second upper bound besides the best uniform slowdown. A
window's phases it shares with the previous window start from that window's answer, and the phase that enters
from the phase-wise factor found again from the state that answer leaves (its swing would otherwise make the
warm start infeasible, and IPOPT crawl out of it).

What a window cannot see is the cost its end state (the swing it leaves) puts on the phases after it; a wider
window sees more of it. docs/planning.md reports how much the duration changes from w = 2 to w = 3.
"""

from __future__ import annotations

import math

import numpy as np

from .ideal_motion import PlanningError
from .retiming import CHECK_INTERVAL_S, CHECK_SUBSTEPS, MAX_SLOWDOWN, MAX_STEP_S, Part, Retiming

# The phase-wise slowdown's bisection: relative resolution of each edge's factor.
PHASE_BISECTION = 1e-2
# A window that does not reach the path's end is followed by the path held at rest at its last corner for this
# long with the inputs within the bounds: the connector's swing, barely damped (the default crane's period is
# about 2.8 s, its decay time about a minute), would otherwise leave the next phase no feasible start.
WINDOW_TAIL_S = 3.0
# IPOPT's iterations per window: a window that needs more (it crawls near feasibility, as a barely damped swing
# makes it) keeps its first phase's own timing slowed (quintic_part) instead: feasible, and said in the summary.
WINDOW_MAX_ITER = 150


def phase_uniform(problem, x_start: np.ndarray, j: int, factor: float) -> tuple[np.ndarray, np.ndarray]:
    """Phase j's own timing slowed by `factor` from x_start: (the end state, the inputs at every step start)."""
    geo = problem.geo
    start, _, T = geo.phases[j]
    duration = factor * T
    count = max(2, int(math.ceil(duration / CHECK_INTERVAL_S)))
    h = duration / count
    t0 = geo.path.edge_t0[j] if geo.edges else 0.0
    _, _, acc = geo.own_timing(t0 + (np.arange(count) + 0.5) * h / factor)
    x = np.array(x_start, float)
    x[-2:] = start, 0.0
    states, inputs = problem.run_grid(x, acc / factor**2, h, CHECK_SUBSTEPS)
    return states[-1], inputs


def phase_factor(problem, x: np.ndarray, j: int, high: float) -> float:
    """The smallest factor (within PHASE_BISECTION) of phase j's own timing that keeps the inputs within the bounds
    from the state x, and the tracked point within max_speed and max_accel; PlanningError when none up to
    MAX_SLOWDOWN does."""
    def feasible(f):
        return problem.excess(phase_uniform(problem, x, j, f)[1]) <= 0

    hi = high
    while not feasible(hi):
        hi *= 2.0
        if hi > MAX_SLOWDOWN:
            raise PlanningError(f"no slowdown of phase {j + 1} up to {MAX_SLOWDOWN:g}x keeps the inputs within the "
                                "limits with the margin from the swing the phases before it leave")
    lo = hi / 2.0
    while lo > 1e-3 and feasible(lo):
        hi, lo = lo, lo / 2.0
    # and the tracked point within max_speed / max_accel (the fallback of an edge IPOPT does not solve is this)
    return max(bisect_factor(feasible, lo, hi, PHASE_BISECTION), problem.kinematic_factor(j))


def bisect_factor(serves, bad: float, good: float, relative: float) -> float:
    """A factor between `bad` (does not serve) and `good` (serves) that serves, within `relative` of the boundary."""
    while good - bad > relative * good:
        mid = 0.5 * (bad + good)
        if serves(mid):
            good = mid
        else:
            bad = mid
    return good


def first_serving(serves, low: float, relative: float, refusal: str) -> float:
    """The smallest factor from `low` up that serves, where serving need not be monotonic in the factor (a residual
    swing beats with its period): `low` if it serves, else doubling until one does (PlanningError(refusal) beyond
    MAX_SLOWDOWN), then bisecting between the last factor found wanting and the first that serves."""
    if serves(low):
        return low
    bad, good = low, 2.0 * low
    while not serves(good):
        bad, good = good, 2.0 * good
        if good > MAX_SLOWDOWN:
            raise PlanningError(refusal)
    return bisect_factor(serves, bad, good, relative)


def phase_slowdown(problem, high: float) -> tuple[list[float], float]:
    """The phase-wise slowdown (see the module's docstring): each phase's factor and the total duration."""
    phases = problem.geo.phases
    x = np.concatenate([problem.x0, [0.0, 0.0]])
    factors = []
    for j in range(len(phases)):
        factors.append(phase_factor(problem, x, j, high))
        x, _ = phase_uniform(problem, x, j, factors[-1])
    return factors, float(sum(f * T for f, (_, _, T) in zip(factors, phases, strict=True)))


def _warm(problem, j: int, count: int, factor: float) -> tuple[np.ndarray, float]:
    """Phase j slowed by `factor` on its `count` intervals: σ̈ per interval and its duration. σ̈ is the own
    timing's at each interval's middle, scaled so that σ, held per interval, ends exactly at the phase's end
    (the midpoints of a quintic's antisymmetric acceleration sum to 0, so σ̇ ends at 0 too)."""
    geo = problem.geo
    start, stop, T = geo.phases[j]
    t0 = geo.path.edge_t0[j] if geo.edges else 0.0
    _, _, acc = geo.own_timing(t0 + (np.arange(count) + 0.5) * T / count)
    acc, h = acc / factor**2, factor * T / count
    reached = float(np.sum(acc * h * h * (count - np.arange(count) - 0.5)))
    return acc * ((stop - start) / reached) if reached > 0 else acc, factor * T


def quintic_part(problem, x: np.ndarray, j: int, count: int, factor: float, final: bool) -> Part:
    """Phase j's own timing slowed by `factor`, from x, on its `count` intervals, as a committed part: what a
    window commits when IPOPT does not solve it (the phase-wise slowdown, feasible by its bisection). σ̈ is the
    quintic's at each interval's middle, scaled so that σ ends exactly at the corner (_warm)."""
    start = problem.geo.phases[j][0]
    acc, T = _warm(problem, j, count, factor)
    h = T / count
    m = _substeps([T], [count])
    x = np.array(x, float)
    x[-2:] = start, 0.0
    states, inputs = problem.run_grid(x, acc, h, m, final)
    if problem.excess(inputs) > 1e-9:
        raise PlanningError(f"phase {j + 1}: IPOPT did not solve its window and its own timing slowed {factor:.4g}x "
                            "is not feasible on the problem's grid either: try more --intervals or a larger margin")
    record = {"phases": [int(j)], "intervals": count, "rk4_steps": count * m, "substeps": m, "iterations": 0,
              "solve_s": 0.0, "status": "quintic_slowdown_kept"}
    return Part(np.array([T]), acc, states, inputs, record["status"], 0, [record], [m])


def _substeps(durations, counts) -> int:
    return max(2, int(math.ceil(max(T / c for T, c in zip(durations, counts, strict=True)) / MAX_STEP_S)))


class WindowedRetiming(Retiming):
    """A Retiming solved by a receding window of `window` phases (see the module's docstring)."""

    def __init__(self, *args, window: int = 2, **kwargs):
        super().__init__(*args, **kwargs)
        self.window = window

    def solve_all(self, x0: np.ndarray, counts: list[int], factor: float, uniform_duration: float,
                  max_iter: int = 400, verbose: bool = False) -> Part:
        return receding(self, x0, counts, factor, uniform_duration, self.window, max_iter, verbose)


def receding(problem, x0: np.ndarray, counts: list[int], factor: float, uniform_duration: float, window: int,
             max_iter: int = 400, verbose: bool = False) -> Part:
    """The committed phases of a receding window of `window` phases (see the module's docstring)."""
    K = len(problem.geo.phases)
    factors, phase_duration = phase_slowdown(problem, factor)
    problem.phase_slowdown = (factors, phase_duration)
    warm_a, warm_T = {}, {}
    for p in range(K):
        warm_a[p], warm_T[p] = _warm(problem, p, counts[p], factors[p])
    durations, timing, states, inputs, records, substeps = [], [], [x0[None, :]], [], [], []
    status, iterations, x, j = "", 0, np.asarray(x0, float), 0
    while j < K:
        which = list(range(j, min(j + window, K)))
        mine = [counts[i] for i in which]
        m = _substeps([warm_T[i] for i in which], mine)
        try:
            while True:
                part = problem.solve_phases(x, which, counts, np.concatenate([warm_a[i] for i in which]),
                                            [warm_T[i] for i in which], uniform_duration,
                                            min(max_iter, WINDOW_MAX_ITER), verbose, m,
                                            0.0 if which[-1] == K - 1 else WINDOW_TAIL_S)
                records += part.windows
                iterations += part.iterations
                needed = _substeps(part.durations, mine)
                if needed <= m:
                    break
                m = needed  # the solution's steps are longer than MAX_STEP_S: again with more, from the answer
                local = np.concatenate([[0], np.cumsum(mine)])
                for i, p in enumerate(which):
                    warm_a[p], warm_T[p] = part.tau_dd[local[i]:local[i + 1]], float(part.durations[i])
        except PlanningError as unsolved:
            # IPOPT gave no answer for this window: its first phase keeps its own timing, slowed from the state
            # it starts in (feasible by the bisection), and the next window starts from there
            factor_j = phase_factor(problem, x, j, factors[j])
            part = quintic_part(problem, x, j, counts[j], factor_j, final=j == K - 1)
            part.windows[0]["reason"] = str(unsolved)
            records += part.windows
            if not status or status == "Solve_Succeeded":
                status = part.status
            durations.append(part.durations)
            timing.append((part.tau_dd, part.tau_ddd))
            states.append(part.states[1:])
            substeps += part.substeps
            inputs.append(part.inputs)
            x = part.states[-1]
            j += 1
            continue
        if not status or status == "Solve_Succeeded":  # the first that is not a success, else success
            status = part.status
        commit = which if which[-1] == K - 1 else which[:1]  # the last window commits all of its phases
        local = np.concatenate([[0], np.cumsum(mine)])
        for i, p in enumerate(which):
            if p not in commit:  # the next window's warm start
                warm_a[p], warm_T[p] = part.tau_dd[local[i]:local[i + 1]], float(part.durations[i])
        stop = local[len(commit)]
        durations.append(part.durations[:len(commit)])
        timing.append((part.tau_dd[:stop], part.tau_ddd[:stop]))
        states.append(part.states[1:stop + 1])
        substeps += [m] * len(commit)
        last = commit[-1] == K - 1
        inputs.append(part.inputs if last else part.inputs[:stop * m])
        x = part.states[stop]
        j = commit[-1] + 1
        entering = which[-1] + 1
        if entering < K:  # slowed from the state this window's answer leaves it, the swing included
            try:
                factor_e = phase_factor(problem, part.states[-1], entering, factors[entering])
                warm_a[entering], warm_T[entering] = _warm(problem, entering, counts[entering], factor_e)
            except PlanningError:  # no slowdown is feasible from there: IPOPT starts from the phase-wise one
                pass
    return Part(np.concatenate(durations), np.concatenate([a for a, _ in timing]), np.vstack(states),
                np.vstack(inputs), status, iterations, records, substeps, np.concatenate([j for _, j in timing]))
