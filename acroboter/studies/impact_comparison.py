"""The energy each cable impact takes in the two plants, compared (acroboter.studies.plant_differential).

The own plant's impact is an impulse (restitution 0) whose kinetic energy change its events book; MuJoCo's is the
work of its compliant cable limits over a window around it, MuJoCo restarted from the own plant's state just before
(`replayed_loss`). MuJoCo's figure converges on the impulse's as its step shrinks, to first order: a grazing
re-tension (generated crane_217, the own plant's loss 0 J) took 0.0303, 0.00602 and 0.00301 J at 5e-5, 1e-5 and
5e-6 s (each step's ratio to the next the ratio of the steps, 5.02 and 2.00). Where the finest step tried still
misses the bound only because of that, `agrees_extrapolated` takes MuJoCo's figure at step 0 by Richardson's
extrapolation from its two finest steps, and only where those two show it converging on the own plant's figure at
first order: their distances from it of one sign, and reducing by the steps' ratio to an observed order within
ORDER_RANGE (a flat pair, 1.15e-4 J then 1.05e-4 J against 0, would otherwise extrapolate a real excess away).
"""

from __future__ import annotations

import math

import numpy as np

# The kinetic energy each re-tension takes, per impact: the own plant's T⁺ − T⁻ (its CableEvents) against the
# work of MuJoCo's constraint forces (acroboter.sim.mujoco_energy) over a window from IMPACT_BEFORE_S before the
# re-tension (of either plant) to RETENSION_WINDOW_S after it; re-tensions whose windows overlap (a cascade)
# are one impact. They agree within IMPACT_ENERGY_REL of the own plant's loss or IMPACT_ENERGY_J (the
# issue's bound). MuJoCo's side converges on the own plant's as its step shrinks: a single snap (the drum of
# L3 at 2 m/s, 0.0975 J in closed form) takes 1.8e-5 more at 5e-5 s, 6e-6 more at 1e-5 s
# (tests/test_plant_fuzz.py); a taut compliant cable's work while its load changes drifts by ~1e-4 J per
# 0.1 s at 5e-5 s, ~5e-6 J at 1e-5 s (that is what IMPACT_ENERGY_J and the confirming step absorb).
IMPACT_BEFORE_S = 2e-3
IMPACT_LEAD_S = 10e-3  # MuJoCo is restarted from the own plant's state this long before an impact's window
IMPACT_ENERGY_REL = 0.01
IMPACT_ENERGY_J = 1e-4


def impact_windows(events, mj_changes: list[float], h: float, steps: int,
                   retension_window: float) -> list[tuple[int, int]]:
    """The impacts compared, as plant-step indices (first, last): the plant steps ending in [first re-tension
    − IMPACT_BEFORE_S, last + retension_window] of either plant's re-tensions whose windows overlap (a
    cascade is one impact), its state at the end of step `first` to the end of step `last`. Windows that
    reach beyond the `steps` compared are left out."""
    marks = sorted([e.t for e in events if e.kind == "taut"] + list(mj_changes))
    windows: list[list[float]] = []
    for t in marks:
        if windows and t - IMPACT_BEFORE_S <= windows[-1][1]:
            windows[-1][1] = t + retension_window
        else:
            windows.append([t - IMPACT_BEFORE_S, t + retension_window])
    out = []
    for a, b in windows:
        first, last = max(0, math.floor(a / h + 1e-9)), math.ceil(b / h - 1e-9)  # plant step ends around it
        if last <= steps:
            out.append((first, last))
    return out


def impact_loss(events, first: int, last: int, h: float) -> float:
    """J: the own plant's kinetic energy loss −ΣΔT of its events in the window (plant step ends first..last)."""
    lo, hi = first * h - 1e-12, last * h + 1e-12
    return float(-sum(e.delta_kinetic for e in events if lo < e.t <= hi))


