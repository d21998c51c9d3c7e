"""Input-shaped timings of a waypoint path: the anti-sway method industrial cranes use (zero-vibration ZV and ZVD
shapers, Singer and Seering 1990), applied to the path's own timing edge by edge, with the swing carried over
the corners; compared in docs/planning.md with the time-optimal rest-to-rest plan.

The crane's swing is the ideal motion's internal dynamics (acroboter.planning.ideal_motion): with the tracked
point held at a place, the connector swings on its modes. `swing_modes` linearises the ideal motion at rest there
(each edge's first corner: the cables' lengths set the modes) and keeps the lightly damped ones (damping ratio below
SWING_DAMPING). A shaper is a train of impulses (times t_i, amplitudes A_i > 0, ΣA_i = 1); convolved with a command
it cancels the residual vibration of its mode:

    ZV:  A = [1, K] / (1 + K),              t = [0, T_d/2]
    ZVD: A = [1, 2K, K²] / (1 + K)²,        t = [0, T_d/2, T_d]        K = exp(−ζπ/√(1 − ζ²)), T_d = 2π/ω_d

(ZVD also zeroes the residual's derivative in the frequency: robust to a mode 5-10 % off). Several modes: the
shapers convolved. On a straight edge the tracked point is linear in the path parameter σ, so shaping σ(t) is
shaping the point's command: each edge's own quintic timing, slowed by a factor f_j, is convolved with the shaper;
σ stays monotone and the geometry exact. The edge then lasts f_j·T_j plus the shaper's span.

The factors are chosen edge by edge, in order, from the state the edges before leave (the swing carried over as the
plant will): each the first (doubling, then bisection to PHASE_BISECTION: the residual swing is not monotonic in it)
whose ideal motion keeps every input within the limits less the margin and ends within REST_TOL of rest, and no
faster than the slowest mode (`ShapedRetiming.slowest_move`). The timing is written as the planner writes a smooth
one (σ̈ at nodes SHAPED_INTERVAL_S apart, linear in between, corrected so each edge ends exactly at its corner at
rest), so the same sampling, checks and certificate apply. "unshaped" is the same search without a shaper: what the
shaper buys.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import casadi as ca
import numpy as np

from ..control.path import quintic_array
from .edges import EdgeRetiming
from .ideal_motion import PlanningError
from .retiming import MAX_SLOWDOWN, MIN_PHASE_INTERVALS, REST_TOL, Solution, solution_of
from .windows import PHASE_BISECTION, _substeps, first_serving

SHAPERS = ("zv", "zvd", "unshaped")
# A mode of the linearised ideal motion at rest is a swing when it oscillates with a damping ratio below this
# (the Baumgarte and servo-law poles are critically damped, ζ = 1).
SWING_DAMPING = 0.3
# The shaped timing's nodes are this far apart at most (s): σ̈ is linear in between (the control period), and at
# least this many over the slowed quintic (a fast edge's quintic is short: its σ̈ must be resolved, the written
# timing is what is checked and flown).
SHAPED_INTERVAL_S = 0.02
QUINTIC_NODES = 64
# Two modes closer than this (relative, in the damped frequency) are one (the pendulum's x and y pair).
SAME_MODE = 1e-3
# The status of a shaped edge's record (no solver ran: the factor is a bisection).
SHAPED_STATUS = "shaped"


@dataclass(frozen=True)
class Mode:
    """A swing mode: natural angular frequency (rad/s), damping ratio, damped period (s)."""

    omega: float
    damping: float

    @property
    def period(self) -> float:
        return 2.0 * math.pi / (self.omega * math.sqrt(1.0 - self.damping**2))

    def as_dict(self) -> dict:
        return {"period_s": self.period, "omega_rad_s": self.omega, "damping_ratio": self.damping}


def swing_modes(dynamics, geometry, q: np.ndarray, tau: float) -> list[Mode]:
    """The lightly damped modes of the ideal motion held at rest at configuration q on the path at τ (the tracked
    point still, σ̇ = σ̈ = 0), slowest first: the eigenvalues of its linearisation in (q, q̇) with an imaginary part
    and a damping ratio below SWING_DAMPING, one per frequency (SAME_MODE)."""
    n = dynamics.layout.n
    mq, mqd = ca.MX.sym("q", n), ca.MX.sym("qd", n)
    g, _, _ = geometry.function(tau)
    zero = ca.DM.zeros(dynamics.layout.n_signals)
    qdd = dynamics.function(mq, mqd, g, zero, zero)[0]
    jac = ca.Function("swing_jacobian", [mq, mqd], [ca.jacobian(qdd, ca.vertcat(mq, mqd))])
    a = np.block([[np.zeros((n, n)), np.eye(n)], [np.asarray(jac(q, np.zeros(n)))]])
    modes: list[Mode] = []
    for lam in sorted(np.linalg.eigvals(a), key=lambda v: abs(v.imag)):
        if lam.imag <= 1e-6:
            continue
        omega = abs(lam)
        mode = Mode(float(omega), float(-lam.real / omega))
        if mode.damping < SWING_DAMPING and not any(abs(m.period - mode.period) <= SAME_MODE * m.period
                                                    for m in modes):
            modes.append(mode)
    return modes


def shaper(kind: str, modes: list[Mode]) -> tuple[np.ndarray, np.ndarray]:
    """The impulse train (times s, amplitudes) of a ZV or ZVD shaper for each mode, convolved; "unshaped": one
    impulse at 0."""
    if kind not in SHAPERS:
        raise PlanningError(f"shaper: expected one of {', '.join(SHAPERS)}, found {kind!r}")
    times, amps = np.zeros(1), np.ones(1)
    if kind == "unshaped":
        return times, amps
    for mode in modes:
        k = math.exp(-mode.damping * math.pi / math.sqrt(1.0 - mode.damping**2))
        half = 0.5 * mode.period
        if kind == "zv":
            t, a = np.array([0.0, half]), np.array([1.0, k]) / (1.0 + k)
        else:
            t, a = np.array([0.0, half, 2.0 * half]), np.array([1.0, 2.0 * k, k * k]) / (1.0 + k) ** 2
        times, amps = (times[:, None] + t[None, :]).ravel(), (amps[:, None] * a[None, :]).ravel()
    order = np.argsort(times, kind="stable")
    return times[order], amps[order]


def shaped_edge(own_s: float, factor: float, times: np.ndarray, amps: np.ndarray) -> tuple[np.ndarray, float]:
    """An edge's own quintic timing (own_s seconds) slowed by `factor` and convolved with the shaper: σ̈ at nodes at
    most SHAPED_INTERVAL_S apart and QUINTIC_NODES over the slowed quintic (the first and last 0), and the edge's
    duration. σ̈ linear between the nodes is the timing flown; it is corrected (least change, away from the ends)
    so that the edge ends exactly: Δσ = 1, σ̇ = 0."""
    span = factor * own_s
    duration = span + float(times[-1])
    count = max(MIN_PHASE_INTERVALS, int(math.ceil(duration / min(SHAPED_INTERVAL_S, span / QUINTIC_NODES))))
    t = np.linspace(0.0, duration, count + 1)
    acc = np.zeros_like(t)
    for t_i, a_i in zip(times, amps, strict=True):
        local = (t - t_i) / span
        inside = (local > 0.0) & (local < 1.0)
        acc[inside] += a_i * quintic_array(local[inside])[2] / span**2
    acc[[0, -1]] = 0.0
    ends = _end_map(count, duration / count)  # (σ̇, Δσ) at the end per unit σ̈ at each node
    weights = np.sin(np.pi * t / duration) ** 2  # the correction vanishes where the edge starts and ends
    missing = np.array([0.0, 1.0]) - ends @ acc
    scaled = ends * weights[None, :]
    acc = acc + weights * (scaled.T @ np.linalg.solve(scaled @ scaled.T, missing))
    return acc, duration


def _end_map(count: int, h: float) -> np.ndarray:
    """(σ̇(T), σ(T) − σ(0)) of a timing from rest whose σ̈ is linear between `count` + 1 nodes h apart, per unit σ̈
    at each node (2 x (count + 1)): exact for the piecewise cubic σ."""
    k = np.arange(count)
    rate = np.zeros(count + 1)
    rate[:-1] += h / 2
    rate[1:] += h / 2
    # interval k contributes σ̇_k h + h²(2a_k + a_{k+1})/6, and σ̇_k carries every interval before it
    after = count - 1 - k  # the intervals after interval k (each sees its full rate change)
    pos = np.zeros(count + 1)
    pos[:-1] += h * h / 2 * after + h * h / 3
    pos[1:] += h * h / 2 * after + h * h / 6
    return np.vstack([rate, pos])


class ShapedRetiming(EdgeRetiming):
    """A waypoint path's own timing, edge by edge, shaped (see the module's docstring): `solve` returns a Solution
    as the optimisers do."""

    def __init__(self, *args, shaper_kind: str = "zv", **kwargs):
        super().__init__(*args, **kwargs)
        self.kind = shaper_kind
        self.smooth = True  # σ̈ continuous
        self._shapers: dict[int, tuple[list[Mode], tuple[np.ndarray, np.ndarray]]] = {}
        self.factors: list[float] = []
        self.counts: list[int] = []  # the last solve's intervals per edge

    def edge_shaper(self, j: int) -> tuple[list[Mode], tuple[np.ndarray, np.ndarray]]:
        """Edge j's swing modes, at rest at its first corner (the cables' lengths there set them: on the paper's
        path the upper square's edges have their own), and its shaper's impulses."""
        if j not in self._shapers:
            modes = swing_modes(self.dyn, self.geo, self.corner(j, MIN_PHASE_INTERVALS), self.geo.phases[j][0])
            self._shapers[j] = modes, shaper(self.kind, modes)
        return self._shapers[j]

    def edge(self, j: int, factor: float) -> tuple[np.ndarray, float]:
        return shaped_edge(self.geo.phases[j][2], factor, *self.edge_shaper(j)[1])

    def fly_edge(self, x: np.ndarray, j: int, factor: float):
        """Edge j shaped at `factor` from the state x: (node states, inputs, σ̈ at the nodes, duration)."""
        nodes, duration = self.edge(j, factor)
        count = nodes.size - 1
        h = duration / count
        # RK4 steps as the chain takes them (EdgeRetiming.chain): the inputs checked here are the plan's
        states, inputs = self.run_grid(x, nodes[:-1], h, _substeps([duration], [count]), jerk=np.diff(nodes) / h)
        return states, inputs, nodes, duration

    def edge_factor(self, x: np.ndarray, j: int) -> float:
        """The smallest factor of edge j's own timing, shaped, from the state x, that keeps the inputs within the
        bounds and leaves the crane at rest at the edge's end as a rest-to-rest edge is (every coordinate within
        REST_TOL of its rest there, every rate within REST_TOL per second), at least the factor max_speed /
        max_accel / max_jerk ask for (a shaper never raises a peak: its amplitudes are positive and sum to 1).
        The residual swing is not monotonic in the factor: from the smallest factor that keeps the inputs (doubling
        from the least factor allowed, then bisecting), this doubles again, then bisects between the last factor
        found wanting and the first that serves."""
        n, rest = self.n, self.corner(j + 1, MIN_PHASE_INTERVALS)

        def within(f):
            return self.excess(self.fly_edge(x, j, f)[1]) <= 0

        def serves(f):
            states, inputs, _, _ = self.fly_edge(x, j, f)
            end = states[-1]
            return (self.excess(inputs) <= 0 and np.abs(end[:n] - rest).max() <= REST_TOL
                    and np.abs(end[n : 2 * n]).max() <= REST_TOL)

        low = max(self.kinematic_factor(j), self.slowest_move(j), 1e-3)
        refusal = f"edge {j + 1}: no slowdown of its own timing up to {MAX_SLOWDOWN:g}x, shaped ({self.kind}), "
        within_bounds = first_serving(within, low, PHASE_BISECTION, refusal + "keeps the inputs within the limits "
                                      "with the margin from the swing the edges before it leave")
        return first_serving(serves, within_bounds, PHASE_BISECTION, refusal + f"ends within {REST_TOL:g} of rest")

    def phase_counts(self, intervals: int) -> list[int]:
        """The intervals of each edge in the last solve (its own grid, not `intervals`)."""
        return list(self.counts)

    def slowest_move(self, j: int) -> float:
        """The factor at which edge j's own quintic lasts the slowest swing mode's period. A shaper cancels the modes
        of the linearised crane; a faster move is a near-step, and the shaped timing a staircase of near-steps that
        drive the crane far from its linearisation and that a sampled controller follows poorly (measured on the
        paper's path: ZVD edges at 0.01-0.1 of their own timing failed their certificates, or flew 250 mm off)."""
        modes = self.edge_shaper(j)[0]
        return modes[0].period / self.geo.phases[j][2] if modes else 0.0

    def solve(self, intervals: int, guess_factor: float | None = None, max_iter: int = 400,
              verbose: bool = False) -> Solution:
        """The shaped timing (`intervals`, `max_iter` unused: the grid is SHAPED_INTERVAL_S, no solver runs)."""
        started = time.perf_counter()
        factor = self.best_uniform() if guess_factor is None else guess_factor
        x0 = np.concatenate([self.x0, [0.0, 0.0]])
        x, counts, durations, nodes, records, factors = x0, [], [], [], [], []
        for j in range(len(self.geo.phases)):
            begun = time.perf_counter()
            f = self.edge_factor(x, j)
            states, _, acc, duration = self.fly_edge(x, j, f)
            x = states[-1].copy()
            x[-2:] = self.geo.phases[j][1], 0.0
            factors.append(f)
            counts.append(acc.size - 1)
            durations.append(duration)
            nodes.append(acc)
            records.append({"phases": [j], "intervals": acc.size - 1, "status": SHAPED_STATUS, "iterations": 0,
                            "factor": f, "solve_s": time.perf_counter() - begun})
        # only a solve that reaches the end describes the plan (a re-solve that fails keeps the plan before it)
        self.factors, self.counts = factors, counts
        tau_dd = np.concatenate([a[:-1] for a in nodes])
        tau_ddd = np.concatenate([np.diff(a) / (d / (a.size - 1)) for a, d in zip(nodes, durations, strict=True)])
        part = self.chain(x0, counts, np.asarray(durations), tau_dd, SHAPED_STATUS, 0, records, tau_ddd)
        return solution_of(part, counts, time.perf_counter() - started, factor, factor * self.geo.path_duration)

    def description(self) -> dict:
        """What the summary says of the shaping: the kind, the node spacing, and for each edge its factor, its swing
        modes and its shaper's impulses."""
        edges = []
        for j, factor in enumerate(self.factors):
            modes, (times, amps) = self.edge_shaper(j)
            edges.append({"factor": factor, "modes": [m.as_dict() for m in modes], "impulse_times_s": times.tolist(),
                          "impulse_amplitudes": amps.tolist()})
        return {"kind": self.kind, "interval_s": SHAPED_INTERVAL_S, "edges": edges}


def corner_swing(problem: EdgeRetiming, times: np.ndarray, states: np.ndarray, corner_nodes: list[int]) -> list[dict]:
    """At each corner the timing stops at (node indices into times/states), the swing left: the largest distance of
    a body's centre from where it rests there (mm), and the largest speed of one (mm/s)."""
    out = []
    for j, k in enumerate(corner_nodes):
        moved, speed, body = problem.swing_at(j + 1, states[k])
        out.append({"corner": j + 1, "t_s": float(times[k]), "displacement_mm": moved, "speed_mm_s": speed,
                    "body": body})
    return out
