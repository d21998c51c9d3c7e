"""The input limits a retiming keeps, with the margin, and the margin a motion achieves.

The margin m is a fraction of each input's limit span: an input with the limits [min, max], both finite,
is kept within [min + m·(max − min), max − m·(max − min)]. An input with one finite limit b (a winch's
default [0, ∞)) has no span: b is moved inwards by m·|b| (so a lower limit 0 stays 0). An input with none
is not bounded. m = 0 plans on the limits themselves; m < 0.5 leaves an interval.

The margin achieved by a motion is, over the inputs with two finite limits, the smallest distance of any
sample to its nearest limit as a fraction of that input's span (negative: beyond a limit).
"""

from __future__ import annotations

import numpy as np

# The planned inputs are checked between the optimiser's nodes on a grid of this step (s), and may leave the bounds
# there by at most INPUT_TOLERANCE of the span (rounding; the optimiser bounds every RK4 step's start and every
# interval's end, where a bang-bang timing's input peaks).
CHECK_STEP_S = 1e-3
INPUT_TOLERANCE = 1e-6


def tightened(lower: np.ndarray, upper: np.ndarray, margin: float) -> tuple[np.ndarray, np.ndarray]:
    """(lower, upper) moved inwards by the margin (see the module's docstring)."""
    lower, upper = np.asarray(lower, dtype=float), np.asarray(upper, dtype=float)
    both = np.isfinite(lower) & np.isfinite(upper)
    span = np.where(both, upper - lower, 0.0)
    low = np.where(both, lower + margin * span, lower + margin * np.abs(np.where(np.isfinite(lower), lower, 0.0)))
    high = np.where(both, upper - margin * span, upper - margin * np.abs(np.where(np.isfinite(upper), upper, 0.0)))
    return low, high


