"""Rest-to-rest edges: EdgeRetiming, a Retiming (acroboter.planning.retiming) of a waypoint path whose every edge
starts and ends with the whole crane at rest, the connector's swing included.

Why. The whole path in one single-shooting problem has an exact Hessian over every RK4 step of the path (about
a thousand on the default path: minutes per IPOPT iteration), and the swing a time-optimal edge leaves at a
corner is barely damped (the default crane's period is about 2.8 s, its decay time about a minute): planned
edge by edge with the swing carried over, the next edge can have no feasible timing at all, not even its own
timing slowed a thousand times (measured on the default crane with winch limits [5, 30] N: the first edge's
optimum left a swing that takes a winch beyond its bounds at rest). A crane operator asks for the other thing
anyway: at a waypoint the load is at rest. So each edge is planned from the static equilibrium at its first
corner to within REST_TOL of the static equilibrium at its last corner (closer in a plan to a tolerance:
REST_TOL_PER_LAG_BOUND), at rest: the edges are then independent problems, small (one edge's RK4 steps) and solved
one after the other.

What it costs. The time-optimal timing with the swing free at the corners can only be faster; docs/planning.md
reports the two on a path where both solve. The plan's inputs are not taken from the edges' solves: the whole
path's timing is integrated again from the static start (the small residual swing of each corner carried into
the next edge, as the plant will), and those inputs are the plan's, checked against the bounds.
"""

from __future__ import annotations

import sys
from concurrent.futures import FIRST_EXCEPTION, ThreadPoolExecutor, wait
from dataclasses import dataclass

import numpy as np

from ..runtime.progress import progress_disabled
from .ideal_motion import PlanningError, SolveFailed
from .limits import CHECK_STEP_S, INPUT_TOLERANCE, bound_span
from .retiming import MAX_SLOWDOWN, MIN_PHASE_INTERVALS, OPTIMAL, Part, Retiming
from .windows import PHASE_BISECTION, _substeps, _warm, first_serving, phase_factor

# An edge whose inputs leave the bounds once the chain carries the swing into it is solved again from there at
# most this many times (EdgeRetiming.carried).
CARRY_ROUNDS = 3
# Each of those solves gets at most this many IPOPT iterations and no second try (from an answer nearby they took
# 17-25; one that finds no timing would otherwise take minutes to say so). An edge after which no timing of the next
# one keeps the bounds is solved again with its inputs also bounded over a hold this long at its last corner (s: half
# the default crane's swing period; a constraint on the swing it leaves, not a pause in the plan).
CARRY_MAX_ITER = 60
CARRY_TAIL_S = 1.5
# The quasi-static motion that finds the configuration at rest at a corner lasts at least this long (s).
QUASI_STATIC_S = 120.0


@dataclass
class Edge:
    """One edge's answer: its duration (1 value), σ̈ and σ⃛ per interval, IPOPT's status, the solve records, the
    iterations, and the lag model's state at its end and start (a plan to a tolerance; else None and zeros)."""

    durations: np.ndarray
    tau_dd: np.ndarray
    tau_ddd: np.ndarray
    status: str
    records: list[dict]
    iterations: int
    lag_end: np.ndarray | None
    lag_start: np.ndarray
    substeps: int  # RK4 steps per interval of its solve: the chain integrates it with as many


def replacing(old: Edge, new: Edge) -> Edge:
    """`new`, an edge solved again from where the chain is, carrying `old`'s solve records (marked replaced: the
    plan's status reads the kept solve's) and iterations."""
    new.records = [{**record, "replaced": True} for record in old.records] + new.records
    new.records[-1]["carried_swing"] = True
    new.iterations += old.iterations
    return new


def node_guess(answer: Edge | Part, smooth: bool) -> np.ndarray:
    """An edge's answer (an Edge, or a solve's Part) as a solve's starting guess: σ̈ per interval, or with a smooth
    timing at every node (the end's from the last interval's jerk)."""
    if not smooth:
        return answer.tau_dd
    h = float(answer.durations[0]) / answer.tau_dd.size
    return np.append(answer.tau_dd, answer.tau_dd[-1] + answer.tau_ddd[-1] * h)


