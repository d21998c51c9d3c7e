"""What each controller reports besides u, against the equations of motion computed with numpy (issue 19).

The controllers' `qdd` and `multipliers` are what the plots, the C export comparison and the reaction
forces read. Checked at moving states of a recorded run, with the symbolic model's terms (`model_terms`):
- MLM: M q̈ + c + φ_qᵀλ − H u = 0 and φ_q q̈ + γ = 0, also when a limit holds u and λ is recomputed
  for the bounded input;
- the penalty methods (any number of iterations): M q̈_N + c + φ_qᵀλ_N + σ_qᵀλ̂_N = 0, eqs. 17–18 summed
  over the iterations;
- the bookkeeping around them: one compiled model shared by controllers with different gains, the
  integral's reset and its restart when time goes back, and the factory's names and refusals.
Mutation testing (docs/mutation.md) found these reached by no other test.
"""

from __future__ import annotations

import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from conftest import load_with_start

from acroboter.control.controllers import MLM, Gains, Penalty, SingularSystemError, make_controller
from acroboter.control.recovery import InputRecovery, RecoveryError
from acroboter.model.spec import RECOVERIES
from acroboter.sim.simulation import setup_default, simulate

REPO = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def crane():
    return load_with_start(REPO / "model_spec" / "acroboter.toml")


@pytest.fixture(scope="module")
def states(crane):
    spec, model, path, start = crane
    controller = make_controller("penalty", model, path, Gains.from_spec(spec))
    r = simulate(model, path, controller, setup_default(model, path), start.q, 3.0,
                 spec.controller.rate_hz, spec.simulation.step)
    return [(r.q[k].copy(), r.qd[k].copy(), float(r.t[k])) for k in (20, 60, 110, 149)]


def terms(model, path, q, qd, t) -> dict:
    return {k: np.array(v, copy=True) for k, v in model.evaluate("model_terms", q, qd, *path.signal_arrays(t)).items()}


def scale_of(*arrays) -> float:
    return max(1.0, *(float(np.abs(a).max()) for a in arrays))


@pytest.mark.parametrize("bounded", [False, True])
def test_mlm_reports_the_multipliers_and_acceleration_of_its_input(crane, states, bounded):
    spec, model, path, _ = crane
    gains = Gains.from_spec(spec)
    lower, upper, preferred = spec.input_limits()
    held = 0
    for q, qd, t in states:
        limits = None
        if bounded:  # the first winch's max just below what it asks here: the QP runs, λ is recomputed
            free = make_controller("mlm", model, path, gains).compute(q, qd, t).copy()
            upper = np.array(spec.input_limits()[1], dtype=float)
            upper[0] = free[0] - 0.05
            limits = (lower, upper, preferred)
        controller = make_controller("mlm", model, path, gains, limits=limits)
        u = controller.compute(q, qd, t).copy()
        lam, none = controller.multipliers
        qdd = controller.qdd
        T = terms(model, path, q, qd, t)
        balance = T["mass_matrix"] @ qdd + T["bias_forces"] + T["phi_q"].T @ lam - T["input_matrix"] @ u
        size = scale_of(T["bias_forces"], T["input_matrix"] @ u)
        np.testing.assert_allclose(balance, 0.0, atol=1e-9 * size)
        np.testing.assert_allclose(T["phi_q"] @ qdd + T["gamma"], 0.0, atol=1e-9 * scale_of(T["gamma"]))
        assert none is None and np.abs(lam).max() > 1.0
        if bounded:
            assert u[0] == pytest.approx(upper[0], abs=1e-9) and controller.limit_state[0] == 1
            held += 1
    assert held == (len(states) if bounded else 0)