def replayed_loss(engine, ledger, own_states: np.ndarray, inputs: np.ndarray, substeps: int, h: float,
                  first: int, last: int) -> float:
    """J: the energy MuJoCo's constraint forces take over the window (plant step ends first..last), MuJoCo
    restarted from the own plant's state IMPACT_LEAD_S before it with the same inputs.

    Why restarted: what an impact takes depends on the closing speed, ½ m_eff v², and a light drum's state
    is not held to the bodies' bound: earlier compliant snaps leave MuJoCo's drums tens of µm and mm/s
    off the own plant's (acroboter seed 924: drum 3 117 µm further from its cable and 2.5 mm/s faster
    2 ms before a snap, 2 % more energy taken, from a state that is not the same). The lead lets MuJoCo's
    taut cables take up their compliant stretch (its creep, CABLE_CREEP_S) before the window."""
    lead = math.ceil(IMPACT_LEAD_S / h - 1e-9)
    start = max(0, first - lead)
    n = own_states.shape[1] // 2
    engine.set_state(own_states[start, :n], own_states[start, n:], start * h)
    ledger.reset()
    y = np.zeros(2 * n)
    at_first = 0.0
    for i in range(start, last):
        if i == first:
            at_first = ledger.work
        k = i // substeps
        engine.advance(y, inputs[k], h, engine.stage_table(i * h, h, 1), 0, 1)
    return float(at_first - ledger.work)




# The order of convergence MuJoCo's figures must show, between its two finest steps, for the extrapolation
ORDER_RANGE = (0.7, 1.4)


def impact_bound(own_loss: float) -> float:
    """J: how far MuJoCo's loss may be from the own plant's `own_loss` (IMPACT_ENERGY_REL of it, or IMPACT_ENERGY_J)."""
    return max(IMPACT_ENERGY_REL * abs(own_loss), IMPACT_ENERGY_J)


Impact = tuple[float, float, float, float]  # its window's start and end (s), the own plant's loss and MuJoCo's (J)


def agrees_extrapolated(fine: list[Impact], fine_step: float, coarse: list[Impact],
                        coarse_step: float) -> tuple[str, float] | None:
    """Whether every impact beyond the bound at MuJoCo's step `fine_step` is within it once MuJoCo's loss is
    extrapolated to step 0 from `coarse_step` (module docstring): (the note that says so, the worst ratio to the
    bound over every impact, extrapolated where it was beyond), or None. `fine`, `coarse`: per impact (its window's
    start and end, s; the own plant's loss, J; MuJoCo's, J), from the same own-plant run."""
    by_window = {(round(a, 9), round(b, 9)): loss for a, b, _, loss in coarse}
    ratio = coarse_step / fine_step
    notes, worst = [], 0.0
    for start, end, own, loss in fine:
        bound = impact_bound(own)
        if abs(loss - own) <= bound:
            worst = max(worst, abs(loss - own) / bound)
            continue
        coarse_loss = by_window.get((round(start, 9), round(end, 9)))  # the same impact, the same window
        if coarse_loss is None or ratio <= 1.0:
            return None
        off_fine, off_coarse = loss - own, coarse_loss - own
        if off_fine * off_coarse <= 0.0:  # not from one side: no convergence seen
            return None
        order = math.log(off_coarse / off_fine) / math.log(ratio)
        if not ORDER_RANGE[0] <= order <= ORDER_RANGE[1]:  # not first order (a flat pair hides a real excess)
            return None
        limit = (ratio * loss - coarse_loss) / (ratio - 1.0)
        if not math.isfinite(limit) or abs(limit - own) > bound:
            return None
        worst = max(worst, abs(limit - own) / bound)
        notes.append(f"the impact at {start:.3f} s takes {own:.4g} J in the own plant and {limit:.4g} J in MuJoCo "
                     f"extrapolated to step 0 (order {order:.2f}, from {coarse_loss:.4g} J at {coarse_step:g} s and "
                     f"{loss:.4g} J at {fine_step:g} s)")
    return ("; ".join(notes), worst) if notes else None
