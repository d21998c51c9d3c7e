"""Desired motion (docs/model.md §5): rest-to-rest quintic edges through the spec's waypoints, a quintic yaw
turn over the whole path, and the signal vector s(t), ṡ(t), s̈(t) that feeds the generated code.

Signals are laid out flat as [s, ṡ, s̈] (3 × n_signals), the layout of CompiledModel.signals, so
one assignment loads them. `flat(t)` evaluates one instant with scalar math (it is on the
control step's hot path); `table(times)` evaluates many at once for the plant.
"""

from __future__ import annotations

import bisect
import math

import numpy as np

from .layout import Layout
from .spec import Spec


def quintic(tau: float) -> tuple[float, float, float]:
    """s(τ) = 10τ³ − 15τ⁴ + 6τ⁵ and its first two derivatives in τ, clamped to [0, 1]."""
    if tau <= 0.0:
        return 0.0, 0.0, 0.0
    if tau >= 1.0:
        return 1.0, 0.0, 0.0
    t2 = tau * tau
    return (
        t2 * tau * (10.0 - 15.0 * tau + 6.0 * t2),
        30.0 * t2 * (1.0 - 2.0 * tau + t2),
        60.0 * tau * (1.0 - 3.0 * tau + 2.0 * t2),
    )


def quintic_array(tau: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    tau = np.clip(tau, 0.0, 1.0)
    t2 = tau * tau
    return (
        t2 * tau * (10.0 - 15.0 * tau + 6.0 * t2),
        30.0 * t2 * (1.0 - 2.0 * tau + t2),
        60.0 * tau * (1.0 - 3.0 * tau + 2.0 * t2),
    )


class DesiredPath:
    """Tracked point position and yaw, relative to a start point and start yaw."""

    def __init__(self, spec: Spec, layout: Layout, start_point: np.ndarray, start_yaw: float):
        self.layout = layout
        self.n_signals = layout.n_signals
        self.start_point = np.asarray(start_point, dtype=float)
        self.start_yaw = float(start_yaw)
        self.yaw_turn = math.radians(spec.path.yaw_deg)
        waypoints = np.asarray(spec.path.waypoints, dtype=float)
        edges = [(a, b) for a, b in zip(waypoints[:-1], waypoints[1:], strict=True) if np.linalg.norm(b - a) > 0]
        self.edge_start = np.array([a for a, _ in edges])
        self.edge_delta = np.array([b - a for a, b in edges])
        self.edge_duration = np.linalg.norm(self.edge_delta, axis=1) / spec.path.mean_speed
        self.edge_t0 = np.concatenate([[0.0], np.cumsum(self.edge_duration)[:-1]])
        self.duration = float(self.edge_duration.sum())
        # Python lists for the scalar path: indexing numpy arrays element-wise is slower.
        self._t0 = self.edge_t0.tolist()
        self._dur = self.edge_duration.tolist()
        self._origin = (self.start_point + self.edge_start).tolist()
        self._delta = self.edge_delta.tolist()
        # Moving anchors: (first signal index, initial position, which world axes follow the path).
        self.anchors = [
            (layout.anchor_signal[a.name], list(a.position), [c in a.follows_path for c in "xyz"])
            for a in spec.anchors
            if a.follows_path
        ]
        # flat(): a template holding the fixed values, and the entries that follow the path.
        ns, p = self.n_signals, layout.path_signal
        self._path_index = (p, ns + p, 2 * ns + p)
        self._last_edge = len(self._dur) - 1
        self._template = [0.0] * (3 * ns)
        self._follow = []
        for j, anchor0, follows in self.anchors:
            for c in range(3):
                if follows[c]:
                    self._follow.append((j + c, c, anchor0[c] - self.start_point[c]))
                else:
                    self._template[j + c] = anchor0[c]

    # --- one instant ------------------------------------------------------------------------------
    def flat(self, t: float) -> list[float]:
        """[s, ṡ, s̈] at time t as a flat list (layout order: anchors, then x y z yaw).

        Scalar Python on purpose: it runs once per control step, where numpy's per-call overhead
        on 3-vectors would cost more than the arithmetic.
        """
        t = float(t)  # numpy scalars make every operation below several times slower
        k = bisect.bisect_right(self._t0, t) - 1
        k = 0 if k < 0 else (self._last_edge if k > self._last_edge else k)
        T = self._dur[k]
        s, ds, dds = quintic((t - self._t0[k]) / T)
        ds /= T
        dds /= T * T
        ox, oy, oz = self._origin[k]
        dx, dy, dz = self._delta[k]
        D = self.duration
        y, yd, ydd = quintic(t / D)
        turn = self.yaw_turn
        out = self._template.copy()
        p, v, a = self._path_index
        out[p], out[p + 1], out[p + 2], out[p + 3] = ox + s * dx, oy + s * dy, oz + s * dz, self.start_yaw + turn * y
        out[v], out[v + 1], out[v + 2], out[v + 3] = ds * dx, ds * dy, ds * dz, turn * yd / D
        out[a], out[a + 1], out[a + 2], out[a + 3] = dds * dx, dds * dy, dds * dz, turn * ydd / (D * D)
        for i, c, offset in self._follow:  # moving anchors: start position + path displacement
            out[i] = offset + out[p + c]
            out[i + v - p] = out[v + c]
            out[i + a - p] = out[a + c]
        return out

    def signal_arrays(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        flat = np.array(self.flat(t))
        ns = self.n_signals
        return flat[:ns], flat[ns : 2 * ns], flat[2 * ns :]

    def position(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Desired position, velocity and acceleration of the tracked point at time t."""
        s, sd, sdd = self.signal_arrays(t)
        p = self.layout.path_signal
        return s[p : p + 3], sd[p : p + 3], sdd[p : p + 3]

    # --- many instants ------------------------------------------------------------------------------
    def table(self, times: np.ndarray) -> np.ndarray:
        """[s, ṡ, s̈] at each time, one row per time (vectorized; for the plant's stage signals)."""
        times = np.asarray(times, dtype=float)
        ns, p = self.n_signals, self.layout.path_signal
        k = np.clip(np.searchsorted(self.edge_t0, times, side="right") - 1, 0, len(self.edge_duration) - 1)
        T = self.edge_duration[k]
        s, ds, dds = quintic_array((times - self.edge_t0[k]) / T)
        d = self.edge_delta[k]
        pos = self.start_point + self.edge_start[k] + s[:, None] * d
        vel = (ds / T)[:, None] * d
        acc = (dds / T**2)[:, None] * d
        D = self.duration
        y, dy, ddy = quintic_array(times / D)
        out = np.zeros((times.size, 3 * ns))
        out[:, p : p + 3], out[:, ns + p : ns + p + 3], out[:, 2 * ns + p : 2 * ns + p + 3] = pos, vel, acc
        out[:, p + 3] = self.start_yaw + self.yaw_turn * y
        out[:, ns + p + 3] = self.yaw_turn * dy / D
        out[:, 2 * ns + p + 3] = self.yaw_turn * ddy / D**2
        for j, anchor0, follows in self.anchors:
            f = np.array(follows)
            out[:, j : j + 3] = np.where(f, np.array(anchor0) + pos - self.start_point, anchor0)
            out[:, ns + j : ns + j + 3] = np.where(f, vel, 0.0)
            out[:, 2 * ns + j : 2 * ns + j + 3] = np.where(f, acc, 0.0)
        return out
