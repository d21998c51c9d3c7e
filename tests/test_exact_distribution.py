"""Issue 18, item 5: with redundant inputs, limits and `preferred` do not cost tracking.

The penalty methods' distribution is lexicographic in the servo-constraint accelerations
(acroboter.control.distribution.BoundedInputs.solve_task), as MLM's is. Oracles, none sharing code with the
distribution: the same crane without limits and with another `preferred` (closed loop); a dense
numpy solve of the constrained dynamics for σ̈(u), its null space by SVD; for random problems, the
fit restricted to the task directions by numpy least squares on an SVD basis, scipy's bounded least
squares (`lsq_linear`) for the existence of an exact fit within the limits, and the closest exact
fit to `preferred` in closed form (one internal direction: a clip of one scalar).
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import REPO, load_with_start
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from scipy.optimize import lsq_linear

from acroboter.control.controllers import Gains, make_controller, unbounded
from acroboter.control.distribution import BoundedInputs
from acroboter.sim.records import Scenario, summarize
from acroboter.sim.simulation import setup_default, simulate

FOUR_CABLE = REPO / "model_spec" / "acroboter_4cable.toml"
METHODS = ("penalty", "iterative-3", "mlm")
# Long enough to show the effect: with the weighted penalty distribution used before, preferred = 152.5 N
# gave 0.0448 mm against 0.0284 mm here (+58 %); over the whole 55 s path 0.0976 against 0.0617 mm.
DURATION = 6.0
WIDE = (5.0, 300.0)


@pytest.fixture(scope="module")
def four_cable():
    return load_with_start(FOUR_CABLE)


def wide_limits(spec):
    """Every winch at [5, 300] N with the default preferred value, the middle: 152.5 N."""
    lower, upper, preferred = spec.input_limits()
    winches = [i for i, a in enumerate(spec.actuators) if a.kind == "winch_tension"]
    lower[winches], upper[winches] = WIDE
    preferred[winches] = 0.5 * sum(WIDE)
    return lower, upper, preferred


@pytest.fixture(scope="module")
def runs(four_cable):
    """Each method on the four-winch crane with [5, 300] N (preferred 152.5 N) and without limits
    (preferred: the spec's 20 N)."""
    spec, model, path, start = four_cable
    plant = setup_default(model, path)
    out = {}
    for method in METHODS:
        for label, limits in (("wide", wide_limits(spec)), ("none", unbounded(spec))):
            controller = make_controller(method, model, path, Gains.from_spec(spec), limits=limits)
            result = simulate(model, path, controller, plant, start.q, DURATION, spec.controller.rate_hz,
                              spec.simulation.step)
            out[method, label] = (result, summarize(result, Scenario.from_model(model), model.layout))
    return out


@pytest.mark.parametrize("method", METHODS)
def test_wide_limits_track_as_no_limits(four_cable, runs, method):
    """Acceptance: within 1 % of the same crane without limits (seen: equal to 1e-8 relative)."""
    spec, model, _, _ = four_cable
    (wide, s_wide), (free, s_free) = runs[method, "wide"], runs[method, "none"]
    assert wide.diverged_at is None and free.diverged_at is None
    for key in ("max_position_error_mm", "rms_position_error_mm"):
        assert s_wide[key] == pytest.approx(s_free[key], rel=0.01), key
    winches = Scenario.from_model(model).winch_inputs
    tensions = wide.u[:, winches]
    # the internal force stays where the task leaves it (20.0..20.1 N here): not pulled to 152.5 N, not
    # driven to a limit
    assert 19.0 < tensions.min() and tensions.max() < 21.5, (tensions.min(), tensions.max())


def servo_accelerations(model, path, q, qd, t, u):
    """σ̈ for input u at (q, q̇, t): the constrained dynamics [M φ_qᵀ; φ_q 0][q̈; λ] = [H u − c; −γ], dense."""
    terms = model.evaluate("model_terms", q, qd, *path.signal_arrays(t))
    m = terms["phi_q"].shape[0]
    kkt = np.block([[terms["mass_matrix"], terms["phi_q"].T], [terms["phi_q"], np.zeros((m, m))]])
    rhs = np.concatenate([terms["input_matrix"] @ u - terms["bias_forces"], -terms["gamma"]])
    qdd = np.linalg.lstsq(kkt, rhs, rcond=None)[0][: terms["mass_matrix"].shape[0]]
    return terms["sigma_q"] @ qdd + terms["gamma_s"]


@pytest.mark.parametrize("method", ["penalty", "iterative-3"])
def test_preferred_moves_only_the_internal_force(four_cable, runs, method):
    """At states of the run: the inputs with [5, 300] N / preferred 152.5 N and without limits / preferred
    20 N cause the same servo accelerations, and differ only along the null space of u -> σ̈, where each
    sits at its own preferred value."""
    spec, model, path, _ = four_cable
    result, _ = runs[method, "wide"]
    gains = Gains.from_spec(spec)
    lw, up, pref_wide = wide_limits(spec)
    pref_free = unbounded(spec)[2]
    wide = make_controller(method, model, path, gains, limits=(lw, up, pref_wide))
    free = make_controller(method, model, path, gains, limits=unbounded(spec))
    l = model.layout.l
    for k in np.linspace(50, len(result.t) - 1, 5).round().astype(int):
        q, qd, t = result.q[k], result.qd[k], result.t[k]
        u_wide, u_free = wide.compute(q, qd, t).copy(), free.compute(q, qd, t).copy()
        assert not wide.limit_state.any()
        base = servo_accelerations(model, path, q, qd, t, np.zeros(l))
        servo_map = np.column_stack([servo_accelerations(model, path, q, qd, t, e) - base for e in np.eye(l)])
        _, singular, vt = np.linalg.svd(servo_map)
        assert singular[-1] > 1e-3 * singular[0]  # full row rank: exactly one internal direction
        internal = vt[-1]
        scale = np.abs(servo_map @ u_free).max()
        np.testing.assert_allclose(servo_map @ u_wide, servo_map @ u_free, rtol=0, atol=1e-8 * scale)
        # each input's internal force is its preferred value's (the cables' pattern −1, 1, −1, 1)
        assert abs(internal @ (u_wide - pref_wide)) < 1e-6
        assert abs(internal @ (u_free - pref_free)) < 1e-6
        assert np.abs(internal[:4]).min() > 0.49


# --- random problems -------------------------------------------------------------------------------------


def task_fit(G, g, E):
    """The fit's input in the task directions, argmin ½uᵀGu + gᵀu over u in range(Eᵀ): numpy lstsq on an
    orthonormal basis of range(Eᵀ) from an SVD (the code under test uses Cholesky of E G Eᵀ)."""
    k = E.shape[0]
    basis = np.linalg.svd(E)[2][:k].T
    a = np.linalg.lstsq(basis.T @ G @ basis, -(basis.T @ g), rcond=None)[0]
    return basis @ a


def random_problem(seed: int, l: int, k: int, near_free: bool):
    """G PSD with, if near_free, one direction nearly free (1e-9 of the others) close to null(E), as the
    four-cable crane's fit; g, E (k × l, full row rank) and preferred values at random."""
    rng = np.random.default_rng(seed)
    E = rng.standard_normal((k, l))
    a = rng.standard_normal((l + 3, l))
    if near_free:
        null = np.linalg.svd(E)[2][-1]
        direction = null + 1e-3 * rng.standard_normal(l)
        direction /= np.linalg.norm(direction)
        a -= np.outer(a @ direction, direction) * (1 - 1e-5)  # the fit barely sees `direction`
    G = a.T @ a
    g = 10 * rng.standard_normal(l)
    preferred = rng.uniform(-20, 20, l)
    return G, g, E, preferred, rng


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**32 - 1), l=st.integers(3, 8), extra=st.integers(1, 2), near_free=st.booleans())
def test_unbounded_task_fit_is_exact_and_internal_forces_at_preferred(seed, l, extra, near_free):
    k = l - extra
    G, g, E, preferred, _ = random_problem(seed, l, k, near_free)
    u_task = task_fit(G, g, E)
    dist = BoundedInputs(np.full(l, -np.inf), np.full(l, np.inf), preferred)
    u = dist.solve_task(G, g, E)
    size = max(1.0, np.abs(E @ u_task).max())
    np.testing.assert_allclose(E @ u, E @ u_task, rtol=0, atol=1e-9 * size)  # the task's part of the fit, exactly
    null = np.linalg.svd(E)[2][k:]
    np.testing.assert_allclose(null @ u, null @ preferred, rtol=0, atol=1e-9 * max(1.0, np.abs(u).max()))
    # independent of preferred in the task: another preferred moves u only in null(E)
    other = BoundedInputs(np.full(l, -np.inf), np.full(l, np.inf), preferred + 100.0).solve_task(G, g, E)
    np.testing.assert_allclose(E @ other, E @ u, rtol=0, atol=1e-9 * size)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**32 - 1), l=st.integers(3, 8), near_free=st.booleans(), inside=st.booleans())
