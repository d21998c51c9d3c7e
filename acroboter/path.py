"""Desired motion (design §6): rest-to-rest quintic edges through the spec's waypoints, a quintic yaw
turn over the whole path, and the signal vector s(t), ṡ(t), s̈(t) that feeds the generated code.
"""

from __future__ import annotations

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


class DesiredPath:
    """Tracked point position and yaw, relative to a start point and start yaw."""

    def __init__(self, spec: Spec, layout: Layout, start_point: np.ndarray, start_yaw: float):
        self.layout = layout
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
        self.final_offset = waypoints[-1]
        # Moving anchors: initial positions and which world axes follow the path.
        self.anchors = [
            (layout.anchor_signal[a.name], np.array(a.position), np.array([c in a.follows_path for c in "xyz"]))
            for a in spec.anchors
            if a.follows_path
        ]

    def position(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Desired position, velocity and acceleration of the tracked point at time t."""
        k = int(np.searchsorted(self.edge_t0, t, side="right")) - 1
        k = min(max(k, 0), len(self.edge_duration) - 1)
        T = self.edge_duration[k]
        s, ds, dds = quintic((t - self.edge_t0[k]) / T)
        d = self.edge_delta[k]
        return self.start_point + self.edge_start[k] + s * d, (ds / T) * d, (dds / T**2) * d

    def yaw(self, t: float) -> tuple[float, float, float]:
        s, ds, dds = quintic(t / self.duration)
        return (
            self.start_yaw + self.yaw_turn * s,
            self.yaw_turn * ds / self.duration,
            self.yaw_turn * dds / self.duration**2,
        )

    def signals(self, t: float, s: np.ndarray, sd: np.ndarray, sdd: np.ndarray) -> None:
        """Write s(t), ṡ(t), s̈(t) into the given arrays (layout order: anchors, then x y z yaw)."""
        pos, vel, acc = self.position(t)
        yaw, yaw_d, yaw_dd = self.yaw(t)
        p = self.layout.path_signal
        s[p : p + 3], sd[p : p + 3], sdd[p : p + 3] = pos, vel, acc
        s[p + 3], sd[p + 3], sdd[p + 3] = yaw, yaw_d, yaw_dd
        for j, anchor0, follows in self.anchors:
            s[j : j + 3] = np.where(follows, anchor0 + pos - self.start_point, anchor0)
            sd[j : j + 3] = np.where(follows, vel, 0.0)
            sdd[j : j + 3] = np.where(follows, acc, 0.0)

    def signal_arrays(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        ns = self.layout.n_signals
        s, sd, sdd = np.zeros(ns), np.zeros(ns), np.zeros(ns)
        self.signals(t, s, sd, sdd)
        return s, sd, sdd
