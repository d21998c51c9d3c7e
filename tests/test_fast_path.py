"""The Python controllers' fast path (acroboter.control.fast_path, issue 23 item 2) against the reference per-term path.

- closed loops with integral action: MLM's results agree to 1e-9 relative; the penalty methods' u to 1e-9 of its
  size, their summaries to 1e-7 (explained, and checked: their step is the more accurate one, against a 40-digit
  evaluation of the same control law);
- input limits that bind: those steps are the reference's (limit_state, saturation, u), the others fast;
- sensing (noise, delay): the estimator's prediction reads the fast step's q̈;
- the singular-system check: a redundant MLM system is still SingularSystemError, a nearly singular one goes to
  the reference, and the fast estimate of the reciprocal condition number is never below the exact one.
No test asserts on measured time.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from reference_laws import penalty_inputs_40_digits
from scipy.linalg import lapack

from acroboter.api.crane import Crane
from acroboter.control.controllers import SingularSystemError, make_controller
from acroboter.control.fast_path import FastController
from acroboter.sim.records import Scenario, summarize
from acroboter.sim.simulation import setup_default, simulate

REPO = Path(__file__).resolve().parent.parent
SPEC = REPO / "model_spec" / "acroboter.toml"
SECONDS = 6.0
KI = 18.375  # docs/integral_action.md: the tests' integrator pole


@pytest.fixture(scope="module")
def crane():
    return Crane.from_toml(SPEC)


def closed_loops(crane, method, seconds=SECONDS, limits=None, **gains):
    model, path, spec = crane.model, crane.path, crane.spec
    g = crane.gains(**gains)
    start = crane.equilibrium()
    out = {}
    for fast in (False, True):
        controller = make_controller(method, model, path, g, limits=limits, fast=fast)
        out[fast] = (controller, simulate(model, path, controller, setup_default(model, path), start.q, seconds,
                                          spec.controller.rate_hz, spec.simulation.step))
    return out


def rel(a, b):
    return float(np.abs(a - b).max() / max(np.abs(a).max(), 1e-300))


@pytest.mark.parametrize("method", ["mlm", "penalty", "iterative-3"])
def test_closed_loop_matches_reference(crane, method):
    runs = closed_loops(crane, method, ki=KI)
    (_, a), (fast, b) = runs[False], runs[True]
    assert isinstance(fast, FastController) and fast.reference_steps == 0 and fast.fast_steps == len(b.t)
    assert np.abs(fast.integral).max() > 1e-6  # the integral acts, and it is the reference's z
    scenario = Scenario.from_model(crane.model)
    sa, sb = summarize(a, scenario, crane.layout), summarize(b, scenario, crane.layout)
    keys = ("max_position_error_mm", "rms_position_error_mm", "max_tilt_deg", "min_winch_tension_N")
    if method == "mlm":  # the same Schur system, another QR: round-off
        assert rel(a.u, b.u) <= 1e-12 and rel(a.q, b.q) <= 1e-12
        for key in keys:
            assert abs(sa[key] - sb[key]) <= 1e-9 * abs(sa[key]), key
    else:  # the multiplier form's u, more accurate (test below): differences at the reference's round-off
        assert rel(a.u, b.u) <= 1e-9 and rel(a.q, b.q) <= 1e-9
        for key in keys:
            assert abs(sa[key] - sb[key]) <= 1e-7 * abs(sa[key]), key
    assert (a.limit_state == b.limit_state).all() and (a.saturated == b.saturated).all()


@pytest.mark.parametrize("method", ["penalty", "iterative-3"])
def test_penalty_difference_is_the_reference_round_off(crane, method):
    """Why the penalty methods differ beyond 1e-9 in some summaries: the fast step solves for the multipliers
    directly, the reference for q̈ with A = M + JᵀDJ and λ̂ = α̂ (σ_q Σq̈ + N ρ_s), a residual of size 1/α̂. Against
    the same law in 40 digits the fast u is at least 10x closer than the reference's."""
    model, path, gains = crane.model, crane.path, crane.gains()
    q0 = crane.equilibrium().q
    rng = np.random.default_rng(5)
    states = [(t, q0 + 1e-4 * rng.standard_normal(q0.size), 1e-2 * rng.standard_normal(q0.size)) for t in (1.0, 4.0)]
    exact = penalty_inputs_40_digits(model, path, gains, method, states)
    ref, fast = (make_controller(method, model, path, gains, fast=f) for f in (False, True))
    scale = np.maximum(np.abs(exact), 1.0)
    err = {}
    for name, c in (("reference", ref), ("fast", fast)):
        err[name] = max(float((np.abs(c.compute(q, qd, t).copy() - exact[i]) / scale[i]).max())
                        for i, (t, q, qd) in enumerate(states))
    assert err["fast"] <= 1e-12 and err["reference"] >= 10 * err["fast"], err


