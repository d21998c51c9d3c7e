"""The bounded input distribution (acroboter.control.distribution) against independent solvers.

Oracles: numpy's dense solves and closed forms for the unbounded cases, scipy's bounded least
squares (`lsq_linear`) and SLSQP with equality constraints for the bounded ones. None of them
shares code with DAQP or the eigen split under test.
"""

from __future__ import annotations

import re

import numpy as np
import pytest
from scipy.optimize import lsq_linear, minimize

from acroboter.control.distribution import PRIMAL_TOLERANCE, SECONDARY_WEIGHT, BoundedInputs, DistributionError

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


# --- what the distribution refuses, and why (mutation testing: docs/mutation.md) --------------------------


def test_solve_task_names_the_singular_matrix_and_lapacks_column():
    """E G Eᵀ singular (the fit sees nothing of the task) or E Eᵀ singular (dependent task rows): a
    DistributionError naming which, with potrf's info (the first column that failed), never a NaN input."""
    dist = BoundedInputs(np.full(3, -INF), np.full(3, INF), np.zeros(3))
    E = np.array([[1.0, 2.0, 0.0], [0.0, 1.0, 1.0]])
    with pytest.raises(DistributionError) as blind:
        dist.solve_task(np.zeros((3, 3)), np.ones(3), E)
    assert str(blind.value) == ("the fit is singular in the task directions: E G Eᵀ is not positive definite "
                                "(LAPACK potrf info 1)")
    dependent = np.array([[1.0, 0.0, 0.0], [1.0, 0.0, 0.0]])  # E Eᵀ fails at column 2, E G Eᵀ at column 1
    with pytest.raises(DistributionError) as rows:
        dist.solve_task(np.diag([0.0, 1.0, 1.0]), np.ones(3), dependent)
    assert str(rows.value) == ("the fit is singular in the task directions: E Eᵀ is not positive definite "
                               "(LAPACK potrf info 2)")


def test_solve_task_refuses_non_finite_terms():
    dist = BoundedInputs(np.full(3, -INF), np.full(3, INF), np.zeros(3))
    E = np.array([[1.0, 2.0, 0.0], [0.0, 1.0, 1.0]])
    for gradient, preferred in ((np.array([np.nan, 0.0, 0.0]), None), (np.ones(3), np.array([0.0, np.inf, 0.0]))):
        if preferred is not None:
            dist = BoundedInputs(np.full(3, -INF), np.full(3, INF), preferred)
        with pytest.raises(DistributionError, match="^the input distribution's terms are not finite$"):
            dist.solve_task(np.eye(3), gradient, E)


def test_solve_task_refuses_a_weighted_distribution_by_name():
    dist = BoundedInputs(np.zeros(3), np.ones(3), np.zeros(3), weight=1e-5)
    with pytest.raises(ValueError) as refused:
        dist.solve_task(np.eye(3), np.zeros(3), np.ones((2, 3)))
    assert str(refused.value) == "solve_task is lexicographic: construct BoundedInputs with weight 0"


@pytest.mark.parametrize("weight", [0.0, 1e-3])
def test_the_solution_does_not_depend_on_the_fits_units(weight):
    """Scaling G and g together (N², a fit in other units) leaves u as it is: the rank decision and the
    secondary weight are relative to G's mean eigenvalue, bounded or not, lexicographic or weighted."""
    rng = np.random.default_rng(12)
    E, e = rng.standard_normal((4, 7)), rng.standard_normal(4)
    G, g = E.T @ E, -E.T @ e
    preferred = rng.uniform(10, 20, 7)
    for lower, upper in ((np.full(7, -INF), np.full(7, INF)), (np.full(7, 9.0), np.full(7, 16.0))):
        ref = BoundedInputs(lower, upper, preferred, weight=weight).solve(G, g).copy()
        for s in (1e-6, 1e-3, 1e3, 1e6):
            u = BoundedInputs(lower, upper, preferred, weight=weight).solve(s * G, s * g)
            np.testing.assert_allclose(u, ref, rtol=1e-6, atol=1e-6 * np.abs(ref).max())


@pytest.mark.parametrize("weight", [0.0, 1e-3])
def test_a_fit_that_sees_nothing_gives_the_preferred_inputs(weight):
    """G = 0 and g = 0 (no input moves the task): every direction is an internal force, u = u_pref."""
    preferred = np.array([3.0, -1.0, 7.0])
    dist = BoundedInputs(np.full(3, -INF), np.full(3, INF), preferred, weight=weight)
    np.testing.assert_allclose(dist.solve(np.zeros((3, 3)), np.zeros(3)), preferred, rtol=0, atol=1e-12)
    # limits that cut u_pref: the inputs within them closest to it (the secondary objective alone)
    cut = BoundedInputs(np.array([0.0, 0.0, 0.0]), np.array([2.0, 1.0, 9.0]), preferred, weight=weight)
    np.testing.assert_allclose(cut.solve(np.zeros((3, 3)), np.zeros(3)), [2.0, 0.0, 7.0], rtol=0, atol=1e-9)


