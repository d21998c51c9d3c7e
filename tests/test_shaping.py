"""Input-shaped timings (acroboter.planning.shaping), each against an oracle of its own:

- the shapers against a damped oscillator integrated by scipy (the residual vibration after the last impulse), and
  against Singer and Seering's residual-vibration formula written here;
- the swing modes against the ideal motion integrated in time (the period of the free swing, by zero crossings);
- the shaped edge's σ(t) against the convolution written here, and its end exactly at the corner at rest;
- a shaped plan's written trajectory against that convolution, its corners at rest, its flights.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.integrate import solve_ivp

from acroboter.planning import shaping

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")


def residual(times, amps, omega, zeta):
    """Singer and Seering's residual vibration of a damped oscillator after an impulse train (relative to one
    impulse): e^(−ζω t_N) |Σ A_i e^(ζω t_i) e^(i ω_d t_i)|."""
    wd = omega * math.sqrt(1 - zeta**2)
    s = sum(a * math.exp(zeta * omega * t) * complex(math.cos(wd * t), math.sin(wd * t))
            for t, a in zip(times, amps, strict=True))
    return math.exp(-zeta * omega * times[-1]) * abs(s)


@settings(max_examples=40, deadline=None)
@given(period=st.floats(0.2, 10.0), zeta=st.floats(0.0, 0.29))
def test_shapers_cancel_their_mode(period, zeta):
    omega = 2 * math.pi / period / math.sqrt(1 - zeta**2)
    mode = shaping.Mode(omega, zeta)
    assert mode.period == pytest.approx(period)
    for kind in ("zv", "zvd"):
        times, amps = shaping.shaper(kind, [mode])
        assert amps.sum() == pytest.approx(1.0) and (amps > 0).all()
        assert residual(times, amps, omega, zeta) < 1e-9
    # ZVD is robust: 10 % off the mode it leaves far less than ZV
    zv, zvd = shaping.shaper("zv", [mode]), shaping.shaper("zvd", [mode])
    for off in (0.9, 1.1):
        assert residual(*zvd, off * omega, zeta) < 0.2 * residual(*zv, off * omega, zeta)


def test_a_shaped_step_leaves_two_modes_at_rest():
    """Two modes, their shapers convolved: an oscillator of each, driven by the shaped step and integrated by scipy,
    is at rest at the step's value after the last impulse (and is not without the shaper)."""
    modes = [shaping.Mode(2.1, 0.05), shaping.Mode(7.3, 0.01)]
    times, amps = shaping.shaper("zv", modes)
    assert times.size == 4
    end = times[-1]
    for mode in modes:
        def step(t, y, shaped, mode=mode):
            r = sum(a for ti, a in zip(times, amps, strict=True) if t >= ti) if shaped else 1.0
            return [y[1], mode.omega**2 * (r - y[0]) - 2 * mode.damping * mode.omega * y[1]]

        for shaped, bound in ((True, 1e-6), (False, None)):
            sol = solve_ivp(step, (0, end + 3.0), [0.0, 0.0], args=(shaped,), rtol=1e-11, atol=1e-13,
                            max_step=0.01, dense_output=True)
            after = np.linspace(end + 1e-6, end + 3.0, 200)
            swing = np.abs(sol.sol(after)[0] - 1.0).max()
            if bound is not None:
                assert swing < bound
            else:
                assert swing > 0.05


@pytest.mark.parametrize("kind", ["zv", "zvd", "unshaped"])
def test_a_shaped_edge_is_the_convolution_and_ends_at_rest(kind):
    """σ̈ linear between the nodes, integrated here exactly, follows the shaped quintic written here and ends at
    Δσ = 1 with σ̇ = 0."""
    mode = shaping.Mode(4.65, 0.007)
    times, amps = shaping.shaper(kind, [mode])
    own, factor = 3.2, 0.6
    nodes, duration = shaping.shaped_edge(own, factor, times, amps)
    h = duration / (nodes.size - 1)
    s, v = [0.0], [0.0]
    for a0, a1 in zip(nodes[:-1], nodes[1:], strict=True):
        s.append(s[-1] + v[-1] * h + h * h * (2 * a0 + a1) / 6)
        v.append(v[-1] + h * (a0 + a1) / 2)
    assert s[-1] == pytest.approx(1.0, abs=1e-12) and v[-1] == pytest.approx(0.0, abs=1e-12)
    assert min(v) > -1e-9
    t = np.linspace(0.0, duration, nodes.size)
    span = factor * own

    def quintic(x):
        x = np.clip(x, 0.0, 1.0)
        return x**3 * (10 - 15 * x + 6 * x * x)

    expected = sum(a * quintic((t - ti) / span) for ti, a in zip(times, amps, strict=True))
    assert np.abs(np.array(s) - expected).max() < 2e-4
    assert duration == pytest.approx(span + times[-1])


