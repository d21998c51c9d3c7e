"""Which coordinates a [sensing] section measures, in the measurement vector's order (docs/sensing.md).

Shared by the estimator (acroboter.sim.sensing) and the stateful exported controller
(acroboter.codegen.controller_c), which must agree on the measurement vector's layout.
"""

from __future__ import annotations

import numpy as np

from .schema import Sensing, sensing_coordinates

# Gauss–Newton stops once max |φ| is this small (the plant itself holds φ to about 1e-13).
PROJECTION_TOLERANCE = 1e-13


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