@pytest.mark.parametrize("method", ["penalty", "iterative-2", "iterative-3", "iterative-4"])
def test_penalty_multipliers_balance_the_commanded_acceleration(crane, states, method):
    spec, model, path, _ = crane
    controller = make_controller(method, model, path, Gains.from_spec(spec))
    for q, qd, t in states:
        controller.compute(q, qd, t)
        lam, lam_hat = (np.array(a, copy=True) for a in controller.multipliers)
        qdd = np.array(controller.qdd, copy=True)
        T = terms(model, path, q, qd, t)
        balance = T["mass_matrix"] @ qdd + T["bias_forces"] + T["phi_q"].T @ lam + T["sigma_q"].T @ lam_hat
        np.testing.assert_allclose(balance, 0.0, atol=1e-8 * scale_of(T["bias_forces"], T["phi_q"].T @ lam))
        assert np.abs(lam_hat).max() > 1e-3  # the servo multipliers carry the task's force


def test_controllers_sharing_one_model_keep_their_own_gains(crane, states):
    """Two controllers on one compiled model, called in turn: each gives what it gives alone (the shared
    parameter buffer is reloaded when the other one wrote it last)."""
    spec, model, path, _ = crane
    gains = Gains.from_spec(spec)
    other = replace(gains, kp=2 * gains.kp, kd=2 * gains.kd)
    for method in ("mlm", "penalty"):
        alone = [make_controller(method, model, path, g) for g in (gains, other)]
        expected = [[c.compute(q, qd, t).copy() for q, qd, t in states] for c in alone]
        a, b = make_controller(method, model, path, gains), make_controller(method, model, path, other)
        for i, (q, qd, t) in enumerate(states):
            np.testing.assert_array_equal(a.compute(q, qd, t), expected[0][i])
            np.testing.assert_array_equal(b.compute(q, qd, t), expected[1][i])
        assert np.abs(expected[0][1] - expected[1][1]).max() > 1e-3  # the gains matter at these states


def test_the_integral_restarts_with_a_new_run(crane, states):
    """z after reset() and after time goes back equals a fresh controller's; at an instant already seen it
    does not grow."""
    spec, model, path, _ = crane
    gains = replace(Gains.from_spec(spec), ki=18.375)
    fresh = make_controller("penalty", model, path, gains)
    used = make_controller("penalty", model, path, gains)
    for q, qd, t in states:
        used.compute(q, qd, t)
    assert np.abs(used.integral).max() > 0
    z = used.integral.copy()
    q, qd, t = states[-1]
    used.compute(q, qd, t)  # the same instant again: nothing to integrate
    np.testing.assert_array_equal(used.integral, z)
    first = [fresh.compute(q, qd, t).copy() for q, qd, t in states[:2]]
    again = [used.compute(q, qd, t).copy() for q, qd, t in states[:2]]  # time went back: a new run
    np.testing.assert_array_equal(again[0], first[0])
    np.testing.assert_array_equal(used.integral, fresh.integral)
    used.reset()
    assert not used.integral.any() and used._t_last is None and used._hold is False


def test_the_factory_names_and_refuses():
    assert make_controller.__name__ == "make_controller"
    spec, model, path, _ = load_with_start(REPO / "model_spec" / "acroboter.toml")
    gains = Gains.from_spec(spec)
    assert isinstance(make_controller("mlm", model, path, gains), MLM)
    assert Penalty(model, path, gains).iterations == 1  # the class alone is the plain penalty method
    for method, iterations in (("penalty", 1), ("iterative-1", 1), ("iterative-7", 7)):
        c = make_controller(method, model, path, gains)
        assert isinstance(c, Penalty) and c.iterations == iterations
        assert c.name == ("penalty" if iterations == 1 else f"iterative-{iterations}")
    for bad in ("newton", "iterative-", "iterative-x", "Penalty"):
        with pytest.raises(ValueError) as err:
            make_controller(bad, model, path, gains)
        assert str(err.value) == f"unknown method '{bad}': use mlm, penalty or iterative-N (N >= 1)"
    with pytest.raises(ValueError, match="^iterations must be at least 1$"):
        make_controller("iterative-0", model, path, gains)


