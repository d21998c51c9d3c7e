"""Saturation as underactuation (issue 22, item 3; docs/saturation.md), against oracles of its own:

- the reduced step alone (acroboter.control.underactuation), property-based (hypothesis) on random servo maps:
  every input within its limits, held ones exactly on them, never NaN; the components kept meet the task
  exactly, and *which* components are released is what a counting oracle says for generic maps (the free
  inputs' degrees of freedom handed out by priority), and what a rank oracle (scipy's null space of the more
  important rows, numpy's rank) says on the crane's own map;
- the hysteresis: an input that dithers across its limit does not switch the task back and forth;
- the closed loop: with limits never reached both strategies give the same runs bit for bit (all three methods,
  the three- and the four-cable crane); with limits in the way every input stays within them at every control
  step, finite, and on the kept components MLM's input realises σ̈ = −2k_D σ̇ − k_P² σ, checked through a dense
  KKT solve of the model's own terms (tests/test_control_law.py's oracle), not through the controller's terms;
- bad input: a priority that does not fit the task, an unknown strategy: a message naming the field, exit 2.
"""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
import scipy.linalg
from conftest import REPO, load_with_start, raw_spec, write_lift_spec
from hypothesis import given, settings
from hypothesis import strategies as st
from test_control_law import constrained_acceleration, servo_law, terms

from acroboter.control.controllers import Gains, make_controller
from acroboter.control.underactuation import Underactuation
from acroboter.model.settings import UNDERACTUATION_RANK_TOLERANCE
from acroboter.model.spec import SpecError, parse_spec
from acroboter.model.spec_checks import task_components
from acroboter.model.spec_edits import with_winch_limits
from acroboter.sim.simulation import setup_default, simulate

COMPONENTS = {"horizontal": [0, 1], "height": [2], "yaw": [3], "level": [4, 5]}
PRIORITY = ("horizontal", "level", "height", "yaw")


def counting_oracle(priority, sizes: dict, free: int) -> tuple[str, ...]:
    """Generic maps: each component takes as many of the free inputs' degrees of freedom as it has rows, by
    priority; one that finds fewer left is released (and takes what is left)."""
    left, released = free, []
    for name in priority:
        if sizes[name] <= left:
            left -= sizes[name]
        else:
            released.append(name)
            left = 0
    return tuple(released)


def rank_oracle(E: np.ndarray, free: np.ndarray, components: dict, priority, closest: list | None = None
                ) -> tuple[str, ...]:
    """A component is kept iff, with every more important row asked of the free inputs, they still move it in as
    many directions as all inputs do (at UNDERACTUATION_RANK_TOLERANCE of its size): scipy's null space of the
    stacked rows above it (those of the components they move at all), numpy's rank. `closest` gets each singular
    value it judged, over the tolerance."""
    released, above = [], []
    for name in priority:
        rows = components[name]
        size = np.linalg.norm(E[rows], 2)
        reach = np.linalg.matrix_rank(E[rows], tol=1e-9 * size)
        left = scipy.linalg.null_space(E[np.ix_(above, free)]) if above else np.eye(int(free.sum()))
        moved = 0
        if left.size:
            reduced = E[np.ix_(rows, free)] @ left
            moved = np.linalg.matrix_rank(reduced, tol=UNDERACTUATION_RANK_TOLERANCE * size)
            if closest is not None:
                closest += list(np.linalg.svd(reduced, compute_uv=False) / (UNDERACTUATION_RANK_TOLERANCE * size))
        if moved < reach:
            released.append(name)
        if moved:  # a component the free inputs do not move at all asks nothing of them
            above += list(rows)
    return tuple(released)


@st.composite
def reduced_problems(draw):
    l = draw(st.integers(6, 8))
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    E = rng.normal(size=(6, l))
    lower = -rng.uniform(0.5, 3.0, l)
    upper = rng.uniform(0.5, 3.0, l)
    u_star = rng.normal(scale=draw(st.floats(0.5, 6.0)), size=l)
    priority = tuple(draw(st.permutations(PRIORITY)))
    return E, lower, upper, u_star, priority


