"""The crane's dynamics terms at a state, by name, for users who evaluate them by hand (as pinocchio's
`crba`/`rnea` or PyDy's `mass_matrix`): the equations the controllers and the plant are built on,

    M(q) q̈ + c(q, q̇, t) = H(q) u − φ_q(q, t)ᵀ λ,      φ(q, t) = 0,      σ(q, t) = 0 (the task),

in natural coordinates (docs/model.md §1-5): q holds each body's centre of mass and axes (m, unitless)
and each winch cable's length (m), in `crane.coordinates` order; t enters through the prescribed
signals (the moving anchors and the desired path at t). Each call evaluates one generated function
of the compiled model (not for a hot loop: a controller binds its buffers once); the arguments are
checked first (shape, finite numbers), with a message that names the argument.
"""

from __future__ import annotations

import math
import numbers

import numpy as np

# term -> (generated function, output, what it needs: "q", "qd", "t")
TERMS = {
    "mass_matrix": ("mass_matrix", "mass_matrix", ("q",)),
    "bias_forces": ("bias_forces", "bias_forces", ("q", "qd", "t")),
    "input_matrix": ("input_matrix", "input_matrix", ("q",)),
    "constraints": ("phi", "phi", ("q", "t")),
    "constraint_jacobian": ("phi_q", "phi_q", ("q", "t")),
    "servo_error": ("sigma", "sigma", ("q", "t")),
    "servo_jacobian": ("sigma_q", "sigma_q", ("q", "t")),
}


def vector(value, size: int, what: str) -> np.ndarray:
    """`value` as `size` finite floats, or a ValueError that names `what`."""
    try:
        array = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        array = None
    if array is None or array.shape != (size,) or not np.isfinite(array).all():
        found = "non-finite values" if array is not None and array.shape == (size,) else (
            f"shape {array.shape}" if array is not None else f"{type(value).__name__}")
        raise ValueError(f"{what}: expected {size} finite numbers (crane.coordinates' order), found {found}")
    return array


def evaluate(model, path, term: str, q, qd=None, t: float = 0.0) -> np.ndarray:
    """One dynamics term (a key of TERMS) at q (and q̇, t) as a new array of its natural shape."""
    function, output, needs = TERMS[term]
    lay = model.layout
    q = vector(q, lay.n, "q")
    qd = vector(qd, lay.n, "qd") if "qd" in needs else np.zeros(lay.n)
    if isinstance(t, bool) or not (isinstance(t, numbers.Real) and math.isfinite(t)):
        raise ValueError(f"t: expected a finite time in seconds, found {t!r}")
    s, sd, sdd = path.signal_arrays(float(t))
    return model.evaluate(function, q=q, qd=qd, s=s, sd=sd, sdd=sdd)[output]