@example(seed=754, l=6, near_free=False, inside=False)  # the oracle's BVLS ran out of iterations (fixed above)
def test_limits_cost_no_tracking_while_an_exact_fit_is_within_them(seed, l, near_free, inside):
    """One internal direction. Limits around an exact fit: the result is exact (E u = e_F), within the
    limits, and the exact fit within them closest to preferred (closed form); `inside`: limits that hold the
    unbounded solution too, which is then returned as it is."""
    k = l - 1
    G, g, E, preferred, rng = random_problem(seed, l, k, near_free)
    u_task = task_fit(G, g, E)
    target = E @ u_task
    internal = np.linalg.svd(E)[2][-1]
    free = u_task + internal * (internal @ preferred)  # the unbounded answer: E u = e_F, internal at preferred
    anchor = free if inside else u_task + internal * (internal @ preferred + rng.uniform(-30, 30))
    lower = anchor - rng.uniform(0.5, 5.0, l)
    upper = anchor + rng.uniform(0.5, 5.0, l)
    dist = BoundedInputs(lower, upper, preferred)
    u = dist.solve_task(G, g, E)
    # oracle 1: an exact fit within the limits exists (scipy's bounded least squares reaches E u = e_F)
    # (BVLS's default max_iter, the number of inputs, stopped it short on seed 754: kept as an example below)
    exists = lsq_linear(E, target, bounds=(lower, upper), method="bvls", tol=1e-14, max_iter=1000)
    assert exists.success, exists.message
    size = max(1.0, np.abs(target).max())
    assert np.abs(E @ exists.x - target).max() < 1e-8 * size
    assert np.all(u >= lower) and np.all(u <= upper)
    np.testing.assert_allclose(E @ u, target, rtol=0, atol=1e-6 * size)
    # oracle 2: among the exact fits u_task + c·n within the limits, the one with c closest to nᵀu_pref
    lo, hi = -np.inf, np.inf
    for i in range(l):
        if abs(internal[i]) > 1e-12:
            a, b = sorted(((lower[i] - u_task[i]) / internal[i], (upper[i] - u_task[i]) / internal[i]))
            lo, hi = max(lo, a), min(hi, b)
    best = u_task + internal * np.clip(internal @ preferred, lo, hi)
    np.testing.assert_allclose(u, best, rtol=0, atol=1e-4 * max(1.0, np.abs(best).max()))
    if inside:
        assert not dist.bounded_step and not dist.limit_state.any()
        np.testing.assert_allclose(u, free, rtol=0, atol=1e-9 * max(1.0, np.abs(free).max()))