@pytest.fixture(scope="module")
def default_dynamics():
    import acroboter
    from acroboter.planning.geometry import PathGeometry
    from acroboter.planning.ideal_motion import IdealDynamics

    crane = acroboter.Crane.from_toml(acroboter.example_spec("acroboter"))
    q0 = crane.equilibrium().q
    return IdealDynamics(crane.spec, q0), PathGeometry(crane.path), q0


def test_the_swing_modes_are_the_free_swing(default_dynamics):
    """Each lightly damped mode of the linearisation, excited alone by a small push along its eigenvector, swings
    in the ideal motion integrated in time (RK4, 5 ms steps, nonlinear) with the mode's period, within 0.5 %."""
    import casadi as ca

    from acroboter.planning.retiming import Retiming

    dyn, geo, q0 = default_dynamics
    modes = shaping.swing_modes(dyn, geo, q0, 0.0)
    assert len(modes) >= 2 and all(m.damping < shaping.SWING_DAMPING for m in modes)
    assert [m.period for m in modes] == sorted([m.period for m in modes], reverse=True)
    n = dyn.layout.n
    mq, mqd = ca.MX.sym("q", n), ca.MX.sym("qd", n)
    zero = ca.DM.zeros(dyn.layout.n_signals)
    jac = ca.Function("j", [mq, mqd], [ca.jacobian(dyn.function(mq, mqd, geo.function(0.0)[0], zero, zero)[0],
                                                   ca.vertcat(mq, mqd))])
    a = np.block([[np.zeros((n, n)), np.eye(n)], [np.asarray(jac(q0, np.zeros(n)))]])
    values, vectors = np.linalg.eig(a)
    problem = Retiming(dyn, geo, q0, np.full(dyn.layout.l, -np.inf), np.full(dyn.layout.l, np.inf))
    for mode in modes:
        k = int(np.argmin(np.abs(values - complex(-mode.damping * mode.omega,
                                                  mode.omega * math.sqrt(1 - mode.damping**2)))))
        push = np.real(vectors[:, k])
        push *= 1e-4 / np.abs(push).max()
        h, steps = 0.005, int(6 * mode.period / 0.005)
        x0 = np.concatenate([q0 + push[:n], push[n:], [0.0, 0.0]])
        states, _ = problem.run_grid(x0, np.zeros(steps), h, 1)
        big = int(np.argmax(np.abs(push[:n])))
        signal = states[:, big] - q0[big]
        signal = signal - signal[-int(mode.period / h):].mean()
        crossings = [i + signal[i] / (signal[i] - signal[i + 1]) for i in range(steps) if
                     signal[i] > 0 >= signal[i + 1]]
        measured = h * (crossings[-1] - crossings[0]) / (len(crossings) - 1)
        assert measured == pytest.approx(mode.period, rel=5e-3)


def _two_edges(tmp_path):
    import acroboter
    from acroboter.model.spec_edits import with_path, with_winch_limits

    text = with_winch_limits(acroboter.example_spec("acroboter").read_text(), 30.0, 5.0)
    path = tmp_path / "two.toml"
    path.write_text(with_path(text, [[0.0, 0.0, 0.0], [0.25, 0.0, 0.0], [0.25, 0.25, 0.0]], yaw_deg=0.0))
    return path


