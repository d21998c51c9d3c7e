"""Where inside a plant step a cable changes state: the located instants of acroboter.sim.cable_events.

Both searches run a partial RK4 step of a fraction θ of the step from its start (the path's signals at t,
t + θh/2, t + θh) for each evaluation, and find θ by Illinois regula falsi:

- **A slack cable comes taut** (`_locate`): its gap comes up through contact, to |gap| ≤ GAP_TOL
  (`_first_crossing`, whose docstring says how a dip too shallow to see is still bracketed).
- **A taut cable goes slack** (`_slack_onset`): its tension, from the plant's own multiplier system at the
  end of the partial step, comes down through zero, to within [−tension_tol, 0]. The generated step flags
  such a step (its last RK4 stage estimates the end tension, at x + h·k3); the tension here is the exact one at
  each θ. A crossing so near the step's end that the estimate misses it is caught at the next step's start, as
  every crossing was before, having pushed for a small part of a step. Why: switched at the start of the next
  step, the cable pushed for up to a whole step. On a
  generated crane whose light drum made a cable's tension fall by 6 N within a step, that push set the own
  plant 52 mm off MuJoCo after a cascade of 242 events, and off itself at half the step by as much: the
  error shrank only as h² (docs/plant-fuzz-cranes.md).

The methods are a mixin of acroboter.sim.plant.Plant (through CableEvents): they use its step binding and
buffers, and leave the x buffer and the step's outputs as their docstrings say.
"""

from __future__ import annotations

import numpy as np

# The earliest fraction of a step at which a return to contact is located (below it: at the start).
THETA_MIN = 1e-9
# A change of a gap smaller than this (m) within a step is not told from round-off (|d| − L of ~1 m).
GAP_RESOLUTION = 1e-13


def illinois(f, lo: float, hi: float, f_lo: float, f_hi: float, close) -> tuple[float, float]:
    """Illinois regula falsi for the root of f on [lo, hi], lo < hi, f_lo < 0 < f_hi: the θ where
    close(f(θ), θ) holds, or the last one tried when the bracket has shrunk to 1e-15, and f there."""
    side = 0
    theta, value = hi, f_hi
    for _ in range(200):
        theta = (lo * f_hi - hi * f_lo) / (f_hi - f_lo)
        if not lo < theta < hi:
            theta = 0.5 * (lo + hi)
        value = f(theta)
        if close(value, theta) or hi - lo <= 1e-15:
            break
        if value < 0.0:
            lo, f_lo = theta, value
            if side == -1:
                f_hi *= 0.5  # Illinois: keep the stale end from stalling the secant
            side = -1
        else:
            hi, f_hi = theta, value
            if side == 1:
                f_lo *= 0.5
            side = 1
    return theta, value