def bound_span(low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """Each input's span between its bounds, 1 for a bound without a finite span: what a step beyond them is a
    fraction of."""
    return np.where(np.isfinite(high - low), high - low, 1.0)


def beyond_bounds(inputs: np.ndarray, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """Each input's step beyond its bounds (low, high), as a fraction of their span (1 for a bound without a finite
    span): ≤ 0 within them, −inf on an unbounded side."""
    span = bound_span(low, high)
    with np.errstate(invalid="ignore"):
        over = np.maximum(inputs - high, low - inputs) / span
    return np.where(np.isnan(over), -np.inf, over)  # inf - inf: an unbounded side


def worst_beyond(values: np.ndarray, low: np.ndarray, high: np.ndarray, tolerance: float = 0.0):
    """The sample and input (k, i) of `values` (samples x inputs) furthest beyond (low, high), with the bound it
    passes, or None when none is beyond them by more than `tolerance` of the span."""
    over = beyond_bounds(values, low, high)
    if not over.size or over.max() <= tolerance:
        return None
    k, i = np.unravel_index(np.argmax(over), over.shape)
    return int(k), int(i), float(high[i] if values[k, i] > high[i] else low[i])


def margin_achieved(inputs: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> tuple[float, int | None]:
    """(the smallest distance to a limit as a fraction of the span, over the inputs with two finite limits;
    the input it is on), (inf, None) when no input has two finite limits. `inputs`: samples x inputs."""
    lower, upper = np.asarray(lower, dtype=float), np.asarray(upper, dtype=float)
    both = np.isfinite(lower) & np.isfinite(upper)
    if not both.any():
        return float("inf"), None
    u = np.asarray(inputs, dtype=float)[:, both]
    span = (upper - lower)[both]
    distance = np.minimum(u - lower[both], upper[both] - u) / span
    worst = distance.min(axis=0)
    i = int(np.argmin(worst))
    return float(worst[i]), int(np.flatnonzero(both)[i])


def active_intervals(times: np.ndarray, inputs: np.ndarray, low: np.ndarray, high: np.ndarray, names: list[str],
                     tolerance: float = 1e-2) -> list[dict]:
    """Where an input is on its tightened limit (within `tolerance` of the span, or of 1 unit without one):
    [{"input", "side", "from_s", "to_s"}, ...] in time order; stretches apart by at most two samples are one."""
    found = []
    span = np.where(np.isfinite(high - low), high - low, 1.0)
    for i, name in enumerate(names):
        for side, limit, sign in (("max", high[i], 1.0), ("min", low[i], -1.0)):
            if not np.isfinite(limit):
                continue
            on = sign * (inputs[:, i] - limit) >= -tolerance * span[i]
            edges = np.flatnonzero(np.diff(np.concatenate([[0], on.astype(int), [0]])))
            mine: list[dict] = []
            for start, stop in zip(edges[::2], edges[1::2], strict=True):
                if mine and start - mine[-1]["_stop"] <= 2:
                    mine[-1].update(to_s=float(times[stop - 1]), _stop=stop)
                else:
                    mine.append({"input": name, "side": side, "from_s": float(times[start]),
                                 "to_s": float(times[stop - 1]), "_stop": stop})
            found += [{k: v for k, v in a.items() if k != "_stop"} for a in mine]
    return sorted(found, key=lambda a: a["from_s"])


def best_spare(base: np.ndarray, directions: np.ndarray, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """The inputs u = base + directions·z with the spare inputs z chosen per sample to keep every input as far
    inside [low, high] as it can (the smallest largest excess, relative to each input's span): the retiming's
    choice of an internal force (acroboter.planning.ideal_motion). `base`: samples x l (z = 0); `directions`:
    samples x l x spares (u's change per unit of each spare input). One spare input: exact, the minimum of a
    convex piecewise-linear function is at a crossing of two of its lines; more: a linear program per sample."""
    base, directions = np.asarray(base, float), np.asarray(directions, float)
    if directions.shape[2] == 0:
        return base
    span = np.where(np.isfinite(high - low), high - low, 1.0)
    sides = [(i, sign) for i in range(base.shape[1]) for sign, bound in ((1.0, high[i]), (-1.0, low[i]))
             if np.isfinite(bound)]
    if not sides:
        return base
    bound = np.array([high[i] if sign > 0 else low[i] for i, sign in sides])
    rows, signs = np.array([i for i, _ in sides]), np.array([s for _, s in sides])
    # each side is a line in z: sign·(base + d·z − bound) / span
    offset = signs * (base[:, rows] - bound) / span[rows]  # samples x sides
    if directions.shape[2] == 1:
        slope = signs * directions[:, rows, 0] / span[rows]
        ds = slope[:, :, None] - slope[:, None, :]
        with np.errstate(divide="ignore", invalid="ignore"):
            cross = (offset[:, None, :] - offset[:, :, None]) / ds
        cross = np.where(np.isfinite(cross), cross, 0.0).reshape(base.shape[0], -1)
        value = (slope[:, None, :] * cross[:, :, None] + offset[:, None, :]).max(axis=2)
        z = np.take_along_axis(cross, value.argmin(axis=1)[:, None], axis=1)
        return base + directions[:, :, 0] * z
    from scipy.optimize import linprog

    out = base.copy()
    k = directions.shape[2]
    for s in range(base.shape[0]):  # minimise t with every side's line ≤ t
        slope = signs[:, None] * directions[s, rows, :] / span[rows][:, None]
        res = linprog(np.r_[np.zeros(k), 1.0], A_ub=np.hstack([slope, -np.ones((len(sides), 1))]),
                      b_ub=-offset[s], bounds=[(None, None)] * (k + 1), method="highs")
        if res.status == 0:
            out[s] = base[s] + directions[s] @ res.x[:k]
    return out


def spare_constraints(inputs, directions, lower: np.ndarray, upper: np.ndarray, signs: np.ndarray,
                      at_rest: np.ndarray) -> list:
    """[(expression, lower bound), ...]: the conditions, at every column of `inputs` (l x places, symbolic, the
    spare input at 0) with `directions` (u's change per unit of the spare input), that some value z of the one
    spare input keeps every input within [lower, upper]: each bounded side is a line a·z ≤ c in z, and lines of
    opposite slope must leave an interval, c_k·(−a_j) + c_j·a_k ≥ 0; a side whose slope is 0 needs c ≥ 0. The
    slopes' signs are those at rest (`signs`), kept by sign·direction ≥ half its value at rest."""
    rising, falling, flat, out = [], [], [], []
    for i in range(len(signs)):
        for bound, side in ((upper[i], 1.0), (lower[i], -1.0)):
            if not np.isfinite(bound):
                continue
            slope, room = side * directions[i, :], side * (bound - inputs[i, :])
            {1.0: rising, -1.0: falling, 0.0: flat}[float(side * signs[i])].append((slope, room))
        if signs[i] != 0 and (np.isfinite(upper[i]) or np.isfinite(lower[i])):
            out.append((signs[i] * directions[i, :], 0.5 * float(at_rest[i])))
    for _slope, room in flat:
        out.append((room, 0.0))
    for slope_k, room_k in rising:
        for slope_j, room_j in falling:
            out.append((room_k * (-slope_j) + room_j * slope_k, 0.0))
    return out
