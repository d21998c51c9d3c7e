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


def tightened(lower: np.ndarray, upper: np.ndarray, margin: float) -> tuple[np.ndarray, np.ndarray]:
    """(lower, upper) moved inwards by the margin (see the module's docstring)."""
    lower, upper = np.asarray(lower, dtype=float), np.asarray(upper, dtype=float)
    both = np.isfinite(lower) & np.isfinite(upper)
    span = np.where(both, upper - lower, 0.0)
    low = np.where(both, lower + margin * span, lower + margin * np.abs(np.where(np.isfinite(lower), lower, 0.0)))
    high = np.where(both, upper - margin * span, upper - margin * np.abs(np.where(np.isfinite(upper), upper, 0.0)))
    return low, high


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
