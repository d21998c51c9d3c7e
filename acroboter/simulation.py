"""Closed loop: the controller every control period, the plant's RK4 in between (zero-order hold)."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from .compiled import CompiledModel
from .controllers import Controller
from .path import DesiredPath
from .plant import Plant, SimulationError
from .spec import PositionTask, WinchTension, YawTask


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


@dataclass
class Scenario:
    """Indices the reports need: where the tracked point, yaw axis and winch inputs are."""

    position_rows: slice
    yaw_body_offset: int | None
    tilt_body_offset: int
    winch_inputs: list[int]

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
        )


def simulate(
    model: CompiledModel,
    path: DesiredPath,
    controller: Controller,
    plant: Plant,
    q0: np.ndarray,
    duration: float,
    rate_hz: float,
    plant_step: float,
    progress=None,
    energy: bool = False,
) -> RunResult:
    """Run the closed loop from rest at q0 for `duration` seconds."""
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
    steps = int(round(duration * rate_hz))
    samples = steps + 1
    rec_t = np.arange(samples) * period
    rec_q, rec_qd = np.zeros((samples, n)), np.zeros((samples, n))
    rec_u = np.zeros((samples, lay.l))
    rec_sigma, rec_phi = np.zeros((samples, lay.k)), np.zeros((samples, lay.m))
    rec_des = np.zeros((samples, 4))
    step_s = np.zeros(samples)
    x = np.zeros(2 * n + (3 if energy else 0))
    x[:n] = q0
    held_u = np.zeros(lay.l)
    p = lay.path_signal
    rec_energy = np.zeros((samples, 4)) if energy else None
    wall0 = time.perf_counter()
    for k in range(samples):
        t = rec_t[k]
        q, qd = x[:n], x[n : 2 * n]
        t0 = time.perf_counter()
        u = controller.compute(q, qd, t)
        step_s[k] = time.perf_counter() - t0
        if not np.all(np.isfinite(u)) or not np.all(np.isfinite(x)):
            raise SimulationError(
                f"{controller.name}: the state or input became non-finite at t = {t:.2f} s (the loop diverged)"
            )
        held_u[:] = u
        terms = controller.terms
        rec_q[k], rec_qd[k], rec_u[k] = q, qd, held_u
        rec_sigma[k], rec_phi[k] = terms["sigma"], terms["phi"]
        rec_des[k] = model.s[p : p + 4]
        if energy:
            rec_energy[k, 0] = plant.mechanical_energy(q, qd)
            rec_energy[k, 1:] = x[2 * n :]
        if k == steps:
            break
        for j in range(substeps):
            plant.step(x, t + j * h, held_u, h, powers=energy)
        if progress is not None:
            progress(1)
    wall = time.perf_counter() - wall0
    result = RunResult(
        controller.name, rec_t, rec_q, rec_qd, rec_u, rec_sigma, rec_phi, rec_des, step_s, wall
    )
    if energy:
        names = ("mechanical", "work_inputs", "work_anchors", "dissipated")
        result.energy = {name: rec_energy[:, i].copy() for i, name in enumerate(names)}
    return result


def summarize(result: RunResult, scenario: Scenario, layout) -> dict:
    """The per-method figures of summary.json (design §10)."""
    pos_err = np.linalg.norm(result.sigma[:, scenario.position_rows], axis=1)
    summary = {
        "max_position_error_mm": 1e3 * float(pos_err.max()),
        "rms_position_error_mm": 1e3 * float(np.sqrt(np.mean(pos_err**2))),
    }
    if scenario.yaw_body_offset is not None:
        u_axis = result.q[:, scenario.yaw_body_offset + 3 : scenario.yaw_body_offset + 6]
        yaw = np.arctan2(u_axis[:, 1], u_axis[:, 0])
        err = np.angle(np.exp(1j * (yaw - result.desired[:, 3])))
        summary["max_yaw_error_deg"] = float(np.degrees(np.abs(err).max()))
    else:
        summary["max_yaw_error_deg"] = None
    w_axis = result.q[:, scenario.tilt_body_offset + 9 : scenario.tilt_body_offset + 12]
    tilt = np.arccos(np.clip(w_axis[:, 2] / np.linalg.norm(w_axis, axis=1), -1.0, 1.0))
    summary["max_tilt_deg"] = float(np.degrees(tilt.max()))
    summary["max_constraint_violation"] = float(np.abs(result.phi).max())
    winch = result.u[:, scenario.winch_inputs]
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
    return summary


def setup_default(model: CompiledModel, path: DesiredPath):
    """Plant for a spec's simulation section."""
    sim = model.spec.simulation
    return Plant(model, path, sim.baumgarte_zeta, sim.baumgarte_omega)


__all__ = ["RunResult", "Scenario", "simulate", "summarize", "setup_default", "DesiredPath"]
