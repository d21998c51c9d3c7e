"""A closed-loop run's records (`RunResult`, allocated once per run by `Records`) and what they say about its
tracking: where the tracked point, the yaw axis and the winches are (`Scenario`), the figures per instant (position
error, yaw, tilt) and the summary's per-method figures (`summarize`): the summary, the figures and `Result` read the
same ones."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..model.spec import PositionTask, WinchTension, YawTask
from ..runtime.compiled import CompiledModel


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
    # The own plant's periods flown again at a finer step where its energy balance said the spec's step could not
    # resolve them (acroboter.sim.plant_refinement), and the finest step used (s; None: none refined, or MuJoCo).
    plant_refined_periods: int = 0
    plant_finest_step: float | None = None
    # Open loop (acroboter.sim.open_loop): per input, the instants at which it was outside the spec's limits.
    outside_limits: dict[str, dict] | None = None
    # With sensing, per instant: the measurement the estimator read (columns: measured_names), the estimate the
    # controller used, and the step's code (acroboter.sim.stateful_controller.STEP_CODES: 0 accepted, 4 coasted).
    measured_names: list[str] | None = None
    measurements: np.ndarray | None = None
    estimate_q: np.ndarray | None = None
    estimate_qd: np.ndarray | None = None
    step_code: np.ndarray | None = None


# A run that strays this far from the path (m) has diverged: nothing useful follows.
DIVERGENCE_LIMIT_M = 0.5



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



class Records:
    """A run's records, allocated once for every instant (about 0.8 kB per instant for the default crane: 290 MB
    at the MAX_CONTROL_STEPS cap); `keep(k)` cuts them at a divergence, `result` hands them over."""

    def __init__(self, lay, plant, samples: int, period: float, energy: bool, sensor):
        """For `samples` instants `period` s apart of a run on `plant` (its cables, whether it balances energy),
        with the energy records if `energy`, and the measurements and estimates if `sensor`."""
        n, n_cables = lay.n, len(plant.cable_names)
        self.layout, self.period = lay, period
        self.t = np.arange(samples) * period
        self.q, self.qd = np.zeros((samples, n)), np.zeros((samples, n))
        self.u = np.zeros((samples, lay.l))
        self.sigma, self.phi = np.zeros((samples, lay.k)), np.zeros((samples, lay.m))
        self.desired = np.zeros((samples, 4))
        self.anchors = np.zeros((samples, lay.path_signal))  # the signals before x_d are the moving anchors'
        self.energy = np.zeros((samples, 4)) if energy else None
        self.tension, self.active = np.zeros((samples, n_cables)), np.ones((samples, n_cables), dtype=np.int8)
        self.limit = np.zeros((samples, lay.l), dtype=np.int8)
        self.saturated = np.zeros(samples, dtype=bool)
        self.impact = np.zeros(samples)
        self.gap = np.zeros((samples, n_cables))
        self.checks_energy = hasattr(plant, "energy_balance")
        self.residual = np.zeros(samples) if self.checks_energy else None
        self.step_s = np.zeros(samples)
        self.sensor = sensor
        if sensor is not None:
            self.y = np.zeros((samples, sensor.index.size))
            self.qhat, self.qdhat = np.zeros((samples, n)), np.zeros((samples, n))
            self.code = np.zeros(samples, np.int8)

    PER_INSTANT = ("t", "q", "qd", "u", "sigma", "phi", "desired", "anchors", "energy", "tension", "active", "limit",
                   "saturated", "impact", "gap", "residual", "step_s", "y", "qhat", "qdhat", "code")

    def keep(self, count: int) -> None:
        """Only the first `count` instants (a run cut short by a divergence)."""
        for name in self.PER_INSTANT:
            if getattr(self, name, None) is not None:
                setattr(self, name, getattr(self, name)[:count])

    def result(self, method: str, plant, wall: float, diverged_at, divergence) -> RunResult:
        """The records as the RunResult of `method`'s run on `plant`, `wall` s of wall time."""
        result = RunResult(method, self.t, self.q, self.qd, self.u, self.sigma, self.phi, self.desired, self.step_s,
                           wall, diverged_at=diverged_at, divergence=divergence, cable_names=list(plant.cable_names),
                           cable_tension=self.tension, cable_active=self.active,
                           cable_transitions=plant.transitions.copy(), impact_energy=self.impact,
                           limit_state=self.limit, saturated=self.saturated, control_period=self.period,
                           plant_params=dict(getattr(plant, "parameters", {})), anchors=self.anchors,
                           cable_gap=self.gap, energy_residual=self.residual,
                           energy_bound=plant.energy_bound if self.checks_energy else None,
                           energy_checked_from=plant.energy_checked_from if self.checks_energy else None,
                           plant_refined_periods=int(getattr(plant, "refined_periods", 0)),
                           plant_finest_step=getattr(plant, "finest_step", None))
        if self.sensor is not None:
            result.measured_names = [self.layout.coordinates[i] for i in self.sensor.index]
            result.measurements, result.step_code = self.y, self.code
            result.estimate_q, result.estimate_qd = self.qhat, self.qdhat
        if self.energy is not None:
            names = ("mechanical", "work_inputs", "work_anchors", "dissipated")
            result.energy = {name: self.energy[:, i].copy() for i, name in enumerate(names)}
            result.energy["impacts"] = self.impact.copy()
        return result


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
        summary["plant_refined_periods"] = result.plant_refined_periods
        summary["plant_finest_step_s"] = result.plant_finest_step
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
