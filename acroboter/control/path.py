"""Desired motion (docs/model.md §5): rest-to-rest quintic edges through the spec's waypoints, a quintic yaw
turn over the whole path, and the signal vector s(t), ṡ(t), s̈(t) that feeds the generated code.

Signals are laid out flat as [s, ṡ, s̈] (3 × n_signals), the layout of CompiledModel.signals, so
one assignment loads them. `flat(t)` evaluates one instant with scalar math (it is on the
control step's hot path); `table(times)` evaluates many at once for the plant.
"""

from __future__ import annotations

import bisect
import logging
import math
import numbers
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..model.layout import Layout
from ..model.spec import Spec


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
        self._anchor_start = {}  # signal index -> the moving anchor's start coordinate (rows)
        for j, anchor0, follows in self.anchors:
            for c in range(3):
                if follows[c]:
                    self._follow.append((j + c, c, anchor0[c] - self.start_point[c]))
                    self._anchor_start[j + c] = anchor0[c]
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

    def rows(self, times) -> np.ndarray:
        """table(times) for a few instants (the plant's cable events): flat per instant, with the moving anchors'
        positions in table's order of operations ((a₀ + x) − x₀, where flat has (a₀ − x₀) + x): the same numbers
        to the bit (tests/test_plant_loop.py) at a thirtieth of table's cost on three instants."""
        out = np.array([self.flat(t) for t in times])
        p = self._path_index[0]
        for i, c, _ in self._follow:
            out[:, i] = (self._anchor_start[i] + out[:, p + c]) - self.start_point[c]
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
        k = np.clip(np.searchsorted(self.edge_t0, times, side="right") - 1, 0, len(self.edge_duration) - 1)
        T = self.edge_duration[k]
        s, ds, dds = quintic_array((times - self.edge_t0[k]) / T)
        d = self.edge_delta[k]
        pos = self.start_point + self.edge_start[k] + s[:, None] * d
        vel = (ds / T)[:, None] * d
        acc = (dds / T**2)[:, None] * d
        D = self.duration
        y, dy, ddy = quintic_array(times / D)
        yaw = np.stack([self.start_yaw + self.yaw_turn * y, self.yaw_turn * dy / D, self.yaw_turn * ddy / D**2])
        return self._signal_table(pos, vel, acc, yaw)

    def _signal_table(self, pos: np.ndarray, vel: np.ndarray, acc: np.ndarray, yaw: np.ndarray) -> np.ndarray:
        """Rows [s, ṡ, s̈] from the tracked point's motion (N x 3 each) and yaw (3 x N: angle, rate,
        acceleration); moving anchors follow the point's displacement from the start."""
        ns, p = self.n_signals, self.layout.path_signal
        out = np.zeros((pos.shape[0], 3 * ns))
        out[:, p : p + 3], out[:, ns + p : ns + p + 3], out[:, 2 * ns + p : 2 * ns + p + 3] = pos, vel, acc
        out[:, p + 3], out[:, ns + p + 3], out[:, 2 * ns + p + 3] = yaw
        for j, anchor0, follows in self.anchors:
            f = np.array(follows)
            out[:, j : j + 3] = np.where(f, np.array(anchor0) + pos - self.start_point, anchor0)
            out[:, ns + j : ns + j + 3] = np.where(f, vel, 0.0)
            out[:, 2 * ns + j : 2 * ns + j + 3] = np.where(f, acc, 0.0)
        return out


# A user's motion: t (N,) -> position (N x 3, or N x 4 with the yaw in rad last), velocity, acceleration.
Motion = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray, np.ndarray]]


def motion_time_scale(path: DesiredPath, duration: float, samples: int = 2001) -> float:
    """The tracked point's fastest time scale over [0, duration] (s): its peak speed over its peak acceleration
    (a quintic edge of T s has 0.325 T; inf for a point that does not accelerate). What a sampled controller must
    resolve: the divergence message names a path faster than that as too fast for the crane."""
    rows = path.table(np.linspace(0.0, duration, samples))
    ns, p = path.n_signals, path.layout.path_signal
    speed = float(np.linalg.norm(rows[:, ns + p: ns + p + 3], axis=1).max())
    accel = float(np.linalg.norm(rows[:, 2 * ns + p: 2 * ns + p + 3], axis=1).max())
    return speed / accel if accel > 0 else math.inf


