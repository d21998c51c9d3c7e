"""Open loop: the plant driven by inputs the user gives, not by a controller.

What it is for: the plant's own truth (cables that go slack and snap taut, energy, the swing) on
inputs nobody tuned, compared against another engine (tests/test_plant_fuzz.py drives the own plant
and MuJoCo with the same generated inputs). `inputs` is a function t -> u (N, N·m; evaluated at each
control instant and held for the period, as a controller's output is) or an array with one row per
control instant. The inputs are validated once, before any work (shape, finite). The spec's input
limits are not applied: an open-loop input is what the user asks, and the run's summary lists, per
input, the instants at which it was outside the limits (`inputs_outside_limits`). The moving anchors
follow `path` (acroboter.api.crane holds them at the spec's start by default).

The run is the closed loop's (acroboter.sim.simulation.simulate) with this module's OpenLoopInputs in
the controller's place: the same records, invariants, summary and CSV.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ..control.path import DesiredPath, TrajectoryPath
from .records import RunResult
from .simulation import simulate

OPEN_LOOP = "open loop"


class OpenLoopError(ValueError):
    """Open-loop inputs that cannot be run (shape, non-finite values, a failing function)."""


class OpenLoopInputs:
    """The inputs of every control instant, evaluated and checked up front; `compute` hands them out
    in the controller's place (the state it is given is not looked at)."""

    name = OPEN_LOOP
    loads_model = False  # compute() writes no buffer: simulate loads the plant's state and the path for its records

    def __init__(self, inputs, times: np.ndarray, input_names: list[str]):
        l = len(input_names)
        self.table = _table(inputs, times, l, input_names)
        self._times = times
        self._period = float(times[1] - times[0]) if len(times) > 1 else 1.0
        self.limit_state = np.zeros(l, dtype=np.int8)
        self.qdd = None

    def compute(self, q: np.ndarray, qd: np.ndarray, t: float) -> np.ndarray:
        return self.table[min(int(round(t / self._period)), len(self.table) - 1)]

    def saturation(self) -> bool:
        return False

    def outside_limits(self, lower: np.ndarray, upper: np.ndarray, input_names: list[str]) -> dict[str, dict]:
        """Per input outside its limits at some instant: how many instants, the first and the range."""
        out = {}
        for i, name in enumerate(input_names):
            column = self.table[:, i]
            beyond = (column < lower[i]) | (column > upper[i])
            if beyond.any():
                out[name] = {"instants": int(beyond.sum()), "first_s": float(self._times[int(np.argmax(beyond))]),
                             "min": float(column.min()), "max": float(column.max()),
                             "limits": [float(lower[i]), float(upper[i])]}
        return out


def _table(inputs, times: np.ndarray, l: int, names: list[str]) -> np.ndarray:
    """One row of l inputs per instant in `times` (the last instant's row is recorded, not applied)."""
    if callable(inputs):
        rows = []
        for t in times:
            try:
                u = np.asarray(inputs(float(t)), dtype=float)
            except Exception as err:  # the user's function: name it, whatever it raised
                raise OpenLoopError(f"the inputs function failed at t = {t:g} s: {err}") from err
            if u.shape != (l,):
                raise OpenLoopError(f"the inputs function returned shape {u.shape} at t = {t:g} s: expected ({l},), "
                                    f"one value per input ({', '.join(names)})")
            rows.append(u)
        table = np.array(rows)
    else:
        try:
            table = np.array(inputs, dtype=float)
        except (TypeError, ValueError) as err:
            raise OpenLoopError(f"inputs: expected a function of t or an array of numbers ({err})") from None
        if table.ndim != 2 or table.shape[1] != l or table.shape[0] not in (len(times) - 1, len(times)):
            raise OpenLoopError(f"inputs: expected an array of {len(times) - 1} rows (one per control instant) and "
                                f"{l} columns ({', '.join(names)}), found shape {table.shape}")
        if table.shape[0] == len(times) - 1:  # the last instant repeats the last row (it is only recorded)
            table = np.vstack([table, table[-1:]])
    bad = ~np.isfinite(table)
    if bad.any():
        k, i = np.argwhere(bad)[0]
        raise OpenLoopError(f"inputs: {names[i]} is {table[k, i]} at t = {times[k]:g} s: every input must be finite")
    return np.ascontiguousarray(table)


def held_path(spec, layout, start: DesiredPath, duration: float) -> TrajectoryPath:
    """The spec's anchors held where the path starts (the climbing unit at rest) for `duration`."""
    point = start.position(0.0)[0]

    def still(times):
        times = np.asarray(times, dtype=float)
        return np.tile(point, (times.size, 1)), np.zeros((times.size, 3)), np.zeros((times.size, 3))

    return TrajectoryPath(spec, layout, still, duration, start.start_yaw)


def simulate_open_loop(model, path: DesiredPath, plant, q0: np.ndarray, inputs: np.ndarray | Callable,
                       duration: float, rate_hz: float, plant_step: float, qd0: np.ndarray | None = None,
                       progress=None) -> RunResult:
    """The plant from (q0, qd0) under `inputs` for `duration` seconds (see the module docstring).
    A broken invariant or a state that leaves any sensible motion ends the run early with
    `diverged_at` and the reason (the invariants: acroboter.sim.plant)."""
    lay = model.layout
    steps = int(round(duration * rate_hz))
    times = np.arange(steps + 1) / rate_hz
    driver = OpenLoopInputs(inputs, times, list(lay.inputs))
    lower, upper, _ = model.spec.input_limits()
    if hasattr(plant, "release_limits"):  # MuJoCo would clamp to ctrlrange (the own plant has no limits)
        plant.release_limits()
    run = simulate(model, path, driver, plant, q0, duration, rate_hz, plant_step, progress=progress,
                   allow_divergence=True, qd0=qd0)
    run.outside_limits = driver.outside_limits(lower, upper, list(lay.inputs))
    return run