@settings(max_examples=300, deadline=None)
@given(reduced_problems())
def test_reduced_step_holds_the_limits_and_releases_by_priority(problem):
    E, lower, upper, u_star, priority = problem
    under = Underactuation(lower, upper, np.zeros_like(lower), COMPONENTS, priority, dwell=0.1, margin=0.0)
    asked = E @ u_star
    if under.full_task(u_star, 0.0):
        assert ((u_star >= lower) & (u_star <= upper)).all()
        return
    u = under.solve(E, asked)
    assert np.isfinite(u).all()
    assert ((u >= lower) & (u <= upper)).all(), "an input beyond its limits"
    held = under.held != 0
    np.testing.assert_array_equal(u[under.held > 0], upper[under.held > 0])
    np.testing.assert_array_equal(u[under.held < 0], lower[under.held < 0])
    assert held.any()
    # what the priority says is released, nothing else
    closest: list = []
    by_rank = rank_oracle(E, ~held, COMPONENTS, priority, closest)
    ratios = np.array(closest)
    if not ((ratios > 0.1) & (ratios < 10)).any():  # no singular value within a factor 10 of the tolerance
        assert under.released == by_rank
    if (ratios > 10).all():  # a generic map (every singular value well above it): the count holds too
        assert under.released == counting_oracle(priority, {k: len(v) for k, v in COMPONENTS.items()},
                                                  int((~held).sum()))
    kept = [r for name in priority if name not in under.released for r in COMPONENTS[name]]
    np.testing.assert_allclose(E[kept] @ u, asked[kept], rtol=0, atol=1e-9 * (1 + np.abs(asked).max()))


def test_hysteresis_does_not_chatter():
    """An input dithering across its limit every step: one switch into the reduced task, none back until the full
    task's input has stayed inside (by the margin) for the dwell."""
    under = Underactuation(np.array([0.0]), np.array([10.0]), np.array([5.0]), {"height": [0]}, ("height",),
                           dwell=0.1, margin=0.01)
    period, t = 0.02, 0.0
    for k in range(200):
        full = under.full_task(np.array([9.95 if k % 2 else 10.05]), t)
        assert not full
        t += period
    assert under.switches == 1
    # inside the limit but not by the margin (9.95 > 10 − 1 %): still reduced
    for _ in range(20):
        assert not under.full_task(np.array([9.95]), t)
        t += period
    # inside by the margin: the full task after the dwell (0.1 s = 5 periods after the first inside step)
    decisions = []
    for _ in range(8):
        decisions.append(under.full_task(np.array([9.5]), t))
        t += period
    assert decisions == [False] * 5 + [True] * 3
    assert under.switches == 2


@pytest.fixture(scope="module")
def crane():
    return load_with_start(REPO / "model_spec" / "acroboter.toml")


def test_crane_map_releases_what_the_rank_oracle_says(crane):
    """The crane's own E at its start: one winch held, then all three, every priority."""
    spec, model, path, start = crane
    controller = make_controller("mlm", model, path, Gains.from_spec(spec))
    controller.compute(start.q, np.zeros(model.layout.n), 1.0)
    controller._servo_fn.call()
    E = controller._servo_fn.outputs["servo_map"].copy()
    components = task_components(spec)
    assert components == COMPONENTS
    lower, upper = np.zeros(6), np.array([26.9, 26.9, 26.9, np.inf, np.inf, np.inf])
    lower[3:] = -np.inf
    import itertools

    seen = set()
    for priority in itertools.permutations(PRIORITY):
        for held in ([0], [0, 1, 2]):
            under = Underactuation(lower, upper, np.full(6, 13.45), components, priority, 0.1, 0.001)
            under.active, under.held[held] = True, 1
            u = under.solve(E, E @ np.array([27.2, 27.0, 27.0, 0.0, 0.0, 0.0]))
            free = under.held == 0
            assert under.released == rank_oracle(E, free, components, priority)
            assert np.isfinite(u).all() and (u <= upper).all() and (u >= lower).all()
            seen.add(under.released)
    # the default priority with one winch held: the height goes (the yaw torque cannot lift), yaw stays
    assert ("height",) in seen and ("level", "height") in seen