@pytest.mark.parametrize("weight", [0.0, 1e-3])
def test_solve_refuses_non_finite_terms(weight):
    dist = BoundedInputs(np.full(3, -INF), np.full(3, INF), np.zeros(3), weight=weight)
    for G, g in ((np.eye(3), np.array([0.0, np.nan, 0.0])), (np.diag([1.0, np.inf, 1.0]), np.zeros(3))):
        with pytest.raises(DistributionError, match="^the input distribution's terms are not finite$"):
            dist.solve(G, g)


def test_a_weighted_fit_that_is_not_convex_is_named():
    """An indefinite G (a controller's broken fit): G + μI has no Cholesky factor, and the error says so."""
    dist = BoundedInputs(np.full(2, -INF), np.full(2, INF), np.zeros(2), weight=1e-3)
    with pytest.raises(DistributionError) as err:
        dist.solve(np.diag([1.0, -5.0]), np.ones(2))
    assert str(err.value) == "G + μI is not positive definite (LAPACK potrf info 2)"


def test_limits_that_cross_are_refused_before_any_solve():
    with pytest.raises(ValueError) as err:
        BoundedInputs(np.array([1.0, 0.0]), np.array([0.0, 1.0]), np.zeros(2))
    assert str(err.value) == "input 0: min 1 is above max 0; give min <= max"


def test_a_fit_that_is_not_convex_is_an_error_not_an_input():
    """An indefinite G (a controller's broken fit) whose unbounded answer leaves the limits: DAQP is handed a
    QP that is not convex, and the distribution says so instead of returning what DAQP gives."""
    dist = BoundedInputs(np.zeros(2), np.ones(2), np.array([0.5, 5.0]))
    with pytest.raises(DistributionError) as err:
        dist.solve(np.diag([3.0, -1.0]), -np.array([1.5, 0.0]))
    # (DAQP reports success, exit flag 1, with a non-finite input for a Hessian that is not positive definite)
    assert re.fullmatch(r"the bounded input distribution failed \(DAQP exit flag 1, input \[.*nan.*\]\): the "
                        r"controller's fit is not convex or its terms are inconsistent with the limits", str(err.value))


def test_the_diagnostics_count_what_ran():
    """bounded_step says whether the last solve needed the QP, qp_solves how many did (bench reports it)."""
    dist = BoundedInputs(np.zeros(2), np.ones(2), np.zeros(2))
    assert dist.bounded_step is False and dist.qp_solves == 0 and dist.limit_state.dtype == np.int8
    # DAQP ignores a setting it does not know: the tolerance the snapping below relies on is the one in force
    assert dist._qp.settings["primal_tol"] == PRIMAL_TOLERANCE
    assert dist.accept(np.array([0.5, 0.5])) and dist.bounded_step is False and dist.qp_solves == 0
    dist.solve(np.eye(2), -np.array([5.0, 0.5]))
    assert dist.bounded_step is True and dist.qp_solves == 1
    np.testing.assert_array_equal(dist.unbounded, [5.0, 0.5])  # what the controller asked (the judge reads it)
    dist.solve(np.eye(2), -np.array([0.5, 0.5]))  # within the limits: no QP
    assert dist.bounded_step is False and dist.qp_solves == 1
    dist.solve(np.eye(2), -np.array([0.5, -3.0]))
    assert dist.bounded_step is True and dist.qp_solves == 2
    assert dist.limit_state.tolist() == [0, -1]


def test_limits_given_as_integers_are_limits():
    """`min = 5` in TOML is an integer: the same input as 5.0."""
    ints = BoundedInputs([0, 0, 0], [10, 10, 10], [5, 5, 5])
    floats = BoundedInputs(np.zeros(3), np.full(3, 10.0), np.full(3, 5.0))
    G, g = np.diag([1.0, 2.0, 3.0]), -np.array([30.0, 4.0, -6.0])
    np.testing.assert_array_equal(ints.solve(G, g), floats.solve(G, g))
    assert ints.lower.dtype == ints.upper.dtype == ints.preferred.dtype == np.float64


def test_an_input_fixed_by_equal_limits_is_held_there():
    """min = max: the input is fixed (a winch run at a set tension); the others are free to fit."""
    dist = BoundedInputs(np.array([3.0, -INF]), np.array([3.0, INF]), np.zeros(2))
    u = dist.solve(np.eye(2), -np.array([5.0, 0.5]))
    assert u.tolist() == [3.0, 0.5] and dist.limit_state.tolist() == [1, 0]