def test_binding_limits_take_the_reference_steps():
    """Limits that bind part of the time (each winch's max at the 90th percentile of its input in the run
    without): those steps are the reference's distribution (DAQP), limit_state and saturation the same; the free
    steps are fast."""
    crane = Crane.from_toml(REPO / "model_spec" / "acroboter_4cable.toml")
    lower, upper, preferred = crane.spec.input_limits()
    free = closed_loops(crane, "penalty", seconds=2.0)[False][1].u
    winches = np.isfinite(upper) & (lower >= 0)
    upper = upper.copy()
    upper[winches] = np.quantile(free[:, winches], 0.9, axis=0)
    runs = closed_loops(crane, "penalty", seconds=2.0, limits=(lower, upper, preferred), ki=KI)
    (_, a), (fast, b) = runs[False], runs[True]
    assert fast.reference_steps > 0 and fast.fast_steps > 0
    assert (a.limit_state != 0).any() and (a.limit_state == b.limit_state).all()
    assert (a.saturated == b.saturated).all()
    assert rel(a.u, b.u) <= 1e-8


def test_every_step_on_the_reference_is_the_reference(crane):
    """The fallback itself: with the fast step's answer never taken, the run is the reference's to the bit."""
    runs = {}
    for fast in (False, True):
        controller = make_controller("penalty", crane.model, crane.path, crane.gains(ki=KI), fast=fast)
        if fast:
            controller._rcond_limit = np.inf  # (a deliberately unsatisfiable check)
        start = crane.equilibrium()
        runs[fast] = simulate(crane.model, crane.path, controller, setup_default(crane.model, crane.path), start.q,
                              1.0, crane.spec.controller.rate_hz, crane.spec.simulation.step)
    assert controller.fast_steps == 0
    assert np.array_equal(runs[False].u, runs[True].u) and np.array_equal(runs[False].q, runs[True].q)


@pytest.mark.parametrize("method", ["mlm", "penalty"])
def test_sensing_reads_the_fast_acceleration(crane, method):
    """With noise and one period of delay the estimator's prediction uses controller.qdd: the fast step's."""
    sensing = {"noise": {"positions": 2e-4}, "delay_periods": 1, "seed": 3}
    a = crane.simulate(method, duration=2.0, sensing=sensing, ki=KI)
    b = crane.simulate(method, duration=2.0, sensing=sensing, ki=KI, fast=True)
    assert rel(a.run.u, b.run.u) <= (1e-11 if method == "mlm" else 1e-8)


def test_redundant_mlm_is_still_a_singular_system():
    crane = Crane.from_toml(REPO / "model_spec" / "acroboter_redundant.toml")
    controller = make_controller("mlm", crane.model, crane.path, crane.gains(), fast=True)
    assert controller.fast_refusal is not None and "singular" in controller.fast_refusal
    with pytest.raises(SingularSystemError, match="redundant"):
        controller.compute(crane.equilibrium().q, np.zeros(crane.layout.n), 0.0)


def test_saturation_as_underactuation_keeps_the_reference_path(crane):
    """The held inputs and the dwell are state the compiled step does not have: refused by name, bit for bit the
    reference."""
    from dataclasses import replace

    gains = replace(crane.gains(), saturation="underactuation")
    controller = make_controller("mlm", crane.model, crane.path, gains, fast=True)
    assert "saturation as underactuation" in controller.fast_refusal
    reference = make_controller("mlm", crane.model, crane.path, gains)
    q, qd = crane.equilibrium().q, np.zeros(crane.layout.n)
    np.testing.assert_array_equal(controller.compute(q, qd, 0.5), reference.compute(q, qd, 0.5))


