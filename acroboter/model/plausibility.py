"""Warnings for a spec whose numbers are each valid but implausible together (a unit slip, a typo):
the spec still runs, and the warning names the field and why. What is an error and what a warning:
a number outside its physical range (a negative mass, a NaN, a zero-length cable) is an error of the
spec (SpecError, exit 2); a mass a hundred times its neighbours', a fixed cable that its ends do not
fit at the start, a drum heavier than the load are warnings (docs/spec.md).
"""

from __future__ import annotations

import numpy as np

from .spec import Spec
from .spec_checks import _end_position

# A body this many times heavier than the lightest: a mass in grams, or a connector typed as a building.
MASS_RATIO = 100.0
# A fixed cable whose length and the distance of its ends in the initial positions differ by more than
# this fraction: the start equilibrium moves the bodies by as much.
LENGTH_MISMATCH = 0.01


def plausibility_warnings(spec: Spec) -> list[tuple[str, str]]:
    """(field, why) for each implausible combination in `spec` (none for the examples)."""
    found = []
    masses = [b.mass for b in spec.bodies]
    light = min(masses)
    for i, body in enumerate(spec.bodies):
        if body.mass > MASS_RATIO * light:
            found.append((f"bodies[{i}].mass", f"{body.mass:g} kg is {body.mass / light:.0f} times the lightest "
                          f"body's ({light:g} kg): a mass in grams, or a slip of the decimal point?"))
    total = sum(masses)
    for i, cable in enumerate(spec.cables):
        if cable.length is not None:
            span = float(np.linalg.norm(_end_position(spec, cable.ends[0]) - _end_position(spec, cable.ends[1])))
            if abs(span - cable.length) > LENGTH_MISMATCH * cable.length:
                found.append((f"cables[{i}].length", f"{cable.length:g} m, but its ends are {span:.4g} m apart in the "
                              "bodies' initial positions: the start equilibrium moves the bodies by the difference"))
        if cable.winch is not None and cable.winch.reflected_inertia > total:
            found.append((f"cables[{i}].winch.reflected_inertia",
                          f"{cable.winch.reflected_inertia:g} kg, more than all the bodies together ({total:g} kg): "
                          "the drum, not the load, dominates the dynamics (kg·m² divided by the drum radius²?)"))
    return found