def test_solve_task_refuses_a_weighted_distribution():
    dist = BoundedInputs(np.zeros(3), np.ones(3), np.zeros(3), weight=1e-5)
    with pytest.raises(ValueError, match="lexicographic"):
        dist.solve_task(np.eye(3), np.zeros(3), np.ones((2, 3)))


@pytest.mark.parametrize("bounded", [False, True])
def test_the_task_fit_does_not_depend_on_the_fits_units(bounded):
    """G and g scaled together (the fit in other units): the same u, bounded or not (the internal forces'
    weight in the QP is relative to EᵀE, and the QP is solved in units where its mean eigenvalue is 1)."""
    l, k = 6, 4
    G, g, E, preferred, rng = random_problem(7, l, k, near_free=True)
    free = BoundedInputs(np.full(l, -np.inf), np.full(l, np.inf), preferred).solve_task(G, g, E).copy()
    lower = free - rng.uniform(-1.0, 0.5, l) if bounded else np.full(l, -np.inf)
    upper = lower + 3.0 if bounded else np.full(l, np.inf)
    ref = BoundedInputs(lower, upper, preferred).solve_task(G, g, E).copy()
    for s in (1e-6, 1e-3, 1e3, 1e6):
        for e_scale in (1e-3, 1.0, 1e3):  # E in other units too (servo accelerations per N or per kN)
            dist = BoundedInputs(lower, upper, preferred)
            u = dist.solve_task(s * G, s * g, e_scale * E)
            np.testing.assert_allclose(u, ref, rtol=0, atol=1e-6 * np.abs(ref).max(), err_msg=f"{s}, {e_scale}")
            assert dist.bounded_step == bounded