def test_condition_estimate_is_never_below_the_exact_one(crane):
    """MLM's fast rcond estimate against the exact reciprocal 1-norm condition number of the Schur matrix, at the
    states of a run: never below it (like gecon's), and within the margin FAST_RCOND_MARGIN above it."""
    from acroboter.model.settings import FAST_RCOND_MARGIN

    runs = closed_loops(crane, "mlm", seconds=3.0)
    fast = runs[True][0]
    schur_fn = crane.model.functions["mlm_terms"]
    ratios = []
    for q, qd, t in zip(runs[True][1].q[::10], runs[True][1].qd[::10], runs[True][1].t[::10], strict=True):
        fast.compute(q, qd, t)
        estimate = float(fast.binding.rcond[0])
        schur_fn.call()
        schur = schur_fn.outputs["schur"]
        exact = 1.0 / (np.linalg.norm(schur, 1) * np.linalg.norm(np.linalg.inv(schur), 1))
        lu, piv, info = lapack.dgetrf(schur)
        gecon = lapack.dgecon(lu, np.linalg.norm(schur, 1))[0]
        assert estimate >= exact * (1 - 1e-9) and gecon >= exact * (1 - 1e-9)
        ratios.append(estimate / exact)
    assert max(ratios) < FAST_RCOND_MARGIN


@pytest.mark.parametrize("overrides", [
    {"noise": {"positions": 2e-4}, "delay_periods": 1, "seed": 3},
    {"noise": {"positions": 2e-4}, "delay_periods": 0, "seed": 3},
    {"noise": {"positions": 2e-4}, "delay_periods": 2, "seed": 3, "predict_delay": False},
    {"groups": [{"name": "tracker", "coordinates": ["CC.r", "CC.u", "CC.v", "SU.r", "SU.u", "SU.v"], "noise": 2e-4},
                {"name": "encoders", "coordinates": ["L1.length", "L2.length", "L3.length"], "quantization": 1e-4}],
     "delay_periods": 2, "seed": 7},
], ids=["delay1", "delay0", "delay2-no-predict", "unmeasured-axes"])
def test_compiled_estimator_matches_the_python_one(crane, overrides):
    """The compiled estimator (acroboter.codegen.estimator_c) under the same reference controller: the same run to
    round-off, with and without delay and prediction, with unmeasured coordinates rebuilt by the projection."""
    from acroboter.sim.fast_estimator import FastEstimator, make_estimator

    model, path, spec = crane.model, crane.path, crane.spec
    sensing = crane.sensing(overrides)
    start = crane.equilibrium()
    runs = {}
    for fast in (False, True):
        estimator = make_estimator(model, path, sensing, fast=fast)
        assert isinstance(estimator, FastEstimator) == fast
        controller = make_controller("mlm", model, path, crane.gains(ki=KI))
        runs[fast] = simulate(model, path, controller, setup_default(model, path), start.q, 2.0,
                              spec.controller.rate_hz, spec.simulation.step, sensor=estimator)
    assert rel(runs[False].u, runs[True].u) <= 1e-12 and rel(runs[False].q, runs[True].q) <= 1e-12


def test_run_fast_option_records_the_path(tmp_path):
    """`acroboter run --fast` runs the fast path and says so in the provenance; the default says reference."""
    import json
    import subprocess
    import sys

    for extra, expected in ((["--fast"], "fast"), ([], "reference")):
        out = tmp_path / expected
        proc = subprocess.run([sys.executable, "-m", "acroboter.run", "--duration", "1.0", "--method", "mlm",
                               "--no-plots", "--quiet", "--out", str(out), *extra], capture_output=True, text=True,
                              cwd=REPO, timeout=600)
        assert proc.returncode == 0, proc.stderr
        doc = json.loads((out / "summary.json").read_text())
        assert doc["provenance"]["controller_path"] == expected


def test_the_path_in_c_is_the_python_path_to_the_bit(crane):
    """The fast step evaluates the spec's path in C (codegen.fast_step.path_source): the same bits as
    DesiredPath.flat at every control instant, at the edges' start times, before the start and after the end."""
    fast = make_controller("penalty", crane.model, crane.path, crane.gains(), fast=True)
    assert fast._c_flat is not None  # the spec's path: in the C
    path = crane.path
    times = [*np.arange(0.0, path.duration + 1.0, 1.0 / crane.spec.controller.rate_hz), *path._t0,
             -1.0, path.duration, path.duration + 5.0, 1e-300]
    signals = crane.model.signals
    for t in times:
        fast._c_flat(float(t))
        assert np.array_equal(signals, np.array(path.flat(t))), t