def unsolved_record(j: int, counts: list[int], unsolved: PlanningError | str) -> dict:
    """The record of a re-solve in `carried` (edge j from the carried swing, or for a calmer corner) that found no
    timing, kept in the records of the answer that stays: `replaced` marks it as a solve the plan's status does not
    read (EdgeRetiming.stuck says what it means for the plan)."""
    return {"phases": [j], "intervals": counts[j], "iterations": 0, "status": "carried_swing_not_solved",
            "replaced": True, "carried_swing": True, "reason": str(unsolved)}


def worst(above: np.ndarray, below: np.ndarray) -> float:
    """The largest step beyond the bounds on either side (edge_excess's), as a fraction of the span."""
    return max(above.max(initial=-np.inf), below.max(initial=-np.inf))


class EdgeRetiming(Retiming):
    """A Retiming of a waypoint path solved edge by edge, each rest to rest (see the module's docstring)."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        if not self.geo.edges:
            raise PlanningError("rest-to-rest edges need a waypoint path (a trajectory file is one phase)")
        self.corners = [self.x0[: self.n]]
        self.stuck: str | None = None  # why the last plan's carried swing left the bounds (`carried`), or None

    def corner(self, j: int, count: int) -> np.ndarray:
        """The configuration at rest at corner j: the end of the quasi-static motion from corner j − 1 (edge j − 1's
        own timing slowed to at least QUASI_STATIC_S, where the swing it leaves is below 1e-5). Found by
        continuation from the static start, not by a static solve per corner: the yaw's servo-constraint holds at
        ψ and at ψ + π, and a static solve from the spec's nominal pose can land on the turned-round branch."""
        while len(self.corners) <= j:
            k = len(self.corners) - 1
            T = self.geo.phases[k][2]
            x, _ = self.grid_motion(k, count, max(30.0, QUASI_STATIC_S / T), self.corners[k])
            self.corners.append(x[: self.n])
        return self.corners[j]

    def at_rest(self, j: int, q: np.ndarray | None = None) -> np.ndarray:
        """The state (q, q̇, σ, σ̇) at rest at corner j (q: its configuration, else `corner(j)`)."""
        q = self.corner(j, MIN_PHASE_INTERVALS) if q is None else q
        return np.concatenate([q, np.zeros(self.n), [float(j), 0.0]])

    def solve_all(self, x0: np.ndarray, counts: list[int], factor: float, uniform_duration: float,
                  max_iter: int = 400, verbose: bool = False) -> Part:
        K = len(self.geo.phases)
        # the warm start: each edge's own timing slowed by the smallest factor feasible from rest
        factors = [self.rest_factor(j, counts[j], phase_factor(self, self.at_rest(j), j, factor)) for j in range(K)]
        self.phase_slowdown = (factors, float(sum(f * T for f, (_, _, T) in zip(factors, self.geo.phases,
                                                                                strict=True))))
        ends = [self.corner(j + 1, MIN_PHASE_INTERVALS) for j in range(K)]  # in turn: each from the one before
        from tqdm import tqdm

        bar = tqdm(total=K, unit="edge", desc="planning", file=sys.stderr, disable=progress_disabled(), leave=False)

        def solved(j: int, lag: np.ndarray) -> Edge:
            # from rest, not from the state the edge before leaves: the edges are then independent problems, solved
            # side by side; the swing the chain carries over is taken out afterwards (`carried`)
            warm_a, warm_T = _warm(self, j, counts[j], factors[j])
            slowdown = (warm_a, warm_T)
            guess = slowdown if self.warm is None else (self.warm[0][j], self.warm[1][j])
            edge = self._solve_edge(j, counts, self.at_rest(j), guess, slowdown, ends[j], uniform_duration,
                                    max_iter, verbose, lag)
            bar.set_postfix_str(f"edge {j + 1}: {float(edge.durations[0]):.3g} s ({edge.status})")
            bar.update()
            return edge

        if self.lag is not None:  # a plan to a tolerance: the lag model's state is carried from edge to edge
            edges, lag = [], np.zeros(6)
            for j in range(K):
                edges.append(solved(j, lag))
                lag = edges[-1].lag_end if edges[-1].lag_end is not None else lag
        else:  # independent problems: solved side by side (CasADi releases the GIL while IPOPT runs)
            edges = self._side_by_side(solved, K)
        bar.close()
        if self.lag is None:  # a plan to a tolerance is judged by its flights (acroboter.planning.tolerance); mending
            # one edge would leave the next one's lag state stale
            edges = self.carried(x0, counts, edges, ends, uniform_duration, max_iter, verbose)
        status, iterations, records = "", 0, []
        for edge in edges:
            if not status or status == "Solve_Succeeded":
                status = edge.status
            records += edge.records
            iterations += edge.iterations
        return self.chain(x0, counts, np.concatenate([e.durations for e in edges]),
                          np.concatenate([e.tau_dd for e in edges]), status, iterations, records,
                          np.concatenate([e.tau_ddd for e in edges]), [e.substeps for e in edges])

    def _side_by_side(self, solved, K: int) -> list[Edge]:
        """solved(j, no lag) for every edge on up to `workers` threads, in edge order. A Ctrl-C in the main thread
        while they run, or an error in one of them, sets `cancelled`: each running solve stops at its next IPOPT
        iteration, the ones not started never start, and the error is raised once they have."""
        workers = max(1, min(self.workers, K))
        self.cancelled.clear()  # a Ctrl-C repeated while an earlier plan's solves were stopping may have left it set
        if workers == 1:
            return [solved(j, np.zeros(6)) for j in range(K)]
        pool = ThreadPoolExecutor(max_workers=workers, thread_name_prefix="edge")
        try:
            futures = [pool.submit(solved, j, np.zeros(6)) for j in range(K)]
            done, _ = wait(futures, return_when=FIRST_EXCEPTION)  # an edge's error stops the others at once
            for future in done:
                if future.exception() is not None:
                    raise future.exception()
            return [f.result() for f in futures]
        except BaseException:
            self.cancelled.set()
            raise
        finally:
            pool.shutdown(wait=True, cancel_futures=True)
            self.cancelled.clear()

    def carried(self, x0: np.ndarray, counts: list[int], edges: list[Edge], ends: list[np.ndarray],
                uniform_duration: float, max_iter: int, verbose: bool) -> list[Edge]:
        """The edges flown in one chain from x0, as the plant flies them: each corner's residual swing (within
        REST_TOL of rest) carried into the next edge. An edge whose inputs then leave the bounds anywhere on a
        CHECK_STEP_S grid (its solve started at rest, and its time-optimal inputs ride the bounds) is solved again
        from the state the chain reaches there, from its own answer: first with the same bounds, then with them moved
        in by the excess and a fifth, up to CARRY_ROUNDS solves (`_mend`). Where no timing of it keeps the bounds,
        the edge before is solved again once with its inputs also bounded over a CARRY_TAIL_S hold at its corner
        after it (a constraint on the swing it leaves, for a calmer corner; the plan does not stop there), and this
        edge mended from there; if that does not help, the edge before is put back. An edge with no timing that
        keeps the bounds ends the mending: the plan then leaves them whatever follows, and
        planner.solve_within_bounds says where (a small leak between the optimiser's nodes that a re-solve does not
        shrink is left to it too). A plan to a tolerance is not mended (its edges share the lag model's state).
        Measured on the paper's path at [5, 30] N (2026-12-07): a residual swing of 12 mm and 40 mm/s took tension_1
        to 31.34 N against bounds of [6.25, 28.75] N; edges 3 and 4 were mended (each 7-10 s of solve); edge 5, the
        0.1 m climb to the upper square, found no timing from the swing edge 4 leaves, nor after edge 4 with its
        corner's hold bounded."""
        from tqdm import tqdm

        bar = tqdm(total=len(edges), unit="edge", desc="carrying the swing", file=sys.stderr,
                   disable=progress_disabled(), leave=False)
        starts, out, tailed, undo = [np.asarray(x0, float)], [], set(), None
        self.stuck = None
        while len(out) < len(edges):
            j = len(out)
            edge, beyond, x_end, why = self._mend(j, starts[j], edges[j], counts, ends[j], uniform_duration, verbose)
            if undo is not None and undo[0] == j and beyond >= undo[3][1]:
                # the calmer corner did not help this edge: the edge before as it was, and this edge's first mend
                _, out[-1], starts[j], (edge, beyond, x_end, why) = undo
            undo = None
            if why is not None and j > 0 and j - 1 not in tailed:
                # no timing of this edge keeps the bounds from the swing the edge before leaves: that edge again, from
                # where it starts, its inputs also bounded over a CARRY_TAIL_S hold at its corner after it (a
                # constraint on the swing it leaves; the plan does not stop there)
                tailed.add(j - 1)
                try:
                    before = self._solve_edge(j - 1, counts, self._start(starts[j - 1], j - 1),
                                              (node_guess(out[-1], self.smooth), out[-1].durations[0]), None,
                                              ends[j - 1], uniform_duration, CARRY_MAX_ITER, verbose,
                                              out[-1].lag_start, tail_s=CARRY_TAIL_S)
                except PlanningError as unsolved:
                    out[-1].records.append(unsolved_record(j - 1, counts, unsolved))
                else:
                    above, below, x_before = self.edge_excess(starts[j - 1], j - 1, counts[j - 1], before)
                    if before.status in OPTIMAL and worst(above, below) <= INPUT_TOLERANCE:
                        undo = (j, out[-1], starts[j], (edge, beyond, x_end, why))
                        out[-1], starts[j] = replacing(out[-1], before), x_before
                        continue  # this edge again, from the calmer corner
            out.append(edge)
            starts.append(x_end)
            bar.set_postfix_str(f"edge {j + 1}: {float(edge.durations[0]):.3g} s")
            bar.update()
            if why is not None:  # no timing of it holds the bounds: the plan leaves them whatever comes after
                since = float(sum(float(e.durations[0]) for e in out[:j]))
                self.stuck = self._stuck(j, starts[j], why, j - 1 in tailed, since)
                out += edges[j + 1:]
                break
        bar.close()
        return out

    def _start(self, x: np.ndarray, j: int) -> np.ndarray:
        """The chain's state x at edge j's first corner, σ there exactly and σ̇ = 0."""
        start = np.asarray(x, float).copy()
        start[-2:] = self.geo.phases[j][0], 0.0
        return start

    def _mend(self, j: int, x: np.ndarray, edge: Edge, counts: list[int], end: np.ndarray, uniform_duration: float,
              verbose: bool) -> tuple[Edge, float, np.ndarray, str | None]:
        """Edge j flown from the chain's state x, solved again from there while its inputs leave the bounds (see
        `carried`): (the edge kept, its largest step beyond the bounds as a fraction of the span, its end state, why
        it is stuck or None: stuck is beyond the bounds, and a solve from there found no timing, the reason IPOPT
        gave). An edge whose re-solves have a timing but do not shrink a leak between the optimiser's nodes is not
        stuck: the whole plan's re-solve with the bounds moved in (planner.solve_within_bounds) is for that."""
        span = bound_span(self.lower, self.upper)
        above, below, x_end = self.edge_excess(x, j, counts[j], edge)
        start = self._start(x, j)
        # first with the same bounds (what the swing carried in takes), then, while the inputs still leave them
        # between the optimiser's nodes, with the bounds moved in
        from_here = bool(np.array_equal(start, self.at_rest(j)))
        down, up = np.zeros_like(span), np.zeros_like(span)  # how far this edge's bounds are moved in
        beyond = worst(above, below)
        for _ in range(CARRY_ROUNDS):
            if beyond <= INPUT_TOLERANCE:
                break
            if from_here:
                down += 1.2 * np.maximum(above, 0.0) * span
                up += 1.2 * np.maximum(below, 0.0) * span
            from_here = True
            base = self.lower, self.upper
            self.lower, self.upper = base[0] + up, base[1] - down
            try:
                again = self._solve_edge(j, counts, start, (node_guess(edge, self.smooth), edge.durations[0]), None,
                                         end, uniform_duration, CARRY_MAX_ITER, verbose, edge.lag_start)
            except PlanningError as unsolved:
                edge.records.append(unsolved_record(j, counts, unsolved))
                # IPOPT's status, not the message's advice (for a plan from rest)
                return edge, beyond, x_end, f"IPOPT: {unsolved.status}" if isinstance(unsolved, SolveFailed) \
                    else str(unsolved)
            finally:
                self.lower, self.upper = base
            if again.status not in OPTIMAL:  # out of iterations at a feasible point: no timing found from here
                why = f"IPOPT: {again.status} after {again.iterations} iterations"
                edge.records.append(unsolved_record(j, counts, why))
                return edge, beyond, x_end, why
            above_again, below_again, x_again = self.edge_excess(x, j, counts[j], again)
            if worst(above_again, below_again) >= beyond:
                break
            edge, above, below, x_end = replacing(edge, again), above_again, below_again, x_again
            beyond = worst(above, below)
        return edge, beyond, x_end, None

    def _stuck(self, j: int, x: np.ndarray, why: str, calmed: bool, since: float) -> str | None:
        """Why the carried swing leaves the bounds: edge j (0-based, starting `since` s into the plan) had no timing
        from the chain's state x. None for the first edge: nothing is carried into it (its bounds were moved in by a
        leak between the optimiser's nodes, and the plan's message says so)."""
        if j == 0:
            return None
        moved, speed, body = self.swing_at(j, x)
        return (f"edge {j + 1} (from t = {since:.3f} s) has no timing that keeps the bounds from the swing edge {j} "
                f"leaves at its corner ({body} {moved:.3g} mm from rest, {speed:.3g} mm/s; {why})"
                + (f", nor after edge {j} was solved again for a calmer corner" if calmed else "")
                + f": each rest-to-rest edge ends with every coordinate within {1e3 * self.rest_tol:g} mm (and mm/s) "
                "of rest (REST_TOL), and that residual swing adds up along the path; limits with more room above "
                "what the path needs at rest leave it room (a smaller --margin alone may not: the faster edges then "
                "swing more), and an input-shaped plan (--shaper zvd) slows each edge from the swing it inherits "
                "and cancels the crane's swing modes")

    def swing_at(self, j: int, x: np.ndarray) -> tuple[float, float, str | None]:
        """The swing in state x against the crane at rest at corner j: (the largest distance of a body's centre from
        where it rests there, mm; the largest speed of one, mm/s; the body furthest away)."""
        rest, n = self.corner(j, MIN_PHASE_INTERVALS), self.n
        moved, speed, body = 0.0, 0.0, None
        for name, offset in self.dyn.layout.body_offset.items():
            distance = 1e3 * float(np.linalg.norm(x[offset : offset + 3] - rest[offset : offset + 3]))
            if distance > moved:
                moved, body = distance, name
            speed = max(speed, 1e3 * float(np.linalg.norm(x[n + offset : n + offset + 3])))
        return moved, speed, body

    def edge_inputs(self, states: np.ndarray, count: int, edge: Edge) -> np.ndarray:
        """An edge's inputs on a CHECK_STEP_S grid, its end's included: its timing integrated again from its start
        `states[0]` (_edge_states) the whole way in steps that short, as Retiming.inputs_on_grid checks a plan (not
        from each node state: those carry the solve's RK4 error): samples x l."""
        h = float(edge.durations[0]) / count
        _, inputs = self.run_grid(states[0], edge.tau_dd, h, max(1, int(np.ceil(h / CHECK_STEP_S))), final=True,
                                  jerk=edge.tau_ddd)
        return inputs

    def edge_excess(self, x: np.ndarray, j: int, count: int, edge: Edge) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Edge j flown from x: (each input's largest step above its upper bound, and below its lower one, as a
        fraction of the span (≤ 0: within); the state at its end, at the corner exactly, as `chain` continues)."""
        states = self._edge_states(x, j, count, edge)
        inputs = self.edge_inputs(states, count, edge)
        span = bound_span(self.lower, self.upper)
        above, below = ((inputs - self.upper) / span).max(axis=0), ((self.lower - inputs) / span).max(axis=0)
        end = states[-1].copy()
        end[-2:] = self.geo.phases[j][1], 0.0
        return above, below, end

    def _edge_states(self, x: np.ndarray, j: int, count: int, edge: Edge) -> np.ndarray:
        """Edge j's node states flown from x (σ at its corner, at rest), as `chain` integrates them."""
        states, _ = self.run_grid(self._start(x, j), edge.tau_dd, float(edge.durations[0]) / count, edge.substeps,
                                  jerk=edge.tau_ddd)
        return states

    def _solve_edge(self, j: int, counts: list[int], start: np.ndarray, guess: tuple, fallback: tuple | None,
                    end: np.ndarray, uniform_duration: float, max_iter: int, verbose: bool,
                    lag: np.ndarray, tail_s: float = 0.0) -> Edge:
        """Edge j from the state `start` at its corner to rest at `end` (its solve, again with more RK4 steps per
        interval while the solution's intervals need them), from `guess` (σ̈, duration). An edge IPOPT gives no
        answer for keeps `fallback` (its own timing slowed from rest, feasible and ending at rest by rest_factor),
        and its status says so; without a fallback the PlanningError is raised."""
        records, iterations = [], 0
        # a warm start (the last tolerance round's timing) that IPOPT finds no way out of is tried again from the
        # feasible slowdown: a narrowed lag bound can leave the last timing deep outside it (drawn path 0, edge 1:
        # Infeasible_Problem_Detected after 365 iterations from the warm start)
        starts = [guess] if fallback is None or guess is fallback else [guess, fallback]
        for attempt, (guess_a, guess_T) in enumerate(starts):
            m = _substeps([guess_T], [counts[j]])
            try:
                while True:
                    part = self.solve_phases(start, [j], counts, guess_a, [guess_T], uniform_duration, max_iter,
                                             verbose, m, rest_at=end, lag_start=lag, tail_s=tail_s,
                                             retry=fallback is not None)
                    records += part.windows
                    iterations += part.iterations
                    needed = _substeps(part.durations, [counts[j]])
                    if needed <= m:
                        break
                    m, guess_a, guess_T = needed, node_guess(part, self.smooth), float(part.durations[0])
                break
            except PlanningError as unsolved:
                if fallback is None:
                    raise
                kept = attempt == len(starts) - 1
                records.append({"phases": [j], "intervals": counts[j], "iterations": 0, "reason": str(unsolved),
                                "status": "quintic_slowdown_kept" if kept else "warm_start_failed"})
                if kept:
                    warm_a, warm_T = fallback
                    return Edge(np.array([warm_T]), warm_a, np.zeros_like(warm_a), "quintic_slowdown_kept", records,
                                iterations, None, lag, _substeps([warm_T], [counts[j]]))
        return Edge(part.durations, part.tau_dd, part.tau_ddd, part.status, records, iterations, part.lag_end, lag, m)

    def grid_motion(self, j: int, count: int, factor: float, q: np.ndarray | None = None):
        """Edge j's own timing slowed by `factor` from rest (at q, else at corner j), σ̈ held per interval on `count`
        intervals (the problem's grid): (the end state, the inputs at every RK4 step start)."""
        acc, T = _warm(self, j, count, factor)
        states, inputs = self.run_grid(self.at_rest(j, q), acc, T / count, _substeps([T], [count]))
        return states[-1], inputs

    def rest_factor(self, j: int, count: int, low: float) -> float:
        """A slowdown of edge j's own timing from rest, at least `low` (the smallest that keeps the inputs within
        the bounds), that also ends within rest_tol / 2 of rest on the problem's grid: IPOPT's feasible start.
        The residual swing is not monotonic in the factor (it beats with the swing's period): this bisects
        between the last factor found wanting and the first that serves, doubling from `low`."""
        n = self.n

        def serves(f):
            x, u = self.grid_motion(j, count, f)
            residual = max(np.abs(x[:n] - self.corner(j + 1, MIN_PHASE_INTERVALS)).max(), np.abs(x[n : 2 * n]).max())
            return residual <= 0.5 * self.rest_tol and self.excess(u) <= 0

        return first_serving(serves, low, PHASE_BISECTION,
                             f"edge {j + 1}: no slowdown of its own timing up to {MAX_SLOWDOWN:g}x ends at rest within "
                             f"{self.rest_tol:g} on a grid of {count} intervals: give more --intervals")

    def chain(self, x0: np.ndarray, counts: list[int], durations: np.ndarray, tau_dd: np.ndarray, status: str,
              iterations: int, records: list[dict], tau_ddd: np.ndarray, substeps: list[int] | None = None) -> Part:
        """The whole path's timing integrated from x0 in one chain (the corners' residual swing carried over):
        the node states and the inputs at every RK4 step start, with RK4 steps of at most MAX_STEP_S, or each edge
        with its solve's `substeps` per interval (its states are then the solve's)."""
        K = len(counts)
        states, inputs, used = [np.asarray(x0, float)[None, :]], [], []
        x, k = np.asarray(x0, float), 0
        for j in range(K):
            m = _substeps([durations[j]], [counts[j]]) if substeps is None else substeps[j]
            xs, u = self.run_grid(x, tau_dd[k : k + counts[j]], durations[j] / counts[j], m, final=j == K - 1,
                                  jerk=tau_ddd[k : k + counts[j]])
            inputs.append(u)
            states.append(xs[1:])
            used.append(m)
            x = xs[-1].copy()
            x[-2:] = self.geo.phases[j][1], 0.0  # the corner exactly (σ ends there to the solver's tolerance)
            k += counts[j]
        return Part(np.asarray(durations, float), np.asarray(tau_dd, float), np.vstack(states), np.vstack(inputs),
                    status, iterations, records, used, np.asarray(tau_ddd, float))