class TrajectoryError(ValueError):
    """A user trajectory that cannot drive the controller (shapes, non-finite values, times)."""


@dataclass(frozen=True)
class SampledTrajectory:
    """A desired motion of the tracked point as samples with their derivatives (world frame, SI).

    `times` start at 0 and increase strictly; `position`, `velocity`, `acceleration` are N x 3 (x, y,
    z in m, m/s, m/s²) or N x 4 (a fourth column: the yaw in rad, rad/s, rad/s²). Between samples
    the motion is the quintic Hermite interpolant, which matches all three at every sample (so the
    desired acceleration is continuous); after the last sample it rests at the last position.
    """

    times: np.ndarray
    position: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray

    def __post_init__(self):
        arrays = {}
        for name in ("times", "position", "velocity", "acceleration"):
            try:
                value = np.array(getattr(self, name), dtype=float)
            except (TypeError, ValueError):
                raise TrajectoryError(f"trajectory {name}: expected numbers") from None
            if not np.isfinite(value).all():
                raise TrajectoryError(f"trajectory {name}: expected finite numbers, found NaN or infinity")
            arrays[name] = value
            object.__setattr__(self, name, value)
        t = arrays["times"]
        if t.ndim != 1 or t.size < 2:
            raise TrajectoryError(f"trajectory times: expected at least two samples in a 1-D array, found shape "
                                  f"{t.shape}")
        if t[0] != 0.0 or not (np.diff(t) > 0).all():
            raise TrajectoryError("trajectory times: expected to start at 0 and increase strictly")
        for name in ("position", "velocity", "acceleration"):
            shape = arrays[name].shape
            if shape not in ((t.size, 3), (t.size, 4)) or shape != arrays["position"].shape:
                raise TrajectoryError(f"trajectory {name}: expected {t.size} x 3 or {t.size} x 4 like position, "
                                      f"found {shape}")

    @property
    def duration(self) -> float:
        return float(self.times[-1])

    def __call__(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        t = np.asarray(t, dtype=float)
        k = np.clip(np.searchsorted(self.times, t, side="right") - 1, 0, self.times.size - 2)
        t0, h = self.times[k], self.times[k + 1] - self.times[k]
        tau = np.clip((t - t0) / h, 0.0, 1.0)[:, None]
        p0, p1 = self.position[k], self.position[k + 1]
        v0, v1 = self.velocity[k] * h[:, None], self.velocity[k + 1] * h[:, None]
        a0, a1 = self.acceleration[k] * (h**2)[:, None], self.acceleration[k + 1] * (h**2)[:, None]
        pos, vel, acc = _quintic_hermite(tau, p0, v0, a0, p1, v1, a1)
        vel, acc = vel / h[:, None], acc / (h**2)[:, None]
        after = t > self.times[-1]  # at rest at the end
        pos[after], vel[after], acc[after] = self.position[-1], 0.0, 0.0
        return pos, vel, acc


def sped_up(trajectory: SampledTrajectory, factor: float) -> SampledTrajectory:
    """The same geometry flown `factor` times faster: p'(t) = p(f t), so the samples move to t/f, the velocities
    (the yaw rate too) are multiplied by f and the accelerations by f². factor > 1 speeds up, < 1 slows down."""
    if isinstance(factor, bool) or not (isinstance(factor, numbers.Real) and math.isfinite(factor) and factor > 0):
        raise TrajectoryError(f"speed-up factor: expected a positive number, found {factor!r}")
    f = float(factor)
    return SampledTrajectory(trajectory.times / f, trajectory.position.copy(), trajectory.velocity * f,
                             trajectory.acceleration * f**2)


def _quintic_hermite(tau, p0, v0, a0, p1, v1, a1):
    """The quintic with value, first and second derivative (in τ) p, v, a at τ = 0 and τ = 1."""
    t2, t3 = tau * tau, tau * tau * tau
    t4, t5 = t3 * tau, t3 * t2
    h = [1 - 10 * t3 + 15 * t4 - 6 * t5, tau - 6 * t3 + 8 * t4 - 3 * t5, 0.5 * (t2 - 3 * t3 + 3 * t4 - t5),
         10 * t3 - 15 * t4 + 6 * t5, -4 * t3 + 7 * t4 - 3 * t5, 0.5 * (t3 - 2 * t4 + t5)]
    dh = [-30 * t2 + 60 * t3 - 30 * t4, 1 - 18 * t2 + 32 * t3 - 15 * t4, tau - 4.5 * t2 + 6 * t3 - 2.5 * t4,
          30 * t2 - 60 * t3 + 30 * t4, -12 * t2 + 28 * t3 - 15 * t4, 1.5 * t2 - 4 * t3 + 2.5 * t4]
    ddh = [-60 * tau + 180 * t2 - 120 * t3, -36 * tau + 96 * t2 - 60 * t3, 1 - 9 * tau + 18 * t2 - 10 * t3,
           60 * tau - 180 * t2 + 120 * t3, -24 * tau + 84 * t2 - 60 * t3, 3 * tau - 12 * t2 + 10 * t3]
    coeffs = (p0, v0, a0, p1, v1, a1)
    return tuple(sum(b * c for b, c in zip(basis, coeffs, strict=True)) for basis in (h, dh, ddh))


class TrajectoryPath(DesiredPath):
    """The signals of a crane driven along a user's motion instead of the spec's waypoints.

    `motion(t)` gives the tracked point's position, velocity and acceleration (N x 3, or N x 4 with
    the yaw) for an array of times; without a yaw column the yaw stays at its start value. Anchors
    that follow the path move with the point's displacement from its position at t = 0.
    """

    def __init__(self, spec: Spec, layout: Layout, motion: Motion, duration: float, start_yaw: float):
        if not (math.isfinite(duration) and duration > 0):
            raise TrajectoryError(f"trajectory duration: expected a positive number of seconds, found {duration}")
        self.motion, self._fixed_yaw = motion, float(start_yaw)
        pos, vel, _ = self._evaluate(np.zeros(1))
        speed = float(np.linalg.norm(vel[0, :3]))
        if speed > 1e-9:  # the closed loop starts from the static equilibrium, at rest
            logging.getLogger(__name__).warning(
                "the trajectory starts moving (%.3g m/s at t = 0) but the crane starts at rest: expect a "
                "tracking transient at the start", speed)
        super().__init__(spec, layout, pos[0, :3], float(pos[0, 3]) if pos.shape[1] == 4 else start_yaw)
        self.duration = float(duration)

    def _evaluate(self, times: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        try:
            out = tuple(np.asarray(v, dtype=float) for v in self.motion(times))
        except Exception as err:  # the user's function: name it, whatever it raised
            raise TrajectoryError(f"the trajectory function failed at t = {times[0]:g} s: {err}") from err
        if len(out) != 3:
            raise TrajectoryError("the trajectory function must return (position, velocity, acceleration)")
        for name, value in zip(("position", "velocity", "acceleration"), out, strict=True):
            if value.shape not in ((times.size, 3), (times.size, 4)):
                raise TrajectoryError(f"the trajectory function's {name} for {times.size} times is {value.shape}, "
                                      f"expected {times.size} x 3 or {times.size} x 4")
            bad = ~np.isfinite(value).all(axis=1)
            if bad.any():
                raise TrajectoryError(f"the trajectory function's {name} is not finite at t = "
                                      f"{times[np.argmax(bad)]:g} s")
        return out

    def table(self, times: np.ndarray) -> np.ndarray:
        times = np.atleast_1d(np.asarray(times, dtype=float))
        pos, vel, acc = self._evaluate(times)
        if pos.shape[1] == 4:
            yaw = np.stack([pos[:, 3], vel[:, 3], acc[:, 3]])
        else:
            yaw = np.stack([np.full(times.size, self._fixed_yaw), np.zeros(times.size), np.zeros(times.size)])
        return self._signal_table(pos[:, :3], vel[:, :3], acc[:, :3], yaw)

    def flat(self, t: float) -> list[float]:
        return self.table(np.array([float(t)]))[0].tolist()

    def rows(self, times) -> np.ndarray:
        return self.table(np.array(times, dtype=float))
