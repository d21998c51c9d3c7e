"""The geometry of a path as a function of one parameter σ: the signals g(σ) (tracked point, yaw, moving
anchors) and their first two derivatives in σ, as CasADi expressions and as numbers. A retiming is a
monotone σ(t); the signals at time t are then

    s = g(σ),  ṡ = g'(σ) σ̇,  s̈ = g''(σ) σ̇² + g'(σ) σ̈.

A waypoint path (the spec's) is K straight edges, each run rest to rest: σ ∈ [0, K], on edge k the point is
the edge's start plus (σ − k) times the edge (linear, so g' ≠ 0 and a timing may leave a corner at full
acceleration), the yaw is the spec's quintic yaw turn at the same fraction of the edge's own time (the
path's own timing spends T_k on edge k). Each edge is a phase of the timing: at the corners σ̇ = 0.

A user trajectory is one phase, σ ∈ [0, D] its own time: g is a C² cubic B-spline through its samples. Where
its own timing is at rest (g' = 0) a retiming passes with the point at rest whatever σ̇ is.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from ..control.path import DesiredPath, TrajectoryPath, quintic_array

# Samples of a user trajectory's geometry per second of its own time for the spline (at least 400).
SPLINE_RATE_HZ = 20.0
# max_speed and max_accel are kept at the nodes this fraction inside: IPOPT meets a constraint to its tolerance
# (sumsqr ≤ bound² to 1e-8, 5e-5 of a 0.01 m/s² bound), and the written samples between nodes must hold it too.
KINEMATIC_SLACK = 1e-3


def point_jerk(d1, d2, d3, tau_d, tau_dd, tau_ddd):
    """The tracked point's jerk g‴σ̇³ + 3g″σ̇σ̈ + g′σ⃛ from the point rows of g′, g″, g‴ (CasADi or numpy, broadcast)."""
    return d3 * tau_d**3 + 3 * d2 * tau_d * tau_dd + d1 * tau_ddd


def point_bounds(opti, geometry, tau, tau_d, tau_dd, jerks, bounds) -> None:
    """The tracked point's speed, acceleration (at every node k: tau[k], tau_d[k] and σ̈ there, tau_dd[k]) and jerk
    (at both ends of every interval, its σ⃛ jerks[i]: g‴σ̇³ + 3g″σ̇σ̈ + g′σ⃛, constant over an interval on a straight
    edge) within `bounds` (max_speed, max_accel, max_jerk; None: unbounded) as constraints of the casadi.Opti."""
    max_speed, max_accel, max_jerk = bounds
    if max_speed is None and max_accel is None and max_jerk is None:
        return
    rows, N = geometry.point_rows, len(tau_dd) - 1
    for k in range(N + 1):
        _, d1, d2 = geometry.function(tau[k])
        if max_speed is not None and k > 0:  # the start's speed is given (x_start), no variable of the problem
            opti.subject_to(ca.sumsqr(d1[rows] * tau_d[k]) <= (max_speed * (1.0 - KINEMATIC_SLACK)) ** 2)
        if max_accel is not None:
            acc = d2[rows] * tau_d[k] ** 2 + d1[rows] * tau_dd[k]
            opti.subject_to(ca.sumsqr(acc) <= (max_accel * (1.0 - KINEMATIC_SLACK)) ** 2)
        if max_jerk is not None:
            d3 = geometry.third(tau[k])[rows]
            for i in {max(k - 1, 0), min(k, N - 1)}:  # the intervals that meet at node k
                jerk = point_jerk(d1[rows], d2[rows], d3, tau_d[k], tau_dd[k], jerks[i])
                opti.subject_to(ca.sumsqr(jerk) <= (max_jerk * (1.0 - KINEMATIC_SLACK)) ** 2)


def _quintic(x):
    x = ca.fmin(ca.fmax(x, 0), 1)
    return x**3 * (10 - 15 * x + 6 * x**2)