def test_a_penalty_matrix_that_is_not_positive_definite_is_named(crane, states):
    spec, model, path, _ = crane
    gains = replace(Gains.from_spec(spec), alpha_geometric=-1e9)
    controller = make_controller("penalty", model, path, gains)
    q, qd, t = states[0]
    with pytest.raises(SingularSystemError) as err:
        controller.compute(q, qd, t)
    assert str(err.value).startswith("the penalty matrix A = M + α̃ φ_qᵀφ_q + α̂ σ_qᵀσ_q is not positive definite "
                                     "(LAPACK potrf info ")
    assert str(err.value).endswith("): check the penalty numbers")


@pytest.mark.parametrize("name, method", [("acroboter", "mlm"), ("acroboter", "penalty"),
                                          ("acroboter_4cable", "mlm"), ("acroboter_4cable", "penalty")])
def test_underactuation_holds_the_input_and_keeps_the_reduced_task_through_the_dwell(name, method):
    """One controller stepped by hand: state A asks winch 1 for more than its max, state B for less.
    A: winch 1 held exactly at its max, the step reported saturated, an input other than the QP's;
    B 0.02 s later (inside the limits, within the 0.1 s dwell): still the reduced task, not B's full-task input;
    B 0.14 s after A (inside the limits by the release margin for longer than the dwell): the full task again,
    B's input exactly.
    (The four-cable crane's MLM reaches the limits through the distribution of its redundant inputs.)"""
    spec, model, path, start = load_with_start(REPO / "model_spec" / f"{name}.toml")
    gains = Gains.from_spec(spec)
    r = simulate(model, path, make_controller("mlm", model, path, gains), setup_default(model, path), start.q, 24.0,
                 spec.controller.rate_hz, spec.simulation.step)
    free = [make_controller(method, model, path, gains) for _ in range(3)]
    # winch 1 capped; on the four-cable crane every winch (one alone is made up for by the others: then both
    # strategies meet the task and agree). The cap sits between the largest ask of the capped winches at A and at B.
    capped = slice(0, 4 if name == "acroboter_4cable" else 1)
    asks = np.array([free[0].compute(r.q[k], r.qd[k], r.t[k])[capped].max() for k in range(0, len(r.t), 25)])
    a, b = 25 * int(asks.argmax()), 25 * int(asks.argmin())
    lower, upper, preferred = (np.array(x, dtype=float) for x in spec.input_limits())
    upper[capped] = 0.5 * (asks.max() + asks.min())
    assert asks.max() - asks.min() > 0.02  # the path asks for more, then less (by 0.029 N on the four-cable crane)
    limits = (lower, upper, preferred)
    under = make_controller(method, model, path, replace(gains, saturation="underactuation"), limits=limits)
    qp = make_controller(method, model, path, gains, limits=limits)
    t0 = 10.0  # the dwell's clock; each state's own path signals are passed with it
    sig_a, sig_b = path.flat(r.t[a]), path.flat(r.t[b])
    u_a = under.compute(r.q[a], r.qd[a], t0, sig_a).copy()
    assert u_a[0] == upper[0] and under.limit_state[0] == 1
    assert under.saturation() is True
    assert np.all(u_a >= lower) and np.all(u_a <= upper)
    if method == "mlm":  # the reported multipliers and acceleration are those of the held input
        lam, _ = under.multipliers
        s_a = np.array(sig_a).reshape(3, -1)
        T = {k: np.array(v, copy=True) for k, v in model.evaluate("model_terms", r.q[a], r.qd[a], *s_a).items()}
        balance = T["mass_matrix"] @ under.qdd + T["bias_forces"] + T["phi_q"].T @ lam - T["input_matrix"] @ u_a
        np.testing.assert_allclose(balance, 0.0, atol=1e-9 * scale_of(T["bias_forces"], T["input_matrix"] @ u_a))
    assert np.abs(u_a - qp.compute(r.q[a], r.qd[a], t0, sig_a)).max() > 1e-6  # not the QP's answer
    # a state gone non-finite while a winch is held: an error naming the step, never a NaN input
    broken = r.qd[a].copy()
    broken[3] = np.nan
    held = make_controller(method, model, path, replace(gains, saturation="underactuation"), limits=limits)
    held.compute(r.q[a], r.qd[a], t0, sig_a)
    with pytest.raises(SingularSystemError) as err:
        held.compute(r.q[a], broken, t0 + 0.02, sig_a)
    assert str(err.value) == f"{under.name}: " + (
        "saturation as underactuation: the servo-constraint terms are not finite" if name == "acroboter"
        else "the input distribution's terms are not finite")  # (the distribution of redundant inputs sees it first)
    if name != "acroboter":
        return  # the four-cable crane's B asks within 0.015 N of the caps: no clear return to test there
    for dt, full in ((0.02, False), (0.14, True)):
        u_b = under.compute(r.q[b], r.qd[b], t0 + dt, sig_b).copy()
        u_free = free[1 if full else 2].compute(r.q[b], r.qd[b], t0 + dt, sig_b)
        if full:
            np.testing.assert_allclose(u_b, u_free, rtol=1e-12, atol=1e-12)
            assert not under.limit_state.any()
        else:
            assert np.abs(u_b - u_free).max() > 1e-6 and under.limit_state.any()


