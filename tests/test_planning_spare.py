"""The retiming's spare inputs (an internal force: the four-cable crane's seven inputs for six servo-constraints)
and the pieces the edge-by-edge retiming stands on, each against an independent oracle: a dense search over the
spare input, a linear program, the static equilibrium's own solve, and the closed form of a held acceleration."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import linprog

import acroboter
from acroboter.planning.ideal_motion import IdealDynamics
from acroboter.planning.limits import best_spare, spare_constraints

LOW = np.array([5.0, 5.0, 5.0, 5.0, -np.inf, -2.0])
HIGH = np.array([30.0, 30.0, 30.0, 30.0, np.inf, np.inf])
SPAN = np.where(np.isfinite(HIGH - LOW), HIGH - LOW, 1.0)


def worst(u: np.ndarray) -> np.ndarray:
    """Per sample, the largest excess of any input beyond its bounds, relative to its span (≤ 0: within)."""
    over = np.maximum(u - HIGH, LOW - u) / SPAN
    return np.where(np.isnan(over), -np.inf, over).max(axis=1)


samples = st.integers(0, 2**32 - 1).map(lambda seed: np.random.default_rng(seed))


@settings(max_examples=60, deadline=None)
@given(rng=samples)
def test_the_spare_input_is_the_best_a_dense_search_finds(rng):
    base = rng.normal(15.0, 12.0, (20, 6))
    direction = rng.choice([-1.0, 1.0], 6) * rng.uniform(0.2, 2.0, 6)
    direction[rng.integers(0, 6)] = 0.0  # an input the internal force does not move
    directions = np.repeat(direction[None, :, None], 20, axis=0)
    chosen = best_spare(base, directions, LOW, HIGH)
    z = np.linspace(-200.0, 200.0, 40001)
    searched = np.array([worst(base[s][None, :] + np.outer(z, direction)).min() for s in range(20)])
    assert np.all(worst(chosen) <= searched + 1e-6)  # never worse than the search (its grid is 0.01 wide)
    assert np.all(worst(chosen) >= searched - 2.0 * 0.01 * np.abs(direction).max() / SPAN[:4].min())
    # and it only moves along the internal force
    shift = (chosen - base)[:, direction != 0] / direction[direction != 0]
    assert np.allclose(shift, shift[:, :1], atol=1e-9)


@settings(max_examples=60, deadline=None)
@given(rng=samples)
def test_the_spare_conditions_hold_exactly_when_some_internal_force_fits(rng):
    """spare_constraints (the retiming's smooth conditions) against a linear program's feasibility per sample."""
    base = rng.normal(17.0, 9.0, (30, 6))
    direction = np.array([-1.0, 1.0, -1.0, 1.0, 0.0, 0.5]) * rng.uniform(0.5, 1.5, 6)
    signs = np.sign(direction)
    conditions = spare_constraints(base.T, np.repeat(direction[:, None], 30, axis=1), LOW, HIGH, signs,
                                   np.abs(direction))
    ours = np.all([np.asarray(expr) >= low - 1e-12 for expr, low in conditions], axis=0)
    for s in range(30):  # is there z with LOW ≤ base + direction·z ≤ HIGH?
        bounded = np.isfinite(HIGH)
        a = np.concatenate([direction[bounded], -direction[np.isfinite(LOW)]])[:, None]
        b = np.concatenate([HIGH[bounded] - base[s, bounded], base[s, np.isfinite(LOW)] - LOW[np.isfinite(LOW)]])
        fits = linprog([0.0], A_ub=a, b_ub=b, bounds=[(None, None)], method="highs").status == 0
        assert ours[s] == fits, s


@pytest.fixture(scope="module")
def four_cable():
    return acroboter.Crane.from_toml(acroboter.example_spec("acroboter_4cable"))


def test_the_four_cable_cranes_spare_input_is_its_internal_force(four_cable):
    """At the static start the ideal inputs, whatever the spare input, differ from the equilibrium solve's own
    inputs (acroboter.sim.statics, its own distribution) only along the internal force: the four tensions in
    turn up and down, nothing else."""
    eq = four_cable.equilibrium()
    dyn = IdealDynamics(four_cable.spec, eq.q)
    assert dyn.spares == 1 and dyn.spare_index == [3]
    path = four_cable.path
    s, sd, sdd = path.signal_arrays(0.0)
    _, u0, direction = (np.asarray(v).ravel() for v in dyn.function(eq.q, np.zeros(dyn.layout.n), s, sd, sdd))
    assert direction[:4] == pytest.approx([-1.0, 1.0, -1.0, 1.0], abs=1e-9)
    assert np.abs(direction[4:]).max() < 1e-9
    z = eq.inputs[3] - u0[3]
    assert u0 + z * direction == pytest.approx(eq.inputs, abs=1e-7)
