"""Closed loop: the controller every control period, the plant's RK4 in between (zero-order hold)."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from ..control.controllers import Controller, SingularSystemError
from ..control.path import DesiredPath
from ..model.spec import MAX_CONTROL_STEPS, PositionTask, WinchTension, YawTask
from ..runtime.compiled import CompiledModel
from .plant import Plant, SimulationError
from .plants import PLANTS, check_mujoco_timestep, setup_default  # noqa: F401 (the names' old home)
from .sensing import REASONS, SensingError, describe
from .stateful import STEP_CODES, StatefulController


@dataclass
class RunResult:
    method: str
    t: np.ndarray  # control instants
    q: np.ndarray  # state at each instant
    qd: np.ndarray
    u: np.ndarray  # input computed at each instant, held until the next
    sigma: np.ndarray  # servo-constraint values at each instant
    phi: np.ndarray  # geometric constraint values at each instant
    desired: np.ndarray  # x_d, y_d, z_d, yaw_d at each instant
    control_step_s: np.ndarray  # wall time of each controller call
    sim_wall_s: float
    # With energy=True, per instant: mechanical energy T + U, and the work so far of the inputs, of the
    # moving anchors (through the constraint forces), and the energy dissipated by damping.
    energy: dict[str, np.ndarray] = field(default_factory=dict)
    # With allow_divergence: when and why the run was stopped early (None: it ran to the end).
    diverged_at: float | None = None
    divergence: str | None = None
    # Cables (spec order, names in cable_names), per instant: the tension (N) at the start of the
    # plant step that follows the instant (for the last instant: the tension a step from there with
    # the input computed at that instant would start with, Plant.probe), and whether the cable was
    # taut (1) or slack (0) in that step.
    cable_names: list[str] = field(default_factory=list)
    cable_tension: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    cable_active: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), dtype=np.int8))
    # Per cable: how often it switched between taut and slack during the run (the plant's count,
    # including switches that are undone before the next instant).
    cable_transitions: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    # Per instant: Σ (T⁺ − T⁻) of the plant's inelastic cable impacts so far (J, ≤ 0 for fixed anchors).
    impact_energy: np.ndarray = field(default_factory=lambda: np.zeros(0))
    # Per instant and input: the controller's limit_state (−1 at the lower limit, +1 at the upper, 0 free).
    limit_state: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), dtype=np.int8))
    # Per instant: whether a limit kept the input from what the controller asked of the task.
    saturated: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))
    control_period: float = 0.0  # s
    # The plant's physical parameters other than the spec's (acroboter.model.physical); {}: the model's crane.
    plant_params: dict[str, float] = field(default_factory=dict)
    # Per instant: the moving anchors' positions (m), 3 columns per anchor in layout order
    # (layout.anchor_signal), so that a run can be drawn without its path.
    anchors: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    # Per instant and cable: |p_a − p_b| − L (m; > 0 stretched, < 0 slack by that much), at the end of the
    # plant step before the instant (the start's for the first).
    cable_gap: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    # Per instant: the plant's energy balance residual (J, Plant.energy_balance; None for MuJoCo, whose
    # soft cable limits dissipate energy of their own) and the bound the plant holds it to.
    energy_residual: np.ndarray | None = None
    energy_bound: float | None = None
    # From when (s) the residual is checked: 0, or once a plant that started off its constraints has
    # closed them (Plant._check_energy); None: never within the run.
    energy_checked_from: float | None = None
    # Open loop (acroboter.sim.open_loop): per input, the instants at which it was outside the spec's limits.
    outside_limits: dict[str, dict] | None = None
    # With sensing, per instant: the measurement the estimator read (columns: measured_names), the estimate the
    # controller used, and the step's code (acroboter.sim.stateful.STEP_CODES: 0 accepted, 4 coasted).
    measured_names: list[str] | None = None
    measurements: np.ndarray | None = None
    estimate_q: np.ndarray | None = None
    estimate_qd: np.ndarray | None = None
    step_code: np.ndarray | None = None


# A run that strays this far from the path (m) has diverged: nothing useful follows.
DIVERGENCE_LIMIT_M = 0.5


# Control periods whose plant stage signals are evaluated at once (see simulate).
STAGE_CHUNK = 500


@dataclass
class Scenario:
    """Indices the reports need: where the tracked point, yaw axis and winch inputs are."""

    position_rows: slice
    yaw_body_offset: int | None
    tilt_body_offset: int
    winch_inputs: list[int]
    winch_gains: list[float]  # the cable tension is gain · u

    @classmethod
    def from_model(cls, model: CompiledModel) -> Scenario:
        spec, lay = model.spec, model.layout
        row, pos_rows = 0, None
        for task in spec.task:
            if isinstance(task, PositionTask):
                pos_rows = slice(row, row + 3)
            row += {"position": 3, "yaw": 1, "level": 2}[task.kind]
        position = next(t for t in spec.task if isinstance(t, PositionTask))
        yaw = next((t for t in spec.task if isinstance(t, YawTask)), None)
        winches = [i for i, a in enumerate(spec.actuators) if isinstance(a, WinchTension)]
        return cls(
            position_rows=pos_rows,
            yaw_body_offset=lay.body_offset[yaw.body] if yaw else None,
            tilt_body_offset=lay.body_offset[position.body],
            winch_inputs=winches,
            winch_gains=[spec.actuators[i].gain for i in winches],
        )


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
    """
    lay = model.layout
    n = lay.n
    period = 1.0 / rate_hz
    substeps = round(period / plant_step)
    if substeps < 1 or not math.isclose(substeps * plant_step, period, rel_tol=1e-9):
        raise SimulationError(
            f"the plant step {plant_step} s must divide the control period {period} s: "
            "fix simulation.step or controller.rate_hz in the spec"
        )
    h = period / substeps
    if not (math.isfinite(duration) and duration > 0):
        raise SimulationError(f"the duration must be a positive number of seconds, found {duration}")
    steps = int(round(duration * rate_hz))
    if steps < 1:
        raise SimulationError(f"{duration:g} s at {rate_hz:g} Hz is no control step: simulate at least one "
                              f"control period ({1 / rate_hz:g} s)")
    if steps > MAX_CONTROL_STEPS:
        raise SimulationError(
            f"{duration:g} s at {rate_hz:g} Hz is {steps} control steps, more than {MAX_CONTROL_STEPS} (the records "
            "would not fit in memory): shorten the duration or the path (path.mean_speed)"
        )
    samples = steps + 1
    # The plant's stage signals, evaluated (vectorized) a chunk of control periods at a time: the
    # run's memory is its records (about 0.8 kB per instant for the default crane: 290 MB at the
    # MAX_CONTROL_STEPS cap), not a table of every RK4 stage of the whole run.
    table, chunk_start = None, -STAGE_CHUNK
    rec_t = np.arange(samples) * period
    rec_q, rec_qd = np.zeros((samples, n)), np.zeros((samples, n))
    rec_u = np.zeros((samples, lay.l))
    rec_sigma, rec_phi = np.zeros((samples, lay.k)), np.zeros((samples, lay.m))
    rec_des = np.zeros((samples, 4))
    rec_anchor = np.zeros((samples, lay.path_signal))  # the signals before x_d are the moving anchors'
    rec_energy = np.zeros((samples, 4)) if energy else None
    n_cables = len(plant.cable_names)
    rec_tension, rec_active = np.zeros((samples, n_cables)), np.ones((samples, n_cables), dtype=np.int8)
    rec_limit = np.zeros((samples, lay.l), dtype=np.int8)
    rec_saturated = np.zeros(samples, dtype=bool)
    rec_impact = np.zeros(samples)
    rec_gap = np.zeros((samples, n_cables))
    checks_energy = hasattr(plant, "energy_balance")
    rec_residual = np.zeros(samples) if checks_energy else None
    step_s = np.zeros(samples)
    sigma_fn, phi_fn = model.functions["sigma"], model.functions["phi"]
    sigma_out, phi_out = sigma_fn.outputs["sigma"], phi_fn.outputs["phi"]
    x = plant.initial_state(q0, qd0)
    p = lay.path_signal
    position_rows = Scenario.from_model(model).position_rows
    clock = time.perf_counter
    diverged_at = divergence = None
    loads = getattr(controller, "loads_model", True)  # whether compute() leaves the state and signals in the buffers
    stateful = rec_y = rec_qhat = rec_qdhat = rec_code = None
    if sensor is not None:  # the controller reads measurements: the exported controller's step (sim.stateful)
        stateful = StatefulController(model, path, controller, sensor)
        stateful.strict = True  # a singular system is the divergence below, as without sensing
        if stateful.init(q0) != 0:
            raise SimulationError(f"{controller.name}: the run cannot start at q0: {stateful.problem}")
        rec_y = np.zeros((samples, sensor.index.size))
        rec_qhat, rec_qdhat, rec_code = np.zeros((samples, n)), np.zeros((samples, n)), np.zeros(samples, np.int8)
    wall0 = clock()
    for k in range(samples):
        t = rec_t[k]
        if k - chunk_start >= STAGE_CHUNK:
            chunk_start = k
            table = plant.stage_rows(h, k * substeps, min(STAGE_CHUNK, max(steps - k, 1)) * substeps)
        row = table[2 * substeps * (k - chunk_start)]
        q, qd = x[:n], x[n : 2 * n]
        t0 = clock()
        try:
            if sensor is None:
                u = controller.compute(q, qd, t)  # evaluates the path itself: the timed step is all of it
            else:  # measurement, its checks, projection and velocity estimate are part of the timed step
                y = sensor.sample(q)
                code = stateful.step(y, t)
                u = stateful.u
                rec_y[k], rec_qhat[k], rec_qdhat[k], rec_code[k] = y, stateful.q, stateful.qd, code
                if code not in (0, 4):  # no trustworthy command: the exported controller would hold its last one
                    diverged_at, divergence = t, _no_command(stateful, sensor)
                    break
        except SingularSystemError as err:
            if k == 0:
                if sensor is not None and (trouble := sensor.trouble(q)) is not None:  # the estimate's doing
                    raise SensingError(f"{controller.name}: {trouble}; at that estimate its system has no "
                                       f"solution ({err})") from None
                raise  # not a divergence: the method cannot handle this system at all
            diverged_at = t
            divergence = str(err) if np.isfinite(x).all() else "the state became non-finite"
            break
        step_s[k] = clock() - t0
        if not (np.isfinite(u).all() and np.isfinite(x).all()):
            diverged_at, divergence = t, "the state or input became non-finite"
            break
        rec_q[k], rec_qd[k], rec_u[k] = q, qd, u
        rec_limit[k] = controller.limit_state
        rec_saturated[k] = controller.saturation()  # a report on the step, after its timing
        rec_impact[k] = plant.impact_energy
        rec_gap[k] = plant.cable_gap
        if checks_energy:
            rec_residual[k] = plant.energy_residual
        if sensor is not None or not loads:  # the records are the plant's state, at the path's signals at t
            model.q[:], model.qd[:] = q, qd
            if not loads:  # an open-loop driver loads nothing: the path's signals at t too
                model.signals[:] = path.flat(t)
        sigma_fn.call()  # at the state and signals the controller just loaded
        phi_fn.call()
        rec_sigma[k], rec_phi[k] = sigma_out, phi_out
        rec_des[k] = row[p : p + 4]
        rec_anchor[k] = row[:p]
        if energy:
            rec_energy[k, 0] = plant.mechanical_energy(q, qd)
            rec_energy[k, 1:] = x[2 * n :]
        strayed = np.abs(sigma_out[position_rows]).max() > DIVERGENCE_LIMIT_M
        if strayed or k == steps:  # no step follows: the tensions a step from here would start with
            plant.probe(x, rec_u[k], t)
            rec_tension[k], rec_active[k] = plant.start_tension, plant.start_active
        if strayed:
            diverged_at, divergence = t, f"the tracked point strayed more than {DIVERGENCE_LIMIT_M} m from the path"
            k += 1
            break
        if k == steps:
            break
        try:
            plant.advance(x, rec_u[k], h, table, (k - chunk_start) * substeps, substeps)
        except SimulationError as err:  # the plant found no consistent cable state (x is left at instant k)
            plant.probe(x, rec_u[k], t)
            rec_tension[k], rec_active[k] = plant.start_tension, plant.start_active
            diverged_at, divergence = t, str(err)
            k += 1
            break
        rec_tension[k], rec_active[k] = plant.start_tension, plant.start_active
        if progress is not None:
            progress(1)
    wall = clock() - wall0
    # x is the plant's state at the last instant the controller computed (a failure stops before the plant step)
    if diverged_at is not None and sensor is not None and (trouble := sensor.trouble(x[:n])) is not None:
        divergence = f"{trouble}; then {divergence}"
    if diverged_at is not None:
        if not allow_divergence or k == 0:  # k == 0: not one instant was recorded, nothing to report
            raise SimulationError(f"{controller.name}: the loop diverged at t = {diverged_at:.2f} s: {divergence}")
        kept = slice(0, k)  # the instants before it went wrong
        rec_t, rec_q, rec_qd, rec_u = rec_t[kept], rec_q[kept], rec_qd[kept], rec_u[kept]
        rec_sigma, rec_phi, rec_des, step_s = rec_sigma[kept], rec_phi[kept], rec_des[kept], step_s[kept]
        rec_anchor = rec_anchor[kept]
        rec_tension, rec_active = rec_tension[kept], rec_active[kept]
        rec_limit, rec_impact, rec_saturated = rec_limit[kept], rec_impact[kept], rec_saturated[kept]
        rec_gap = rec_gap[kept]
        if stateful is not None:
            rec_y, rec_qhat, rec_qdhat, rec_code = rec_y[kept], rec_qhat[kept], rec_qdhat[kept], rec_code[kept]
        if checks_energy:
            rec_residual = rec_residual[kept]
        if energy:
            rec_energy = rec_energy[kept]
    result = RunResult(controller.name, rec_t, rec_q, rec_qd, rec_u, rec_sigma, rec_phi, rec_des, step_s, wall,
                       diverged_at=diverged_at, divergence=divergence, cable_names=list(plant.cable_names),
                       cable_tension=rec_tension, cable_active=rec_active,
                       cable_transitions=plant.transitions.copy(), impact_energy=rec_impact,
                       limit_state=rec_limit, saturated=rec_saturated, control_period=period,
                       plant_params=dict(getattr(plant, "parameters", {})), anchors=rec_anchor,
                       cable_gap=rec_gap, energy_residual=rec_residual,
                       energy_bound=plant.energy_bound if checks_energy else None,
                       energy_checked_from=plant.energy_checked_from if checks_energy else None)
    if stateful is not None:
        result.measured_names = [lay.coordinates[i] for i in sensor.index]
        result.measurements, result.step_code = rec_y, rec_code
        result.estimate_q, result.estimate_qd = rec_qhat, rec_qdhat
    if energy:
        names = ("mechanical", "work_inputs", "work_anchors", "dissipated")
        result.energy = {name: rec_energy[:, i].copy() for i, name in enumerate(names)}
        result.energy["impacts"] = rec_impact.copy()
    return result


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