def test_mlm_refuses_redundant_systems_by_name():
    """In-process (tests/test_redundancy.py runs them too, through the API): a redundant task has more servo-
    constraints than inputs; a duplicated cable makes the (n+m+l) system singular."""
    spec, model, path, start = load_with_start(REPO / "model_spec" / "acroboter_redundant_task.toml")
    with pytest.raises(SingularSystemError) as task:
        make_controller("mlm", model, path, Gains.from_spec(spec))
    lay = model.layout
    assert str(task.value) == (
        f"MLM needs at least as many inputs as servo-constraints, found {lay.k} servo-constraints for {lay.l} inputs "
        "(redundant task): its matrix is not square. Use the penalty or iterative penalty method.")
    spec, model, path, start = load_with_start(REPO / "model_spec" / "acroboter_redundant.toml")
    controller = make_controller("mlm", model, path, Gains.from_spec(spec))
    with pytest.raises(SingularSystemError) as system:
        controller.compute(start.q, np.zeros(model.layout.n), 0.0)
    size = model.layout.n + model.layout.m + model.layout.l
    assert re.fullmatch(
        rf"MLM's {size}x{size} system is singular \(reciprocal condition number \d\.\de[-+]\d\d\): the geometric "
        r"constraints are redundant or the task is not reachable by the inputs\. MLM needs independent constraints; "
        r"use the penalty or iterative penalty method, which handle redundancy\.", str(system.value))
    assert controller.rcond < 1e-12


@pytest.mark.parametrize("method", ["mlm", "penalty", "iterative-3"])
def test_the_signals_given_are_the_ones_used(crane, states, method):
    """compute(q, q̇, t, signals): the path's signals as given (a table's row), whatever t is."""
    spec, model, path, _ = crane
    q, qd, t = states[2]
    given = make_controller(method, model, path, Gains.from_spec(spec)).compute(q, qd, 0.0, path.flat(t)).copy()
    own = make_controller(method, model, path, Gains.from_spec(spec)).compute(q, qd, t)
    np.testing.assert_array_equal(given, own)


def test_the_integral_holds_over_a_period_after_a_saturated_step(crane, states):
    """Anti-windup (docs/integral_action.md): z advances by the trapezoid of σ over a period unless the step
    that began it saturated. Unbounded, z is the trapezoid from the first step on; with the first winch's
    max below what it asks at every state, every step saturates and z stays 0. k_I = 1 (any value but 0
    integrates)."""
    spec, model, path, _ = crane
    gains = replace(Gains.from_spec(spec), ki=1.0)
    lower, upper, preferred = spec.input_limits()
    free = make_controller("mlm", model, path, gains)
    asked = [free.compute(q, qd, t)[0] for q, qd, t in states]
    tight = np.array(upper, dtype=float)
    tight[0] = min(asked) - 0.05
    for limits, saturates in ((None, False), ((lower, tight, preferred), True)):
        controller = make_controller("mlm", model, path, gains, limits=limits)
        expected = np.zeros(controller.k)
        previous = None
        for q, qd, t in states:
            controller.compute(q, qd, t)
            assert controller.saturation() is saturates
            sigma = terms(model, path, q, qd, t)["sigma"]
            if previous is not None and not saturates:
                expected += 0.5 * (t - previous[0]) * (previous[1] + sigma)
            previous = (t, sigma)
            np.testing.assert_allclose(controller.integral, expected, rtol=1e-12, atol=1e-18)
        assert saturates or np.abs(expected).max() > 1e-9  # σ is not 0 at these states