class CableCrossings:
    """The located instants of the plant's cable events (see the module docstring)."""

    def _gaps_after(self, x_start: np.ndarray, t: float, h: float, address: int | None = None) -> np.ndarray:
        """The cable gaps after an RK4 step of length h from x_start at t (x buffer: x_start)."""
        self._x[:] = x_start
        self._point_step(t, h, address)
        self._step.call()
        return self._gap

    def _first_crossing(self, x_start, t: float, h: float, cable: int, address: int | None) -> float | None:
        """The θ in (0, 1] where the slack `cable`'s gap g(θ) comes up through its contact level in the
        step of length h from x_start (to GAP_TOL), None if it does not come up inside the step.

        A cable below contact at the start (g(0) < −GAP_TOL) is bracketed by [0, 1] on g itself. A
        cable at contact at the start (|g(0)| ≤ GAP_TOL) that separates and comes back is located on
        the secant slope f(θ) = (g(θ) − g(0))/θ instead: f starts at the separation rate (× h, < 0)
        and ends at g(1) − g(0) > 0, so its root, the return, is bracketed however shallow the dip
        (g itself may never go below −GAP_TOL in a micro-second dip: scanning g for such a point
        missed returns and let the cable end the step stretched, the cascade of issue 18). The lower
        end of the bracket is the first θ of THETA_MIN, 10 THETA_MIN, ... at which g has moved by more
        than GAP_RESOLUTION from g(0) (below that its change is round-off, of either sign). If it has
        moved up there, the cable is coming up from the start: that θ is returned (the impact there
        takes it taut, or leaves it slack if its impulse would push)."""
        gap_tol = self.gap_tol

        def g(theta: float) -> float:
            return float(self._gaps_after(x_start, t, theta * h, address if theta == 1.0 else None)[cable])

        g0, g1 = g(0.0), g(1.0)
        if g0 < -gap_tol:
            f, lo, hi, f_lo, f_hi = g, 0.0, 1.0, g0, g1
        else:
            if g1 - g0 <= gap_tol:  # not coming up beyond where it started: no crossing in this step
                return None

            def f(theta: float) -> float:
                return (g(theta) - g0) / theta

            lo, hi, f_hi = THETA_MIN, 1.0, g1 - g0
            while True:
                f_lo = f(lo)
                if abs(f_lo) * lo > GAP_RESOLUTION or lo >= 0.1:
                    break
                lo *= 10.0
            if f_lo >= 0.0:
                return lo
        return illinois(f, lo, hi, f_lo, f_hi,
                        lambda value, theta: abs(value if f is g else value * theta) <= gap_tol)[0]

    def _tensions_after(self, x_start: np.ndarray, t: float, h: float, address: int | None = None) -> np.ndarray:
        """Every cable's tension (N, the current mask's multiplier system) at the end of an RK4 step of length h
        from x_start at t; the x buffer holds that end state afterwards, the step's outputs a step of length 0
        from it."""
        self._gaps_after(x_start, t, h, address)
        self._x[:] = self._x_next
        self._set_stage(t + h, 0.0)
        self._step.call()
        return self._tension

    def _slack_onset(self, x_start: np.ndarray, t: float, h: float, address: int | None):
        """The earliest θ in [0, 1] at which a taut cable's tension comes down through zero in the step of
        length h from x_start (to within [−tension_tol, 0]), with that cable and the state there; None if every
        taut cable still pulls at the step's end. Leaves the x buffer and the step's outputs undefined."""
        tol = self.tension_tol
        end = self._tensions_after(x_start, t, h, address).copy()
        taut = [c for c in self._modelled if self._active[c] == 1.0 and end[c] < -tol]
        best = None
        for c in taut:
            def f(theta: float, c: int = c) -> float:  # > 0 once the tension is below −tol/2
                return -(float(self._tensions_after(x_start, t, theta * h)[c]) + 0.5 * tol)

            f_lo, f_hi = f(0.0), -(float(end[c]) + 0.5 * tol)
            if f_lo >= 0.0:
                # below −tol/2 already at the start: the start's force-level decision kept it taut (its least
                # violating mask, within the push tolerance); released here, _settle would take it taut again
                continue
            theta = illinois(f, 0.0, 1.0, f_lo, f_hi, lambda value, _theta: abs(value) <= 0.5 * tol)[0]
            if best is None or theta < best[0]:
                best = (theta, c)
        if best is None:
            return None
        theta, cable = best
        self._gaps_after(x_start, t, theta * h, address if theta == 1.0 else None)
        return theta, cable, self._x_next.copy()

    def _locate(self, x_start, t: float, h: float, candidates: list[int], address: int | None):
        """The earliest crossing among the candidates: (θ, the state there, every cable's gap there),
        or None when none crosses inside the step."""
        thetas = [th for c in candidates if (th := self._first_crossing(x_start, t, h, c, address)) is not None]
        if not thetas:
            self._gaps_after(x_start, t, h, address)  # leave the whole step's result in the outputs
            return None
        theta = min(thetas)
        self._gaps_after(x_start, t, theta * h, address if theta == 1.0 else None)
        return theta, self._x_next.copy(), self._gap.copy()