# --- the tracking figures per instant: the summary, the figures and Result read the same ones ----------


def position_error_mm(result: RunResult, scenario: Scenario) -> np.ndarray:
    """|tracked point − r_d| per instant, mm."""
    return 1e3 * np.linalg.norm(result.sigma[:, scenario.position_rows], axis=1)


def realized_yaw(result: RunResult, scenario: Scenario) -> np.ndarray:
    """Yaw of the task's yaw body (else the tracked body) from atan2(u_y, u_x), unwrapped, rad."""
    offset = scenario.yaw_body_offset if scenario.yaw_body_offset is not None else scenario.tilt_body_offset
    u_axis = result.q[:, offset + 3 : offset + 6]
    return np.unwrap(np.arctan2(u_axis[:, 1], u_axis[:, 0]))


def yaw_error_deg(result: RunResult, scenario: Scenario) -> np.ndarray | None:
    """Realized minus desired yaw, wrapped to (−180, 180] deg; None when the crane has no yaw task."""
    if scenario.yaw_body_offset is None:
        return None
    return np.degrees(np.angle(np.exp(1j * (realized_yaw(result, scenario) - result.desired[:, 3]))))


def tilt_deg(result: RunResult, scenario: Scenario) -> np.ndarray:
    """Angle of the tracked body's w axis from the vertical, deg."""
    w_axis = result.q[:, scenario.tilt_body_offset + 9 : scenario.tilt_body_offset + 12]
    return np.degrees(np.arccos(np.clip(w_axis[:, 2] / np.linalg.norm(w_axis, axis=1), -1.0, 1.0)))


