"""The plant of a closed loop: the project's own Baumgarte RK4 plant or MuJoCo on the spec's MJCF model, and
MuJoCo's step checked against the spec's."""

from __future__ import annotations

import math

from ..control.path import DesiredPath
from ..runtime.compiled import CompiledModel
from .plant import Plant

__all__ = ["PLANTS", "check_mujoco_timestep", "setup_default"]

PLANTS = ("own", "mujoco")  # the project's Baumgarte RK4 plant, or MuJoCo on the spec's MJCF model


def check_mujoco_timestep(plant_step: float, dt, control_period: float | None = None) -> float:
    """MuJoCo's step: a number of seconds in its range (acroboter.model.ranges.MUJOCO_TIMESTEP) that divides the
    spec's plant step (ValueError naming a step that does, otherwise) and, with `control_period`, makes at most
    MAX_MUJOCO_STEPS_PER_PERIOD steps in it (the work, and the memory of the path's table, a period takes)."""
    from ..model.ranges import MUJOCO_TIMESTEP, mujoco_work_problem

    MUJOCO_TIMESTEP.check(dt, "mujoco_timestep")  # a RangeError, a ValueError
    if control_period is not None and (problem := mujoco_work_problem(dt, control_period)) is not None:
        raise ValueError(f"mujoco_timestep: {problem}")
    count = plant_step / dt
    if round(count) >= 1 and math.isclose(round(count) * dt, plant_step, rel_tol=1e-9):
        return float(dt)
    for k in range(max(1, math.ceil(count)), 100_000):  # the largest step below dt that prints exactly
        text = f"{plant_step / k:.6g}"
        if math.isclose(float(text) * k, plant_step, rel_tol=1e-12):
            break
    raise ValueError(f"mujoco_timestep: {dt:g} s must divide the spec's plant step simulation.step = {plant_step:g} s "
                     f"(MuJoCo steps {count:.4g} times per plant step): give e.g. {text} s")


def setup_default(model: CompiledModel, path: DesiredPath, plant_params=None, plant: str = "own",
                  mujoco_timestep: float | None = None, start=None):
    """Plant for a spec's simulation section; `plant_params` (name -> value, acroboter.model.physical)
    make its crane differ from the controller's model. plant="mujoco": MuJoCo on the spec's MJCF
    model (acroboter.sim.mujoco_plant) at `mujoco_timestep`, which must divide the spec's plant step (default: the
    crane's own, acroboter.sim.mujoco_step, from its static equilibrium `start`; without one the MJCF's)."""
    sim = model.spec.simulation
    if plant == "own":
        if mujoco_timestep is not None:
            raise ValueError("mujoco_timestep: only the MuJoCo plant has a time step of its own (plant='mujoco')")
        return Plant(model, path, sim.baumgarte_zeta, sim.baumgarte_omega, plant_params)
    if plant != "mujoco":
        raise ValueError(f"plant: expected one of {', '.join(PLANTS)}, found {plant!r}")
    from ..process.extras import require

    require("mujoco", "plant='mujoco'", "plant='own' needs no extra")  # MissingExtraError, an ImportError
    from ..model.mjcf_model import DEFAULT_TIMESTEP
    from .mujoco_plant import MujocoPlant

    if mujoco_timestep is None and start is not None:
        from .mujoco_step import crane_step

        mujoco_timestep = crane_step(model, start)[0]
    dt = check_mujoco_timestep(sim.step, DEFAULT_TIMESTEP if mujoco_timestep is None else mujoco_timestep,
                               1.0 / model.spec.controller.rate_hz)
    return MujocoPlant(model, path, plant_params, timestep=float(dt))