def test_without_integral_action_nothing_is_integrated(crane, states):
    spec, model, path, _ = crane
    for method in ("mlm", "penalty"):
        controller = make_controller(method, model, path, Gains.from_spec(spec))
        assert controller.ki == 0.0 and controller.saturation() is False  # nothing judged before a step
        for q, qd, t in states:
            controller.compute(q, qd, t)
        assert not controller.integral.any()


def test_the_factory_passes_the_limits_and_the_distribution_its_weight():
    """A caller's limits reach every method; the penalty methods' eq12/eq13 recoveries weight the
    secondary objective where inputs are redundant (four cables), never on a square system."""
    from acroboter.model.settings import PENALTY_SECONDARY_WEIGHT

    for name, redundant in (("acroboter", False), ("acroboter_4cable", True)):
        spec, model, path, _ = load_with_start(REPO / "model_spec" / f"{name}.toml")
        lower, upper, preferred = spec.input_limits()
        upper = np.asarray(upper, dtype=float)  # a winch's max is inf: a finite one of the caller's
        mine = (np.asarray(lower) - 1.0, np.where(np.isinf(upper), 100.0, upper - 0.5), preferred)
        for method in ("mlm", "penalty", "iterative-3"):
            for recovery in ("projected", "eq12"):
                gains = replace(Gains.from_spec(spec), recovery=recovery)
                c = make_controller(method, model, path, gains, limits=mine)
                np.testing.assert_array_equal(c.limits.upper, mine[1])
                np.testing.assert_array_equal(c.limits.lower, mine[0])
                weighted = redundant and method != "mlm" and recovery != "projected"
                assert c.limits.weight == (PENALTY_SECONDARY_WEIGHT if weighted else 0.0)
        with pytest.raises(ValueError, match="^saturation: expected 'qp' or 'underactuation', found 'clip'$"):
            make_controller("mlm", model, path, replace(Gains.from_spec(spec), saturation="clip"))


def test_the_factory_builds_the_fast_path_of_the_method_asked(crane, states):
    """fast=True wraps the reference controller of that method with that caller's limits: u as the reference's
    (to the fast path's 1e-9, docs/fast-path.md), and unlike the neighbouring method's."""
    from acroboter.control.fast_path import FastController
    from acroboter.runtime.casadi_backend import CasadiModel

    spec, model, path, _ = crane
    if isinstance(model, CasadiModel):
        pytest.skip("ACROBOTER_TEST_MODELS=casadi: the fast path compiles its step from the C of a compiled model")
    gains = Gains.from_spec(spec)
    lower, upper, preferred = spec.input_limits()
    upper = np.asarray(upper, dtype=float)  # a winch's max is inf: finite ones of the caller's, not binding here
    mine = (lower, np.where(np.isinf(upper), 100.0, upper - 0.25), preferred)
    q, qd, t = states[1]
    asked = {m: make_controller(m, model, path, gains, limits=mine).compute(q, qd, t).copy()
             for m in ("mlm", "penalty", "iterative-3")}
    for method, other in (("mlm", "penalty"), ("iterative-3", "penalty")):
        fast = make_controller(method, model, path, gains, limits=mine, fast=True)
        assert isinstance(fast, FastController) and fast.name == method
        np.testing.assert_array_equal(fast.reference.limits.upper, mine[1])
        u = fast.compute(q, qd, t)
        np.testing.assert_allclose(u, asked[method], rtol=0, atol=1e-9 * np.abs(asked[method]).max())
        assert np.abs(u - asked[other]).max() > 100 * 1e-9 * np.abs(asked[method]).max()


