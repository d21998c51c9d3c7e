"""Rest-to-rest edges: EdgeRetiming, a Retiming (acroboter.planning.retiming) of a waypoint path whose every edge
starts and ends with the whole crane at rest, the connector's swing included.

Why. The whole path in one single-shooting problem has an exact Hessian over every RK4 step of the path (about
a thousand on the default path: minutes per IPOPT iteration), and the swing a time-optimal edge leaves at a
corner is barely damped (the default crane's period is about 2.8 s, its decay time about a minute): planned
edge by edge with the swing carried over, the next edge can have no feasible timing at all, not even its own
timing slowed a thousand times (measured on the default crane with winch limits [5, 30] N: the first edge's
optimum left a swing that takes a winch beyond its bounds at rest). A crane operator asks for the other thing
anyway: at a waypoint the load is at rest. So each edge is planned from the static equilibrium at its first
corner to within REST_TOL of the static equilibrium at its last corner, at rest: the edges are then independent
problems, small (one edge's RK4 steps) and solved one after the other.

What it costs. The time-optimal timing with the swing free at the corners can only be faster; docs/planning.md
reports the two on a path where both solve. The plan's inputs are not taken from the edges' solves: the whole
path's timing is integrated again from the static start (the small residual swing of each corner carried into
the next edge, as the plant will), and those inputs are the plan's, checked against the bounds.
"""

from __future__ import annotations

import sys

import numpy as np

from ..runtime.progress import progress_disabled
from .ideal_motion import PlanningError
from .retiming import MAX_SLOWDOWN, MIN_PHASE_INTERVALS, REST_TOL, Part, Retiming
from .windows import PHASE_BISECTION, _substeps, _warm, first_serving, phase_factor

# The quasi-static motion that finds the configuration at rest at a corner lasts at least this long (s).
QUASI_STATIC_S = 120.0


class EdgeRetiming(Retiming):
    """A Retiming of a waypoint path solved edge by edge, each rest to rest (see the module's docstring)."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        if not self.geo.edges:
            raise PlanningError("rest-to-rest edges need a waypoint path (a trajectory file is one phase)")
        self.corners = [self.x0[: self.n]]

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
        durations, tau_dd, jerks, records = [], [], [], []
        status, iterations = "", 0
        from tqdm import tqdm

        bar = tqdm(total=K, unit="edge", desc="planning", file=sys.stderr, disable=progress_disabled(), leave=False)
        lag = np.zeros(6)  # a plan to a tolerance: the lag model's state carried from edge to edge
        for j in range(K):
            # from rest, not from the state the edge before leaves: its residual swing (within REST_TOL) must then be
            # stopped too, and on the paper's path at [5, 30] N that made the second edge 4.72 s where it takes 1.79 s
            # from rest (the whole plan 38.5 s, measured 2026-12-06); the chain carries the swing instead
            start = self.at_rest(j)
            warm_a, warm_T = _warm(self, j, counts[j], factors[j])
            guess_a, guess_T = (warm_a, warm_T) if self.warm is None else (self.warm[0][j], self.warm[1][j])
            m = _substeps([guess_T], [counts[j]])
            try:
                while True:
                    part = self.solve_phases(start, [j], counts, guess_a, [guess_T], uniform_duration, max_iter,
                                             verbose, m, rest_at=self.corner(j + 1, MIN_PHASE_INTERVALS),
                                             lag_start=lag)
                    records += part.windows
                    iterations += part.iterations
                    needed = _substeps(part.durations, [counts[j]])
                    if needed <= m:
                        break
                    m, guess_a, guess_T = needed, part.tau_dd, float(part.durations[0])
                edge_T, edge_a, edge_j, edge_status = part.durations, part.tau_dd, part.tau_ddd, part.status
                lag = part.lag_end if part.lag_end is not None else lag
            except PlanningError as unsolved:
                # IPOPT gave no answer: the edge keeps its warm start, its own timing slowed from rest (feasible and
                # ending at rest by rest_factor's bisection), and the summary says so
                edge_T, edge_a, edge_status = np.array([warm_T]), warm_a, "quintic_slowdown_kept"
                edge_j = np.zeros_like(warm_a)
                records.append({"phases": [j], "intervals": counts[j], "status": edge_status, "iterations": 0,
                                "reason": str(unsolved)})
            if not status or status == "Solve_Succeeded":
                status = edge_status
            durations.append(edge_T)
            tau_dd.append(edge_a)
            jerks.append(edge_j)
            bar.set_postfix_str(f"edge {j + 1}: {float(edge_T[0]):.3g} s ({edge_status})")
            bar.update()
        bar.close()
        return self.chain(x0, counts, np.concatenate(durations), np.concatenate(tau_dd), status, iterations, records,
                          np.concatenate(jerks))

    def grid_motion(self, j: int, count: int, factor: float, q: np.ndarray | None = None):
        """Edge j's own timing slowed by `factor` from rest (at q, else at corner j), σ̈ held per interval on `count`
        intervals (the problem's grid): (the end state, the inputs at every RK4 step start)."""
        acc, T = _warm(self, j, count, factor)
        states, inputs = self.run_grid(self.at_rest(j, q), acc, T / count, _substeps([T], [count]))
        return states[-1], inputs

    def rest_factor(self, j: int, count: int, low: float) -> float:
        """A slowdown of edge j's own timing from rest, at least `low` (the smallest that keeps the inputs within
        the bounds), that also ends within REST_TOL / 2 of rest on the problem's grid: IPOPT's feasible start.
        The residual swing is not monotonic in the factor (it beats with the swing's period): this bisects
        between the last factor found wanting and the first that serves, doubling from `low`."""
        n = self.n

        def serves(f):
            x, u = self.grid_motion(j, count, f)
            residual = max(np.abs(x[:n] - self.corner(j + 1, MIN_PHASE_INTERVALS)).max(), np.abs(x[n : 2 * n]).max())
            return residual <= 0.5 * REST_TOL and self.excess(u) <= 0

        return first_serving(serves, low, PHASE_BISECTION,
                             f"edge {j + 1}: no slowdown of its own timing up to {MAX_SLOWDOWN:g}x ends at rest within "
                             f"{REST_TOL:g} on a grid of {count} intervals: give more --intervals")

    def chain(self, x0: np.ndarray, counts: list[int], durations: np.ndarray, tau_dd: np.ndarray, status: str,
              iterations: int, records: list[dict], tau_ddd: np.ndarray) -> Part:
        """The whole path's timing integrated from x0 in one chain (the corners' residual swing carried over):
        the node states and the inputs at every RK4 step start, with RK4 steps of at most MAX_STEP_S."""
        K = len(counts)
        states, inputs, substeps = [np.asarray(x0, float)[None, :]], [], []
        x, k = np.asarray(x0, float), 0
        for j in range(K):
            m = _substeps([durations[j]], [counts[j]])
            xs, u = self.run_grid(x, tau_dd[k : k + counts[j]], durations[j] / counts[j], m, final=j == K - 1,
                                  jerk=tau_ddd[k : k + counts[j]])
            inputs.append(u)
            states.append(xs[1:])
            substeps.append(m)
            x = xs[-1].copy()
            x[-2:] = self.geo.phases[j][1], 0.0  # the corner exactly (σ ends there to the solver's tolerance)
            k += counts[j]
        return Part(np.asarray(durations, float), np.asarray(tau_dd, float), np.vstack(states), np.vstack(inputs),
                    status, iterations, records, substeps, np.asarray(tau_ddd, float))