def summarize(result: RunResult, scenario: Scenario, layout) -> dict:
    """The per-method figures of summary.json (see docs/run.md, `acroboter run`)."""
    pos_err = np.linalg.norm(result.sigma[:, scenario.position_rows], axis=1)  # m (position_error_mm ÷ 1e3)
    summary = {
        "max_position_error_mm": 1e3 * float(pos_err.max()),
        "rms_position_error_mm": 1e3 * float(np.sqrt(np.mean(pos_err**2))),
    }
    if result.diverged_at is not None and pos_err.max() <= DIVERGENCE_LIMIT_M:
        # The state blew up between two records (non-finite, or the controller failed): what was
        # recorded before says nothing about the error at divergence, which is unbounded.
        summary["max_position_error_before_divergence_mm"] = summary["max_position_error_mm"]
        summary["max_position_error_mm"] = summary["rms_position_error_mm"] = None
    if scenario.yaw_body_offset is not None:
        # From the wrapped atan2, not yaw_error_deg's unwrapped yaw: the same angle, but the summary's
        # figures are kept to the bit as they have been recorded.
        u_axis = result.q[:, scenario.yaw_body_offset + 3 : scenario.yaw_body_offset + 6]
        err = np.angle(np.exp(1j * (np.arctan2(u_axis[:, 1], u_axis[:, 0]) - result.desired[:, 3])))
        summary["max_yaw_error_deg"] = float(np.degrees(np.abs(err).max()))
    else:
        summary["max_yaw_error_deg"] = None
    summary["max_tilt_deg"] = float(tilt_deg(result, scenario).max())
    summary["max_constraint_violation"] = constraint_violation(result, layout)
    winch = result.u[:, scenario.winch_inputs] * np.array(scenario.winch_gains)  # tension = gain · u
    summary["min_winch_tension_N"] = float(winch.min()) if winch.size else None
    summary["max_winch_tension_N"] = float(winch.max()) if winch.size else None
    summary["max_abs_input"] = {
        name: float(np.abs(result.u[:, i]).max()) for i, name in enumerate(layout.inputs)
    }
    us = 1e6 * result.control_step_s
    summary["control_step_us"] = {
        "median": float(np.median(us)),
        "mean": float(us.mean()),
        "p99": float(np.percentile(us, 99)),
    }
    summary["sim_wall_s"] = float(result.sim_wall_s)
    # Times from the records: every instant but the last stands for the control period after it.
    period = result.control_period
    held = slice(0, max(len(result.t) - 1, 0))
    summary["cables"] = {
        name: {
            "time_slack_s": float(np.count_nonzero(result.cable_active[held, c] == 0) * period),
            "transitions": int(result.cable_transitions[c]),
            "min_tension_N": float(result.cable_tension[:, c].min()) if len(result.t) else None,
            "max_tension_N": float(result.cable_tension[:, c].max()) if len(result.t) else None,
        }
        for c, name in enumerate(result.cable_names)
    }
    limits = result.limit_state

    def worst_error(mask: np.ndarray) -> float | None:
        return 1e3 * float(pos_err[mask].max()) if mask.any() else None

    summary["inputs"] = {
        name: {
            "time_at_lower_limit_s": float(np.count_nonzero(limits[held, i] == -1) * period),
            "time_at_upper_limit_s": float(np.count_nonzero(limits[held, i] == 1) * period),
            "max_position_error_while_at_limit_mm": worst_error(limits[:, i] != 0),
        }
        for i, name in enumerate(layout.inputs)
    }
    # Saturation: the instants at which a limit kept the input from what the controller asked of the
    # task (an input on a limit that only moved internal forces does not count), and what it cost.
    saturated = result.saturated
    # Per cable the largest |p_a − p_b| − L at any instant (m; > 0 only if stretched: the plant holds a
    # slack cable to 1e-9 m, a taut one to its constraint stabilisation).
    if result.cable_gap.size:
        summary["cable_max_gap_m"] = {name: float(result.cable_gap[:, c].max())
                                      for c, name in enumerate(result.cable_names)}
    if result.energy_residual is not None and result.energy_residual.size:
        # over the instants the plant checked (a plant that started off its constraints: from their closing)
        start = result.energy_checked_from
        checked = result.energy_residual[result.t >= start] if start is not None else result.energy_residual[:0]
        summary["max_abs_energy_residual_J"] = float(np.abs(checked).max()) if checked.size else None
        summary["energy_residual_bound_J"] = result.energy_bound
        summary["energy_checked_from_s"] = start
    if result.outside_limits is not None:
        summary["inputs_outside_limits"] = result.outside_limits
    summary["saturated"] = bool(saturated.any())
    summary["time_saturated_s"] = float(np.count_nonzero(saturated[held]) * period)
    summary["max_position_error_while_saturated_mm"] = worst_error(saturated)
    return summary


def constraint_violation(result: RunResult, layout) -> float:
    """max |φ| over the rigid rows, and over the cables only where stretched (φ > 0): a slack cable
    (φ < 0, its ends closer than its length) is allowed, not a violation."""
    cable = np.array([name.startswith("cable ") for name in layout.constraints])
    if not result.phi.size:
        return 0.0
    rigid = np.abs(result.phi[:, ~cable]).max() if (~cable).any() else 0.0
    stretched = np.maximum(result.phi[:, cable], 0.0).max() if cable.any() else 0.0
    return float(max(rigid, stretched))
