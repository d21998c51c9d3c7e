"""MuJoCo's step for a crane: chosen from the crane's own numbers, and how far off a coarser one is expected to be.

MuJoCo's cables are stiff soft constraints whose error grows with the step. Measured on 18 generated cranes
(acroboter.model.crane_generator; 3-6 winches, drums 0.005-1 kg; docs/mujoco.md, "Its step, per crane"), one
winch ±50 % of its static tension at 2 Hz for 3 s, the default MuJoCo plant against the own plant (bodies' centres):

- the difference is the own plant's floor (0.006-4.5 µm) plus an excess that grows as h^p, p = 2.0-2.5 (median 2.1);
- across cranes the excess follows, within a factor of about 4.5 (ln-rms 1.5), the largest cable's T/m_eff at rest
  (T its tension, m_eff = 1/(g P gᵀ) the mass it moves: g the cable's length gradient, P the inverse mass matrix
  projected on the bodies' own constraints), E ≈ C·max(T/m_eff)·h², C (unitless) = 0.059 at the geometric mean and
  ERROR_ENVELOPE = 0.27 over every crane measured. No other quantity tried (the fastest natural frequency, the
  open-loop growth rate, the lightest drum) orders the cranes better.

The rule (`chosen_step`): the coarsest step of STEP_LADDER that divides the plant step and whose enveloped excess is
within STEP_ERROR_BOUND_M. Every generated crane measured so far gets 1e-4 s but one (11,883 m/s²: 5e-5 s, measured
1.6 µm): the rule keeps 1e-4 s below 7,430 m/s². `expected_error` is what a run's summary states for the step used.
"""

from __future__ import annotations

import numpy as np

STEP_LADDER = (1e-4, 5e-5, 2e-5, 1e-5, 5e-6)  # s, coarsest first
ERROR_ENVELOPE = 0.27  # unitless (m = C · m/s² · s²): the largest C of the cranes measured (module docstring)
STEP_ERROR_BOUND_M = 20e-6  # the plant fuzz's position bound


def cable_accelerations(model, q: np.ndarray, multipliers: np.ndarray) -> dict[str, float]:
    """m/s², per cable: its tension at (q, λ) over the mass it moves, T/m_eff (module docstring)."""
    lay, spec = model.layout, model.spec
    mass = model.term("mass_matrix", q=q)
    jacobian = model.term("phi_q", q=q)
    minv = np.linalg.inv(mass)
    cable_rows = [i for i, name in enumerate(lay.constraints) if name.startswith("cable ")]
    rigid = jacobian[[i for i in range(lay.m) if i not in cable_rows]]
    # the inverse mass on the bodies' own constraints (their axes orthonormal): P = M⁻¹ − M⁻¹Aᵀ(AM⁻¹Aᵀ)⁺AM⁻¹
    projected = minv - minv @ rigid.T @ np.linalg.pinv(rigid @ minv @ rigid.T) @ rigid @ minv
    out = {}
    for cable, row in zip(spec.cables, cable_rows, strict=True):
        length = float(q[lay.winch_index[cable.name]]) if cable.winch is not None else float(cable.length)
        gradient = jacobian[row] / (2.0 * length)  # ∂|d|/∂q of the row |d|² − L²
        tension = abs(2.0 * length * float(multipliers[row]))
        out[cable.name] = tension * float(gradient @ projected @ gradient)  # T / m_eff
    return out


def expected_error(acceleration: float, timestep: float) -> float:
    """m: the bodies' excess over the own plant expected at `timestep` (the envelope of the cranes measured)."""
    return ERROR_ENVELOPE * acceleration * timestep**2


def chosen_step(acceleration: float, plant_step: float) -> float:
    """s: the coarsest STEP_LADDER step that divides `plant_step` with its expected excess within the bound (the
    finest one if none is)."""
    dividing = [h for h in STEP_LADDER if abs(plant_step / h - round(plant_step / h)) < 1e-9]
    for h in dividing:
        if expected_error(acceleration, h) <= STEP_ERROR_BOUND_M:
            return h
    return dividing[-1] if dividing else STEP_LADDER[-1]


def crane_step(model, start) -> tuple[float, float]:
    """The rule's step for the crane of `model` at rest at `start` (an Equilibrium), and its largest T/m_eff."""
    acceleration = max(cable_accelerations(model, start.q, start.multipliers).values(), default=0.0)
    return chosen_step(acceleration, model.spec.simulation.step), acceleration