def _run(spec, model, path, start, method, saturation, duration, log=None):
    controller = make_controller(method, model, path, Gains.from_spec(spec, saturation=saturation))
    if log is not None and controller.underactuation is not None:
        solve = controller.underactuation.solve

        def logged(servo_map, asked):
            u = solve(servo_map, asked)
            log.append((controller._t_now, controller.underactuation.released, controller.limits.unbounded.copy(),
                        u.copy()))
            return u

        controller.underactuation.solve = logged
    return simulate(model, path, controller, setup_default(model, path), start.q, duration,
                    spec.controller.rate_hz, spec.simulation.step, allow_divergence=True)


@pytest.mark.parametrize("name,methods", [("acroboter", ("mlm", "penalty", "iterative-3")),
                                          ("acroboter_4cable", ("mlm", "penalty"))])
def test_limits_never_reached_bit_for_bit(name, methods):
    spec, model, path, start = load_with_start(REPO / "model_spec" / f"{name}.toml")
    for method in methods:
        qp = _run(spec, model, path, start, method, "qp", 6.0)
        under = _run(spec, model, path, start, method, "underactuation", 6.0)
        assert not qp.limit_state.any()
        for field in ("u", "q", "qd", "sigma"):
            np.testing.assert_array_equal(getattr(qp, field), getattr(under, field), err_msg=f"{method} {field}")


@pytest.fixture(scope="module")
def limited(tmp_path_factory):
    from acroboter.model.spec import load_spec

    text = with_winch_limits((REPO / "model_spec" / "acroboter.toml").read_text(), 26.9, 0.0)
    path = tmp_path_factory.mktemp("limited") / "limited.toml"
    path.write_text(text)
    spec = load_spec(path)
    from acroboter.runtime.cache import load_model
    from acroboter.sim.statics import desired_path, solve_equilibrium

    model = load_model(spec)
    desired = desired_path(model)
    return spec, model, desired, solve_equilibrium(model, desired)


