"""The bounded input distribution (acroboter.control.distribution) against independent solvers.

Oracles: numpy's dense solves and closed forms for the unbounded cases, scipy's bounded least
squares (`lsq_linear`) and SLSQP with equality constraints for the bounded ones. None of them
shares code with DAQP or the eigen split under test.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import lsq_linear, minimize

from acroboter.control.distribution import SECONDARY_WEIGHT, BoundedInputs

INF = np.inf


def random_least_squares(rng, rows: int, cols: int):
    a = rng.standard_normal((rows, cols))
    b = rng.standard_normal(rows) * 10
    return a, b, a.T @ a, -a.T @ b  # ½|a u − b|² = ½ uᵀ(aᵀa)u − (aᵀb)ᵀu + const


@pytest.mark.parametrize("seed", range(5))
def test_free_inputs_give_the_least_squares_solution(seed):
    rng = np.random.default_rng(seed)
    a, b, G, g = random_least_squares(rng, 9, 6)
    dist = BoundedInputs(np.full(6, -INF), np.full(6, INF), np.zeros(6))
    u = dist.solve(G, g)
    np.testing.assert_allclose(u, np.linalg.lstsq(a, b, rcond=None)[0], rtol=1e-10, atol=1e-12)
    assert not dist.limit_state.any()


@pytest.mark.parametrize("seed", range(8))
def test_bounded_least_squares_matches_scipy(seed):
    rng = np.random.default_rng(seed)
    a, b, G, g = random_least_squares(rng, 9, 6)
    free = np.linalg.lstsq(a, b, rcond=None)[0]
    lower = free - rng.uniform(-0.5, 1.0, 6) * np.abs(free)  # some bounds cut the free solution
    upper = lower + rng.uniform(0.1, 2.0, 6) * (1 + np.abs(free))
    lower[0] = -INF  # an unbounded side
    dist = BoundedInputs(lower, upper, np.zeros(6))
    u = dist.solve(G, g)
    ref = lsq_linear(a, b, bounds=(lower, upper), method="bvls", tol=1e-14)
    np.testing.assert_allclose(u, ref.x, rtol=1e-8, atol=1e-8)
    assert np.all(u >= lower) and np.all(u <= upper)
    # limit_state names exactly the inputs the oracle holds on a bound
    on_lower = np.isclose(ref.x, lower, rtol=0, atol=1e-9)
    on_upper = np.isclose(ref.x, upper, rtol=0, atol=1e-9)
    assert (dist.limit_state == -1).tolist() == on_lower.tolist()
    assert (dist.limit_state == 1).tolist() == on_upper.tolist()
    assert (on_lower | on_upper).any() or dist.within_limits(free)


def test_internal_forces_go_to_the_preferred_values():
    """More inputs than equations: among the exact solutions of E u = e, the one closest to u_pref."""
    rng = np.random.default_rng(3)
    E, e = rng.standard_normal((4, 7)), rng.standard_normal(4)
    preferred = rng.uniform(10, 20, 7)
    dist = BoundedInputs(np.full(7, -INF), np.full(7, INF), preferred)
    u = dist.solve(E.T @ E, -E.T @ e)
    closest = preferred + np.linalg.pinv(E) @ (e - E @ preferred)  # closed form
    np.testing.assert_allclose(u, closest, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(E @ u, e, atol=1e-10)


def test_bounded_internal_forces_match_an_equality_constrained_oracle():
    """Limits cut the exact solution closest to u_pref; another exact one within them exists."""
    rng = np.random.default_rng(4)
    E = rng.standard_normal((3, 6))
    inside = rng.uniform(8, 12, 6)  # an exact solution within the limits
    e = E @ inside
    preferred = np.full(6, 30.0)  # far outside: the closest exact solution breaks the upper limit
    lower, upper = np.full(6, 5.0), np.full(6, 14.0)
    dist = BoundedInputs(lower, upper, preferred)
    u = dist.solve(E.T @ E, -E.T @ e)
    ref = minimize(lambda x: 0.5 * np.sum((x - preferred) ** 2), inside, jac=lambda x: x - preferred,
                   method="SLSQP", bounds=list(zip(lower, upper, strict=True)),
                   constraints=[{"type": "eq", "fun": lambda x: E @ x - e, "jac": lambda x: E}],
                   options={"ftol": 1e-12, "maxiter": 500})
    assert ref.success
    # The QP weighs the internal forces by SECONDARY_WEIGHT against the primary: exact to about that
    # (seen: |E u − e| 2e-7, |u − SLSQP's| 1.4e-5 over 30 seeds).
    assert SECONDARY_WEIGHT <= 1e-9
    np.testing.assert_allclose(E @ u, e, atol=1e-6)
    np.testing.assert_allclose(u, ref.x, atol=1e-4)
    assert (dist.limit_state == 1).any()
    assert np.all(u >= lower) and np.all(u <= upper)


def test_weighted_secondary_objective_has_the_closed_form():
    rng = np.random.default_rng(5)
    E, e = rng.standard_normal((4, 7)), rng.standard_normal(4)
    G, g = E.T @ E, -E.T @ e
    preferred = rng.uniform(10, 20, 7)
    dist = BoundedInputs(np.full(7, -INF), np.full(7, INF), preferred, weight=1e-3)
    mu = 1e-3 * np.trace(G) / 7  # the weight is relative to G's mean eigenvalue
    np.testing.assert_allclose(dist.solve(G, g), np.linalg.solve(G + mu * np.eye(7), mu * preferred - g), rtol=1e-9)


def test_accept_keeps_a_solution_within_the_limits_bit_for_bit():
    dist = BoundedInputs(np.zeros(3), np.full(3, INF), np.zeros(3))
    u = np.array([26.753871403, 1e-300, 3.0])
    assert dist.accept(u)
    assert dist.u.tobytes() == u.tobytes()
    assert not dist.accept(np.array([1.0, -1e-12, 2.0]))  # a cable asked to push, however little