def test_a_zv_plan_flies_its_convolution_and_stops_at_rest(tmp_path):
    """The default crane, two 0.25 m edges at winch limits [5, 30] N, margin 5 %, ZV: the written trajectory is each
    edge's own quintic convolved with the shaper at the plan's factors (written here); every corner within REST_TOL
    of rest; MLM and Penalty fly it with the limits applied, never saturated, within a millimetre; the planned
    inputs keep the margin on the 1 ms grid. Unshaped edges at the same factors leave a corner swinging more."""
    import acroboter
    from acroboter.planning.retiming import REST_TOL

    crane = acroboter.Crane.from_toml(_two_edges(tmp_path))
    plan = crane.plan(margin=0.05, shaper="zv", certify=["mlm", "penalty"])
    assert plan.status == "planned" and plan.corners == "shaped"
    assert plan.margin_achieved >= 0.05 - 1e-6
    shaped = plan.shaping["edges"]
    own = crane.path.edge_duration
    traj = plan.trajectory
    start, t0 = np.asarray(traj.position[0, :3]), 0.0
    corners = [start, start + [0.25, 0, 0], start + [0.25, 0.25, 0]]
    for j, edge in enumerate(shaped):
        times, amps = np.array(edge["impulse_times_s"]), np.array(edge["impulse_amplitudes"])
        span = edge["factor"] * own[j]
        duration = span + times[-1]
        inside = (traj.times >= t0) & (traj.times <= t0 + duration)
        x = np.clip((traj.times[inside, None] - t0 - times[None, :]) / span, 0.0, 1.0)
        fraction = (amps[None, :] * x**3 * (10 - 15 * x + 6 * x * x)).sum(axis=1)
        expected = corners[j] + fraction[:, None] * (corners[j + 1] - corners[j])
        assert np.abs(traj.position[inside, :3] - expected).max() < 2e-4  # σ̈ linear between nodes: 0.1 % of the edge
        t0 += duration
    assert t0 == pytest.approx(plan.duration)
    for corner in plan.corner_swing:
        assert corner["displacement_mm"] <= 1e3 * REST_TOL and corner["speed_mm_s"] <= 1e3 * REST_TOL
    for method, flight in plan.certificate.flights.items():
        assert flight["saturated_s"] == 0 and flight["max_position_error_mm"] < 1.0, method
    # what the shaper buys: the same factors without it leave more swing at the first corner
    from acroboter.planning.geometry import PathGeometry
    from acroboter.planning.ideal_motion import IdealDynamics
    from acroboter.planning.limits import tightened

    lower, upper, _ = crane.spec.input_limits()
    low, high = tightened(lower, upper, 0.05)
    q0 = crane.equilibrium().q
    dyn, geo = IdealDynamics(crane.spec, q0), PathGeometry(crane.path)
    swings = {}
    for kind in ("zv", "unshaped"):
        problem = shaping.ShapedRetiming(dyn, geo, q0, low, high, shaper_kind=kind)
        states, _, _, _ = problem.fly_edge(np.concatenate([problem.x0, [0.0, 0.0]]), 0, shaped[0]["factor"])
        swings[kind] = shaping.corner_swing(problem, np.zeros(1), states[-1:], [0])[0]
    assert swings["zv"]["speed_mm_s"] < 0.2 * swings["unshaped"]["speed_mm_s"]


def test_plan_shaper_cli(tmp_path):
    """`acroboter plan --shaper zv` writes the shaping and the corners' swing into summary.json; a shaper with a
    tolerance, a trajectory file, swing corners or a window is refused before any work (exit 2, the option named)."""
    from acroboter.cli.plan import main

    spec = _two_edges(tmp_path)
    out = tmp_path / "plan"
    assert main(["--spec", str(spec), "--shaper", "zv", "--out", str(out), "--no-plots", "-q"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["corners"] == "shaped" and summary["shaping"]["kind"] == "zv"
    for edge in summary["shaping"]["edges"]:
        assert len(edge["impulse_times_s"]) == 2 ** len(edge["modes"]) and edge["factor"] > 0
    assert [c["corner"] for c in summary["corner_swing"]] == [1, 2]
    for extra in (["--tolerance", "1mm"], ["--trajectory", str(tmp_path / "x.csv")], ["--corners", "swing"],
                  ["--window", "2"]):
        with pytest.raises(SystemExit) as exit_:
            main(["--spec", str(spec), "--shaper", "zv", "--out", str(out), *extra])
        assert exit_.value.code == 2


def test_a_failed_resolve_leaves_the_kept_plans_description(tmp_path):
    """A shaped solve that fails part-way (a re-solve with the bounds moved in) leaves the factors and the grid of
    the solve before it: the plan kept is the one its summary and its corners describe (a review found them
    overwritten with the failed attempt's first edges)."""
    import acroboter
    from acroboter.planning.geometry import PathGeometry
    from acroboter.planning.ideal_motion import IdealDynamics, PlanningError
    from acroboter.planning.limits import tightened

    crane = acroboter.Crane.from_toml(_two_edges(tmp_path))
    lower, upper, _ = crane.spec.input_limits()
    low, high = tightened(lower, upper, 0.05)
    q0 = crane.equilibrium().q
    problem = shaping.ShapedRetiming(IdealDynamics(crane.spec, q0), PathGeometry(crane.path), q0, low, high,
                                     shaper_kind="zv")
    solution = problem.solve(0, guess_factor=1.0)
    factors, counts = list(problem.factors), list(problem.counts)
    assert len(factors) == 2 and sum(counts) == solution.tau_dd.size
    first = problem.edge_factor

    def fails_on_the_second(x, j):
        if j == 1:
            raise PlanningError("no timing with the bounds moved in")
        return 1.3 * first(x, j)

    problem.edge_factor = fails_on_the_second
    with pytest.raises(PlanningError):
        problem.solve(0, guess_factor=1.0)
    assert problem.factors == factors and problem.phase_counts(0) == counts
    assert [e["factor"] for e in problem.description()["edges"]] == factors