class PathGeometry:
    """g(τ) for a DesiredPath (the spec's waypoints) or a TrajectoryPath (a user's motion).

    `function` is a casadi.Function τ -> (g, g', g'') over the whole signal vector (layout order: moving
    anchors, then x_d, y_d, z_d, yaw_d); `evaluate(taus)` gives the same as arrays (one row per τ)."""

    def __init__(self, path: DesiredPath):
        self.path = path
        self.path_duration = float(path.duration)  # the path's own timing's duration
        self.layout = path.layout
        self.n_signals = path.n_signals
        tau = ca.SX.sym("sigma")
        self.edges = not isinstance(path, TrajectoryPath)
        if not self.edges:
            self.end = self.path_duration
            self.phases = [(0.0, self.end, self.end)]  # (σ from, σ to, the own timing's seconds)
            point, yaw = self._spline(path, tau)
        else:
            self.end = float(len(path.edge_duration))
            self.phases = [(float(k), float(k + 1), float(T)) for k, T in enumerate(path.edge_duration)]
            point = ca.DM(path.start_point + path.edge_start[0])
            own = 0  # the path's own time at σ: piecewise linear
            last = len(path.edge_duration) - 1
            for k, (T, delta) in enumerate(zip(path.edge_duration, path.edge_delta, strict=True)):
                # half-open edges: at a corner σ = k the slope is the outgoing edge's (fmin/fmax would give
                # half of it there), at the path's end the last edge's
                done = tau > k + 1 if k == last else tau >= k + 1
                fraction = ca.if_else(tau < k, 0, ca.if_else(done, 1, tau - k))
                point = point + ca.DM(delta) * fraction
                own = own + T * fraction
            yaw = path.start_yaw + path.yaw_turn * _quintic(own / self.path_duration)
        g = self._signals(point, yaw)
        d1 = ca.jacobian(g, tau)
        d2 = ca.jacobian(d1, tau)
        self.function = ca.Function("geometry", [tau], [g, d1, d2], ["tau"], ["g", "dg", "ddg"])
        # g''' for a jerk bound (0 on a straight edge; piecewise constant on a trajectory's cubic spline)
        self.third = ca.Function("geometry_third", [tau], [ca.jacobian(d2, tau)], ["tau"], ["dddg"])
        self._map: dict[int, ca.Function] = {}
        self._third_map: dict[int, ca.Function] = {}
        p = self.layout.path_signal
        self.point_rows, self.yaw_row = slice(p, p + 3), p + 3

    def _signals(self, point, yaw):
        out = [None] * self.n_signals
        p = self.layout.path_signal
        for c in range(3):
            out[p + c] = point[c]
        out[p + 3] = yaw
        for j, anchor0, follows in self.path.anchors:
            for c in range(3):
                out[j + c] = anchor0[c] + (point[c] - self.path.start_point[c]) if follows[c] else ca.SX(anchor0[c])
        return ca.vertcat(*out)

    def _spline(self, path: TrajectoryPath, tau):
        """A user's motion: a cubic B-spline (C², CasADi's interpolant) through its samples in its own time."""
        count = max(400, int(np.ceil(self.end * SPLINE_RATE_HZ)) + 1)
        taus = np.linspace(0.0, self.end, count)
        table = path.table(taus)
        p = path.layout.path_signal
        columns = [ca.interpolant(f"trajectory_{c}", "bspline", [taus], table[:, p + c]) for c in range(4)]
        point = ca.vertcat(*[columns[c](tau) for c in range(3)])
        return point, columns[3](tau)

    def own_timing(self, t) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """σ, σ̇, σ̈ of the path's own timing at its times t (the spec path's quintic edges)."""
        t = np.asarray(t, dtype=float)
        if not self.edges:
            return np.clip(t, 0.0, self.end), np.where(t <= self.end, 1.0, 0.0), np.zeros_like(t)
        path = self.path
        k = np.clip(np.searchsorted(path.edge_t0, t, side="right") - 1, 0, len(path.edge_duration) - 1)
        T = path.edge_duration[k]

        s, ds, dds = quintic_array((t - path.edge_t0[k]) / T)
        return k + s, ds / T, dds / T**2

    def own_peaks(self, phase: int | None = None, samples: int = 2001) -> tuple[float, float, float]:
        """The tracked point's peak speed (m/s), acceleration (m/s²) and jerk (m/s³, the acceleration's differences
        over the samples) on the path's own timing, over the whole path or one phase: a uniform slowdown by f divides
        them by f, f² and f³."""
        start, stop = 0.0, self.path_duration
        if phase is not None and self.edges:
            start = float(self.path.edge_t0[phase])
            stop = start + self.phases[phase][2]
        tau, rate, accel = self.own_timing(np.linspace(start, stop, samples))
        _, d1, d2 = self.evaluate(tau)
        rows = self.point_rows
        velocity = d1[:, rows] * rate[:, None]
        acceleration = d2[:, rows] * rate[:, None] ** 2 + d1[:, rows] * accel[:, None]
        jerk = np.diff(acceleration, axis=0) / ((stop - start) / (samples - 1))
        return (float(np.linalg.norm(velocity, axis=1).max()), float(np.linalg.norm(acceleration, axis=1).max()),
                float(np.linalg.norm(jerk, axis=1).max()))

    def place(self, tau: float, point=None) -> str:
        """Where τ is, in words: 's = 0.46 (x, y, z = 0.25, 0.25, 0.45 m)' (s = τ / D)."""
        if point is None:
            g, _, _ = self.evaluate([tau])
            point = g[0, self.point_rows]
        xyz = ", ".join(f"{v:.4g}" for v in point)
        return f"s = {tau / self.end:.3f} of the path (x, y, z = {xyz} m)"

    def evaluate(self, taus) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(g, g', g'') at each τ, one row per τ."""
        taus = np.atleast_1d(np.asarray(taus, dtype=float))
        if taus.size not in self._map:
            self._map[taus.size] = self.function.map(taus.size)
        g, d1, d2 = self._map[taus.size](taus[None, :])
        return np.asarray(g).T, np.asarray(d1).T, np.asarray(d2).T

    def signals(self, tau, tau_d, tau_dd, tau_ddd):
        """Flat [s, ṡ, s̈] rows for the retiming's τ, τ̇, τ̈, and the tracked point's jerk (rows x 3) with its τ⃛
        (arrays of one value per instant)."""
        tau = np.atleast_1d(np.asarray(tau, dtype=float))
        g, d1, d2 = self.evaluate(tau)
        if tau.size not in self._third_map:
            self._third_map[tau.size] = self.third.map(tau.size)
        d3 = np.asarray(self._third_map[tau.size](tau[None, :])).T
        tau_d, tau_dd, tau_ddd = (np.asarray(v, dtype=float)[:, None] for v in (tau_d, tau_dd, tau_ddd))
        p = self.point_rows
        return (np.hstack([g, d1 * tau_d, d2 * tau_d**2 + d1 * tau_dd]),
                point_jerk(d1[:, p], d2[:, p], d3[:, p], tau_d, tau_dd, tau_ddd))
