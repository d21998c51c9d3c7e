"""Which coordinates a [sensing] section measures, in the measurement vector's order (docs/sensing.md).

Shared by the estimator (acroboter.sim.sensing) and the stateful exported controller
(acroboter.codegen.controller_c), which must agree on the measurement vector's layout.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .schema import Sensing, sensing_coordinates

# Gauss–Newton stops once max |φ| is this small (the plant itself holds φ to about 1e-13).
PROJECTION_TOLERANCE = 1e-13
# The sample checks (docs/sensing.md, "Bad samples"), shared by the Python estimator, the fast path's compiled one
# and the stateful exported controller:
# - a projection that leaves max |φ| above this has not converged (good samples end at ~1e-13): the sample that
#   led to it is rejected, and an estimate that ends above it is not used;
PROJECTION_ACCEPT = 1e-6
# - a sample further from its prediction than the crane's speed allows over a period plus this many noise standard
#   deviations (and one quantisation step) is rejected (good samples, 0.2 mm noise: at most 7 σ of the noise);
GATE_SIGMAS = 10.0
# - a fully measured unit axis whose length is off 1 by more than this (plus the noise's GATE_SIGMAS σ and a step).
AXIS_TOLERANCE = 0.1


@dataclass(frozen=True)
class SampleChecks:
    """The numbers the estimator checks a sample y against (y in measured_indices' order)."""

    gate: np.ndarray  # per y[j]: the largest |y[j] − its prediction| in one control period (m or unitless)
    axes: np.ndarray  # (number of fully measured unit axes, 3): the y indices of each one's x, y, z components
    axis_tolerance: np.ndarray  # per fully measured axis: the largest | |axis| − 1 |
    max_coast: int  # rejected samples in a row before the estimate is declared lost


def sample_checks(spec, layout, sensing: Sensing) -> SampleChecks:
    """The gate of each measured coordinate (max_speed or max_axis_rate times the control period, plus GATE_SIGMAS
    noise σ and one quantisation step) and the unit axes measured whole, with their length tolerance."""
    index, noise, step = measured_indices(spec, layout, sensing)
    period = 1.0 / spec.controller.rate_hz
    names = [layout.coordinates[i] for i in index]
    is_axis = np.array([name.rpartition(".")[2][:1] in "uvw" for name in names], dtype=bool)
    speed = np.where(is_axis, sensing.max_axis_rate, sensing.max_speed)
    gate = speed * period + GATE_SIGMAS * noise + step
    where = {name: j for j, name in enumerate(names)}
    axes, tolerance = [], []
    for body in spec.bodies:
        for a in "uvw":
            parts = [where.get(f"{body.name}.{a}_{c}") for c in "xyz"]
            if None not in parts:
                axes.append(parts)
                tolerance.append(AXIS_TOLERANCE + GATE_SIGMAS * float(noise[parts].max()) + float(step[parts].max()))
    return SampleChecks(gate, np.array(axes, dtype=np.intp).reshape(-1, 3), np.array(tolerance),
                        sensing.max_coast_periods)


def measured_indices(spec, layout, sensing: Sensing) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(coordinate indices, noise standard deviation, quantisation step or 0) per measured coordinate."""
    index, noise, step = [], [], []
    for group in sensing.groups:
        for selector in group.coordinates:
            for name in sensing_coordinates(spec, selector):
                index.append(layout.coordinates.index(name))
                noise.append(group.noise)
                step.append(group.quantization or 0.0)
    return np.array(index, dtype=np.intp), np.array(noise), np.array(step)


def measured_groups(spec, sensing: Sensing) -> list[str]:
    """The group's name per measured coordinate, in measured_indices' order."""
    return [group.name for group in sensing.groups for selector in group.coordinates
            for _ in sensing_coordinates(spec, selector)]


def is_ideal(spec, layout, sensing: Sensing | None) -> bool:
    """Every coordinate measured without noise, quantisation or delay: the plant's state itself."""
    if sensing is None:
        return True
    index, noise, step = measured_indices(spec, layout, sensing)
    return (len(set(index.tolist())) == layout.n and not noise.any() and not step.any()
            and sensing.delay_periods == 0)