@pytest.mark.parametrize("method", ["mlm", "penalty", "iterative-3"])
def test_saturated_run_keeps_limits_and_the_kept_servo_law(limited, method):
    """The default crane held to 26.9 N per winch from t = 24 s (the limits bind at 25.1 s) for 8 s."""
    spec, model, path, start = limited
    log = []
    r = _run(spec, model, path, start, method, "underactuation", 32.0, log)
    lower, upper, _ = spec.input_limits()
    assert np.isfinite(r.u).all() and np.isfinite(r.q).all()
    assert ((r.u >= lower) & (r.u <= upper)).all(), "an input beyond its limits"
    assert r.limit_state.any() and len(log) > 50
    gains = Gains.from_spec(spec)
    components = task_components(spec)
    checked = 0
    for t, released, u_star, u in log[:: max(1, len(log) // 12)]:
        k = int(round(t * spec.controller.rate_hz))
        assert abs(r.t[k] - t) < 1e-9
        np.testing.assert_array_equal(r.u[k], u)
        kept = [row for name, rows in components.items() if name not in released for row in rows]
        assert released and kept
        T = terms(model, path, r.q[k], r.qd[k], r.t[k])
        sigma_ddot = T["sigma_q"] @ constrained_acceleration(T, u, -T["gamma"]) + T["gamma_s"]
        if method == "mlm":  # the kept rows meet the tracking law
            law = servo_law(T, gains)
        else:  # the penalty methods: the kept rows get what their own full-task input would cause
            law = T["sigma_q"] @ constrained_acceleration(T, u_star, -T["gamma"]) + T["gamma_s"]
        scale = np.abs(sigma_ddot).max() + np.abs(law).max()
        np.testing.assert_allclose(sigma_ddot[kept], law[kept], rtol=0, atol=1e-8 * scale)
        # and the released ones do not (the test would pass with nothing released otherwise)
        miss = np.abs(sigma_ddot - law)
        assert miss[[i for i in range(len(law)) if i not in kept]].max() > 1e-6 * scale
        checked += 1
    assert checked >= 6


def test_bad_priority_and_strategy_are_refused():
    data = raw_spec("acroboter")
    data["controller"]["underactuation"] = {"priority": ["horizontal", "level", "height"]}
    with pytest.raises(SpecError, match=r"controller\.underactuation\.priority: .*no 'yaw'"):
        parse_spec(data)
    data["controller"]["underactuation"] = {"priority": ["horizontal", "level", "height", "yaw", "tilt"]}
    with pytest.raises(SpecError, match=r"controller\.underactuation\.priority"):
        parse_spec(data)
    data["controller"]["underactuation"] = {}
    data["controller"]["saturation"] = "clip"
    with pytest.raises(SpecError, match=r"controller\.saturation: expected one of 'qp' or 'underactuation'"):
        parse_spec(data)


def test_cli_saturation_option(tmp_path):
    bad = subprocess.run([sys.executable, "-m", "acroboter.run", "--saturation", "clip", "--out", str(tmp_path)],
                         capture_output=True, text=True)
    assert bad.returncode == 2 and "--saturation" in bad.stderr and "underactuation" in bad.stderr
    ok = subprocess.run([sys.executable, "-m", "acroboter.run", "--saturation", "underactuation", "--method", "mlm",
                         "--duration", "1", "--no-plots", "-q", "--out", str(tmp_path / "run")],
                        capture_output=True, text=True)
    assert ok.returncode == 0, ok.stderr


def test_api_saturation_override(crane):
    import acroboter

    c = acroboter.Crane.from_toml(acroboter.example_spec("acroboter"))
    with pytest.raises(ValueError, match="saturation: expected one of qp, underactuation"):
        c.simulate("mlm", duration=0.1, saturation="clip")
    r = c.simulate("mlm", duration=0.2, saturation="underactuation", warm_up=0)
    assert np.isfinite(r.u).all()


def test_export_refuses_underactuation(crane):
    """The exported step meets limits with the QP only: a spec asking underactuation is refused with the reason."""
    from acroboter.codegen.export_step import ExportError, build_step

    spec = crane[0]
    with pytest.raises(ExportError, match="bounded least squares only"):
        build_step(spec, "penalty", Gains.from_spec(spec, saturation="underactuation"))


def test_the_advice_for_a_time_optimal_plan_at_its_limits_holds(tmp_path):
    """docs/saturation.md's advice (issue 34 item 6): a time-optimal plan flown at its limits (margin 0) is flown
    closer by the QP than by underactuation, which holds a winch at its limit after the need has passed. Measured
    2026-12-06 on the default crane's 0.1 m lift, winches [24, 29] N, 8 intervals, MLM: 0.706 against 5.17 mm."""
    import acroboter
    from acroboter.planning.planner import PlanFailure

    crane = acroboter.Crane.from_toml(write_lift_spec(tmp_path))
    try:
        plan = crane.plan(margin=0.0, intervals=8, certify=False)
    except PlanFailure as err:  # the plan itself is what is flown; whether it is "the one asked for" is not at issue
        plan = err.plan
    worst = {}
    for strategy in ("qp", "underactuation"):
        result = crane.simulate("mlm", trajectory=plan.trajectory, saturation=strategy, duration=plan.duration + 1.0)
        assert result.saturated.any()  # the limits are met on the way: the strategies matter
        worst[strategy] = result.position_error_mm.max()
    assert 2.0 * worst["qp"] < worst["underactuation"], worst