@pytest.mark.parametrize("method", ["penalty", "iterative-3"])
@pytest.mark.parametrize("recovery", ["eq12", "eq13"])
def test_a_bounded_least_squares_recovery_is_its_fit_within_the_limits(crane, states, method, recovery):
    """eq12 (min |H u + σ_qᵀλ̂|) and eq13 (min |H u − (M q̈ + c + φ_qᵀλ)|) with the limit of the input they use
    most moved 5 % inside what it asks (on this crane they leave the winches at 0: the pseudo-inverse's
    answer, docs/model.md): the input is the same fit within the limits, scipy's bounded least squares
    (lsq_linear) of the step's own λ̂, q̈ and λ, to 1e-7 of u."""
    from scipy.optimize import lsq_linear

    spec, model, path, _ = crane
    gains = replace(Gains.from_spec(spec), recovery=recovery)
    lower, upper, preferred = spec.input_limits()
    for q, qd, t in states[:2]:
        free = make_controller(method, model, path, gains).compute(q, qd, t).copy()
        i = int(np.argmax(np.abs(free)))
        low, high = np.array(lower, dtype=float), np.array(upper, dtype=float)
        side = 1 if free[i] > 0 else -1
        (high if side > 0 else low)[i] = 0.95 * free[i]
        controller = make_controller(method, model, path, gains, limits=(low, high, preferred))
        u = controller.compute(q, qd, t).copy()
        lam, lam_hat = (np.array(a, copy=True) for a in controller.multipliers)
        T = terms(model, path, q, qd, t)
        H = T["input_matrix"]
        if recovery == "eq12":
            target = -(T["sigma_q"].T @ lam_hat)
        else:
            target = T["mass_matrix"] @ controller.qdd + T["bias_forces"] + T["phi_q"].T @ lam
        best = lsq_linear(H, target, bounds=(low, high), tol=1e-14, method="bvls", max_iter=1000).x
        assert u[i] == pytest.approx(0.95 * free[i], abs=1e-9) and controller.limit_state[i] == side
        np.testing.assert_allclose(u, best, rtol=0, atol=1e-7 * np.abs(best).max())
        assert np.abs(u - free).max() > 0.01 * np.abs(free).max()  # the limit changed the input


def test_the_recoveries_refuse_what_they_cannot_do_and_say_why():
    """An unknown recovery names the choices; eq15 and κ, square maps, refuse a system with more servo-constraints
    than inputs and name the recoveries that can; dependent actuators make eq12's HᵀH singular, said in words."""
    mass = np.diag([2.0, 2.0, 2.0, 1.0])
    with pytest.raises(RecoveryError, match="^" + re.escape(f"unknown input recovery 'eq14': choose one of "
                                                            f"{', '.join(RECOVERIES)}") + "$"):
        InputRecovery("eq14", mass, 3, 3, 0.5)
    assert ", ".join(RECOVERIES) == "projected, kinetic, eq12, eq13, eq15, kappa"
    for kind in ("eq15", "kappa"):
        with pytest.raises(RecoveryError, match="^" + re.escape(f"recovery '{kind}' needs as many servo-constraints "
                                                                "as inputs (found 3 for 2): use 'projected' or "
                                                                "'eq12'") + "$"):
            InputRecovery(kind, mass, 3, 2, 0.5)
        InputRecovery(kind, mass, 2, 2, 0.5)  # square: accepted
    dependent = np.array([[1.0, 2.0], [0.0, 0.0], [1.0, 2.0], [0.0, 0.0]])  # the second actuator is twice the first
    terms = {"input_matrix": dependent, "sigma_q": np.ones((2, 4))}
    with pytest.raises(RecoveryError, match="^" + re.escape("HᵀH is singular: the actuators' generalized forces "
                                                            "are linearly dependent") + "$"):
        InputRecovery("eq12", mass, 2, 2, 0.5).recover(terms, np.ones(2), np.zeros(4), np.zeros(0))
