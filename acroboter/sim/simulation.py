"""Closed loop: the controller every control period, the plant's RK4 in between (zero-order hold)."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from ..control.controllers import Controller, SingularSystemError
from ..control.path import DesiredPath, motion_time_scale
from ..model.spec import MAX_CONTROL_STEPS
from .plant import Plant, SimulationError
from .plants import PLANTS, check_mujoco_timestep, setup_default  # noqa: F401 (the names' old home)
from .records import DIVERGENCE_LIMIT_M, Records, RunResult, Scenario
from .sensing import REASONS, SensingError, describe
from .stateful_controller import STEP_CODES, StatefulController

# Control periods whose plant stage signals are evaluated at once (see simulate).
STAGE_CHUNK = 500
# A diverged run on a path whose time scale (peak speed / peak acceleration, 0.325 of a quintic edge's duration) is
# below this many control periods is reported as a path too fast for the crane: a sampled controller that holds its
# input a period cannot follow an edge of fewer than about six periods, whatever the plant then says.
TOO_FAST_PERIODS = 2.0


def simulate(
    model,
    path: DesiredPath,
    controller: Controller,
    plant: Plant,
    q0: np.ndarray,
    duration: float,
    rate_hz: float,
    plant_step: float,
    progress=None,
    energy: bool = False,
    allow_divergence: bool = False,
    sensor=None,
    qd0: np.ndarray | None = None,
) -> RunResult:
    """Run the closed loop from rest at q0 for `duration` seconds.

    The path's signals are evaluated once for the whole run (vectorized) at every RK4 stage time
    for the plant; the controller evaluates them itself at each control instant (that is part of
    its timed step, as on a real controller). With energy=True the mechanical energy
    and the integrated works are recorded at every instant (with the impacts' kinetic energy change
    as "impacts": mechanical − mechanical[0] = work_inputs + work_anchors − dissipated + impacts).
    Every instant also records the cables' tensions and activity and the controller's limit_state.

    A run diverges when the state or input stops being finite, the controller's system turns
    singular, the plant's cables find no consistent taut/slack state (chattering), or the tracked
    point strays more than DIVERGENCE_LIMIT_M from the path. That raises
    SimulationError, or with allow_divergence returns the run up to that instant with
    `diverged_at` and `divergence` set.

    `qd0`: the plant's initial velocities (default at rest).

    `sensor` (acroboter.sim.sensing.Estimator, reset here to q0): the controller reads its estimate from
    measurements instead of the plant's state; the records stay the plant's (docs/sensing.md).

    The phases: the run's periods checked (`RunTiming`), its records allocated (`Records`), the loop
    (`ClosedLoop.run`: command, record, plant step, per control instant), the result cut at a divergence.
    """
    timing = RunTiming.of(duration, rate_hz, plant_step)
    records = Records(model.layout, plant, timing.samples, timing.period, energy, sensor)
    loop = ClosedLoop(model, path, controller, plant, sensor, timing, records)
    x = plant.initial_state(q0, qd0)
    loop.start(q0)
    wall0 = time.perf_counter()
    kept, stop = loop.run(x, progress)
    wall = time.perf_counter() - wall0
    if stop is not None:
        diverged_at, divergence = stop
        # x is the plant's state at the last instant the controller computed (a failure stops before the plant step)
        if sensor is not None and (trouble := sensor.trouble(x[: model.layout.n])) is not None:
            divergence = f"{trouble}; then {divergence}"
        if (too_fast := path_too_fast(path, timing)) is not None:
            divergence = f"{too_fast}; then {divergence}"
        elif (unstable := unstable_loop(model, path, controller, q0, qd0, diverged_at)) is not None:
            divergence = f"{unstable}; then {divergence}"
        if not allow_divergence or kept == 0:  # kept == 0: not one instant was recorded, nothing to report
            raise SimulationError(f"{controller.name}: the loop diverged at t = {diverged_at:.2f} s: {divergence}")
        records.keep(kept)  # the instants before it went wrong
        return records.result(controller.name, plant, wall, diverged_at, divergence)
    return records.result(controller.name, plant, wall, None, None)


def unstable_loop(model, path: DesiredPath, controller: Controller, q0: np.ndarray, qd0,
                  diverged_at: float) -> str | None:
    """What to say of a loop that is unstable at the run's start (acroboter.sim.loop_stability) with a mode that grows
    at least e-fold before `diverged_at`; None when it is not, or the analysis cannot be made. A diagnosis only:
    whatever it raises, the divergence is still reported."""
    from .loop_stability import loop_stability

    gains = getattr(controller, "gains", None)
    if gains is None:
        return None
    qd = np.zeros_like(q0) if qd0 is None else qd0
    try:
        return loop_stability(model, path, gains, controller.name, q0, qd, 0.0).describe(diverged_at)
    except Exception:  # noqa: BLE001 (a diagnosis must never hide the divergence it explains)
        return None


def path_too_fast(path: DesiredPath, timing: RunTiming) -> str | None:
    """What to say of a path too fast for the sampled controller (None when it is not): its time scale against the
    control period."""
    scale = motion_time_scale(path, timing.steps * timing.period)
    if not scale < TOO_FAST_PERIODS * timing.period:
        return None
    return (f"the path is too fast for the crane: it changes on a time scale of {1e3 * scale:.3g} ms (peak speed / "
            f"peak acceleration), {scale / timing.period:.2g} control periods of {1e3 * timing.period:.3g} ms where a "
            f"sampled controller needs at least {TOO_FAST_PERIODS:g}; slow it (path.mean_speed, the trajectory's "
            "timing, or `acroboter plan`)")


@dataclass(frozen=True)
class RunTiming:
    """A run's control instants and plant steps, checked: `steps` control periods of `period` s, each `substeps`
    plant steps of `h` s."""

    period: float
    substeps: int
    h: float
    steps: int

    @property
    def samples(self) -> int:
        return self.steps + 1

    @classmethod
    def of(cls, duration: float, rate_hz: float, plant_step: float) -> RunTiming:
        period = 1.0 / rate_hz
        substeps = round(period / plant_step)
        if substeps < 1 or not math.isclose(substeps * plant_step, period, rel_tol=1e-9):
            raise SimulationError(
                f"the plant step {plant_step} s must divide the control period {period} s: "
                "fix simulation.step or controller.rate_hz in the spec"
            )
        if not (math.isfinite(duration) and duration > 0):
            raise SimulationError(f"the duration must be a positive number of seconds, found {duration}")
        steps = int(round(duration * rate_hz))
        if steps < 1:
            raise SimulationError(f"{duration:g} s at {rate_hz:g} Hz is no control step: simulate at least one "
                                  f"control period ({1 / rate_hz:g} s)")
        if steps > MAX_CONTROL_STEPS:
            raise SimulationError(
                f"{duration:g} s at {rate_hz:g} Hz is {steps} control steps, more than {MAX_CONTROL_STEPS} (the "
                "records would not fit in memory): shorten the duration or the path (path.mean_speed)"
            )
        return cls(period, substeps, period / substeps, steps)


class _Stop(Exception):
    """The loop ends early at t for `reason`; `recorded`: whether instant k is in the records."""

    def __init__(self, t: float, reason: str, recorded: bool = False):
        self.t, self.reason, self.recorded = t, reason, recorded


class ClosedLoop:
    """One run's loop: per control instant the command (`command`), the records (`record`), the plant's
    substeps to the next instant (`advance`)."""

    def __init__(self, model, path: DesiredPath, controller: Controller, plant: Plant, sensor, timing: RunTiming,
                 records: Records):
        self.model, self.path, self.controller, self.plant, self.sensor = model, path, controller, plant, sensor
        self.timing, self.records = timing, records
        self.n, self.p = model.layout.n, model.layout.path_signal
        self.sigma_fn, self.phi_fn = model.functions["sigma"], model.functions["phi"]
        self.sigma_out, self.phi_out = self.sigma_fn.outputs["sigma"], self.phi_fn.outputs["phi"]
        self.position_rows = Scenario.from_model(model).position_rows
        self.loads = getattr(controller, "loads_model", True)  # whether compute() leaves the state and signals
        self.stateful: StatefulController | None = None
        self.table, self.chunk_start = None, -STAGE_CHUNK

    def start(self, q0: np.ndarray) -> None:
        """With sensing, the exported controller's step (StatefulController) initialised at q0."""
        if self.sensor is None:
            return
        self.stateful = StatefulController(self.model, self.path, self.controller, self.sensor)
        self.stateful.strict = True  # a singular system is the divergence below, as without sensing
        if self.stateful.init(q0) != 0:
            raise SimulationError(f"{self.controller.name}: the run cannot start at q0: {self.stateful.problem}")

    def run(self, x: np.ndarray, progress) -> tuple[int, tuple[float, str] | None]:
        """(instants recorded, None) or, at a divergence, (instants kept, (t, why))."""
        steps = self.timing.steps
        for k in range(self.timing.samples):
            t = self.records.t[k]
            try:
                self._stage_table(k)
                u = self.command(k, x, t)
                self.record(k, x, u, t)
                if k == steps:
                    return k + 1, None
                self.advance(k, x, t)
            except _Stop as stop:
                return (k + 1 if stop.recorded else k), (stop.t, stop.reason)
            if progress is not None:
                progress(1)
        return self.timing.samples, None

    def _stage_table(self, k: int) -> None:
        """The plant's stage signals, evaluated (vectorized) a chunk of control periods at a time: the run's memory
        is its records, not a table of every RK4 stage of the whole run."""
        if k - self.chunk_start >= STAGE_CHUNK:
            self.chunk_start = k
            substeps = self.timing.substeps
            count = min(STAGE_CHUNK, max(self.timing.steps - k, 1)) * substeps
            self.table = self.plant.stage_rows(self.timing.h, k * substeps, count)

    def command(self, k: int, x: np.ndarray, t: float) -> np.ndarray:
        """The controller's u at instant k (timed: with sensing, the measurement, its checks, projection and
        velocity estimate are part of the step)."""
        q, qd, rec = x[: self.n], x[self.n : 2 * self.n], self.records
        t0 = time.perf_counter()
        try:
            if self.sensor is None:
                u = self.controller.compute(q, qd, t)  # evaluates the path itself: the timed step is all of it
            else:
                y = self.sensor.sample(q)
                code = self.stateful.step(y, t)
                u = self.stateful.u
                rec.y[k], rec.qhat[k], rec.qdhat[k], rec.code[k] = y, self.stateful.q, self.stateful.qd, code
                if code not in (0, 4):  # no trustworthy command: the exported controller would hold its last one
                    raise _Stop(t, _no_command(self.stateful, self.sensor))
        except SingularSystemError as err:
            if k == 0:
                if self.sensor is not None and (trouble := self.sensor.trouble(q)) is not None:  # the estimate's
                    raise SensingError(f"{self.controller.name}: {trouble}; at that estimate its system has no "
                                       f"solution ({err})") from None
                raise  # not a divergence: the method cannot handle this system at all
            raise _Stop(t, str(err) if np.isfinite(x).all() else "the state became non-finite") from None
        rec.step_s[k] = time.perf_counter() - t0
        if not (np.isfinite(u).all() and np.isfinite(x).all()):
            raise _Stop(t, "the state or input became non-finite")
        return u

    def record(self, k: int, x: np.ndarray, u: np.ndarray, t: float) -> None:
        """Instant k's records; a tracked point strayed beyond DIVERGENCE_LIMIT_M stops the run (instant k kept)."""
        n, p, rec, plant, model = self.n, self.p, self.records, self.plant, self.model
        q, qd = x[:n], x[n : 2 * n]
        rec.q[k], rec.qd[k], rec.u[k] = q, qd, u
        rec.limit[k] = self.controller.limit_state
        rec.saturated[k] = self.controller.saturation()  # a report on the step, after its timing
        rec.impact[k] = plant.impact_energy
        rec.gap[k] = plant.cable_gap
        if rec.checks_energy:
            rec.residual[k] = plant.energy_residual
        if self.sensor is not None or not self.loads:  # the records are the plant's state, at the path's signals
            model.q[:], model.qd[:] = q, qd
            if not self.loads:  # an open-loop driver loads nothing: the path's signals at t too
                model.signals[:] = self.path.flat(t)
        self.sigma_fn.call()  # at the state and signals the controller just loaded
        self.phi_fn.call()
        rec.sigma[k], rec.phi[k] = self.sigma_out, self.phi_out
        row = self.table[2 * self.timing.substeps * (k - self.chunk_start)]
        rec.desired[k] = row[p : p + 4]
        rec.anchors[k] = row[:p]
        if rec.energy is not None:
            rec.energy[k, 0] = plant.mechanical_energy(q, qd)
            rec.energy[k, 1:] = x[2 * n :]
        strayed = np.abs(self.sigma_out[self.position_rows]).max() > DIVERGENCE_LIMIT_M
        if strayed or k == self.timing.steps:  # no step follows: the tensions a step from here would start with
            plant.probe(x, rec.u[k], t)
            rec.tension[k], rec.active[k] = plant.start_tension, plant.start_active
        if strayed:
            raise _Stop(t, f"the tracked point strayed more than {DIVERGENCE_LIMIT_M} m from the path", True)

    def advance(self, k: int, x: np.ndarray, t: float) -> None:
        """The plant's substeps to instant k + 1 under the held input, and the tensions it started with."""
        rec, plant, substeps = self.records, self.plant, self.timing.substeps
        try:
            plant.advance(x, rec.u[k], self.timing.h, self.table, (k - self.chunk_start) * substeps, substeps)
        except SimulationError as err:  # the plant found no consistent cable state (x is left at instant k)
            plant.probe(x, rec.u[k], t)
            rec.tension[k], rec.active[k] = plant.start_tension, plant.start_active
            raise _Stop(t, str(err), True) from None
        rec.tension[k], rec.active[k] = plant.start_tension, plant.start_active


def _no_command(stateful: StatefulController, sensor) -> str:
    """Why the controller had no trustworthy command (a step code other than 0 and 4), naming the sensing."""
    code = stateful.code
    if code == 5:
        j = sensor.rejected
        where = f" at y[{j}] {stateful.model.layout.coordinates[sensor.index[j]]}" if j >= 0 else ""
        s = sensor.sensing
        gate = (f"; the gate: max_speed = {s.max_speed:g} m/s, max_axis_rate = {s.max_axis_rate:g} 1/s"
                if sensor.reason in (3, 5) else "")
        count = (f"{sensor.checks.max_coast + 1} samples in a row rejected" if sensor.coasted > sensor.checks.max_coast
                 else "more than a third of the samples rejected")
        return (f"the controller's estimate was lost: {count}, the last {REASONS[sensor.reason]}{where} (sensing: "
                f"{describe(s)}{gate}); it holds its last good command until two consecutive samples agree "
                "(docs/sensing.md, \"Bad samples\")")
    return f"the controller's step returned {code}: {STEP_CODES[code]}"
