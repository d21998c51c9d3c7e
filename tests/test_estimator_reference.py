"""The estimator (acroboter.sim.sensing) against a transcription of docs/sensing.md in dense numpy (issue 19).

The reference below is written from the documented algorithm, not from the module: every solve is
numpy's `lstsq`/`pinv` on the full matrices of the symbolic model's terms (`model_terms`), the delay
line is a Python list of (measurement, commanded q̈) per instant, and no buffer is reused. It is
driven through instants of a recorded closed loop with commanded accelerations that differ at every
instant (so that a q̈ filed under the wrong instant shows), with and without delay and prediction,
with every coordinate or only the trackers' measured, with noise and quantisation. Mutation testing
(docs/mutation.md) found the delay line's indexing, the reset and the unmeasured coordinates' least
squares reached by no other test.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from conftest import load_with_start, raw_spec

from acroboter.control.controllers import Gains, make_controller
from acroboter.model.schema import Sensing, SpecError
from acroboter.model.spec import parse_spec
from acroboter.sim.sensing import (
    ESTIMATE_LIMIT,
    PROJECTION_TOLERANCE,
    Estimator,
    check_measurable,
    describe,
    resolve,
)
from acroboter.sim.simulation import setup_default, simulate

REPO = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def crane():
    return load_with_start(REPO / "model_spec" / "acroboter.toml")


@pytest.fixture(scope="module")
def recorded(crane):
    """2 s of the penalty closed loop: states that move."""
    spec, model, path, start = crane
    controller = make_controller("penalty", model, path, Gains.from_spec(spec))
    return simulate(model, path, controller, setup_default(model, path), start.q, 2.0,
                    spec.controller.rate_hz, spec.simulation.step)


class Reference:
    """docs/sensing.md, step by step, in numpy."""

    def __init__(self, model, path, sensing, index, noise, step, rows):
        self.model, self.path, self.sensing = model, path, sensing
        self.index, self.noise, self.step, self.rows = index, noise, step, rows
        self.n = model.layout.n
        self.unmeasured = np.setdiff1d(np.arange(self.n), index)
        self.T = 1.0 / model.spec.controller.rate_hz
        self.d = sensing.delay_periods
        p = math.exp(-self.T / sensing.velocity_filter_s)
        self.alpha, self.beta = 1 - p * p, (1 - p) ** 2

    def terms(self, q, qd, signals):
        ns = len(signals) // 3
        s, sd, sdd = (np.array(signals[i * ns:(i + 1) * ns]) for i in range(3))
        out = self.model.evaluate("model_terms", q, qd, s, sd, sdd)
        return out["phi"][self.rows], out["phi_q"][self.rows], out["phi_dot"][self.rows]

    def sample(self, q):
        y = q[self.index].copy()
        if self.noise.any():
            y += self.rng.standard_normal(self.index.size) * self.noise
        on = self.step > 0
        y[on] = self.step[on] * np.round(y[on] / self.step[on])
        return y

    def reset(self, q0):
        self.rng = np.random.default_rng(self.sensing.seed)
        # the crane at rest before the start: measurements of q0 (d + 1 drawn, the first never read: the
        # first instant's own sample takes its place), no acceleration commanded
        self.line = [self.sample(q0) for _ in range(self.d + 1)][1:]
        self.commanded = [np.zeros(self.n) for _ in range(self.d + 1)]  # q̈ of instants k − d − 1 … k − 1
        self.q_m, self.qd_m = q0.copy(), np.zeros(self.n)
        self.x = self.v = None

    def project(self, q, signals):
        iterations = self.sensing.projection_iterations
        if self.unmeasured.size:
            for _ in range(iterations):
                phi, phi_q, _ = self.terms(q, np.zeros(self.n), signals)
                q[self.unmeasured] -= np.linalg.lstsq(phi_q[:, self.unmeasured], phi, rcond=None)[0]
        for _ in range(iterations):
            phi, phi_q, _ = self.terms(q, np.zeros(self.n), signals)
            if np.abs(phi).max() <= PROJECTION_TOLERANCE:
                break
            q -= np.linalg.pinv(phi_q) @ phi
        return q

    def rates(self, q, qd, signals):
        _, phi_q, phi_dot = self.terms(q, qd, signals)
        return qd - np.linalg.pinv(phi_q) @ phi_dot

    def estimate(self, q_plant, t):
        T, d = self.T, self.d
        self.line.append(self.sample(q_plant))
        measured = self.line.pop(0)  # taken d periods ago
        acc = self.commanded[0]  # commanded at k − d − 1: over the period that ends at the measurement
        q = self.q_m
        if self.x is not None:
            q += T * self.qd_m + 0.5 * T * T * acc
        q[self.index] = measured
        self.project(q, self.path.flat(max(t - d * T, 0.0)))
        if self.x is None:
            self.x, self.v = q.copy(), np.zeros(self.n)
        else:
            x = self.x + T * self.v + 0.5 * T * T * acc
            v = self.v + T * acc
            r = q - x
            self.x, self.v = x + self.alpha * r, v + self.beta / T * r
        self.qd_m = self.rates(q, self.v.copy(), self.path.flat(max(t - d * T, 0.0)))
        if not (d and self.sensing.predict_delay):
            return q.copy(), self.qd_m.copy()
        q_out, qd_out = q.copy(), self.qd_m.copy()
        for a in self.commanded[1:]:  # instants k − d … k − 1
            q_out += T * qd_out + 0.5 * T * T * a
            qd_out += T * a
        self.project(q_out, self.path.flat(t))
        return q_out, self.rates(q_out, qd_out, self.path.flat(t))

    def applied(self, qdd):
        self.commanded.pop(0)
        self.commanded.append(qdd.copy())


CASES = {
    "every coordinate, noise": ({"noise": {"positions": 2e-4, "axes": 2e-4, "lengths": 2e-4}, "seed": 5}),
    "delay 1, predicted": ({"noise": {"positions": 1e-4}, "delay_periods": 1, "seed": 6}),
    "delay 3, predicted, quantised": ({"noise": {"positions": 1e-4}, "quantization": {"lengths": 1e-4},
                                       "delay_periods": 3, "seed": 7}),
    "delay 2, not predicted": ({"noise": {"axes": 1e-4}, "delay_periods": 2, "predict_delay": False, "seed": 8}),
    "trackers only, delay 2": ({"groups": [{"name": "tracker", "noise": 1e-4, "coordinates": [
        "CC.r", "CC.u", "CC.v", "SU.r", "SU.u", "SU.v"]}], "delay_periods": 2, "seed": 9}),
}


@pytest.mark.parametrize("case", CASES)
def test_the_estimator_is_the_documented_algorithm(crane, recorded, case):
    spec, model, path, _ = crane
    sensing = resolve(spec, CASES[case])
    estimator = Estimator(model, path, sensing)
    ref = Reference(model, path, sensing, estimator.index, estimator.noise, estimator.step, estimator.rows)
    rng = np.random.default_rng(11)
    q0 = recorded.q[0]
    for _pass in range(2):  # the second pass after reset(): nothing of the first may remain
        estimator.reset(q0)
        ref.reset(q0)
        for k in range(40):
            t = recorded.t[k]
            q_hat, qd_hat = (a.copy() for a in estimator.estimate(recorded.q[k], t))
            q_ref, qd_ref = ref.estimate(recorded.q[k].copy(), t)
            np.testing.assert_allclose(q_hat, q_ref, rtol=0, atol=1e-10, err_msg=f"{case}: q at {k}")
            np.testing.assert_allclose(qd_hat, qd_ref, rtol=0, atol=1e-8 * max(1e-3, np.abs(qd_ref).max()),
                                       err_msg=f"{case}: q̇ at {k}")
            qdd = rng.normal(0.0, 0.05, model.layout.n)  # a different commanded q̈ at every instant
            estimator.applied(qdd)
            ref.applied(qdd)
        assert np.abs(q_hat - q0).max() > 1e-4  # the run moved the crane: the predictions were exercised


def test_the_unmeasured_coordinates_are_the_constraints_least_squares(crane, recorded):
    """One Gauss–Newton step of the unmeasured coordinates: numpy's lstsq on φ_q's unmeasured columns."""
    spec, model, path, _ = crane
    sensing = resolve(spec, CASES["trackers only, delay 2"])
    estimator = Estimator(model, path, sensing)
    q = recorded.q[30].copy()
    q[estimator.unmeasured] += 1e-3
    model.q[:], model.signals[:] = q, path.flat(recorded.t[30])
    estimator._phi.call()
    estimator._phi_q.call()
    rows, free = estimator.rows, estimator.unmeasured
    expected = np.linalg.lstsq(estimator._phi_q_out[rows][:, free], estimator._phi_out[rows], rcond=None)[0]
    got = estimator._least_squares(estimator._phi_out).copy()
    np.testing.assert_allclose(got, expected, rtol=1e-10, atol=1e-14)
    assert np.abs(expected).max() > 1e-4


def test_a_lost_rank_gives_a_non_finite_step_not_a_wrong_one(crane):
    """φ_q without rank (all zeros here): both solves give NaN, which stops the run with a message."""
    spec, model, path, _ = crane
    estimator = Estimator(model, path, resolve(spec, CASES["trackers only, delay 2"]))
    estimator._phi_q_out[:] = 0.0
    assert np.isnan(estimator._least_squares(np.ones(model.layout.m))).all()
    assert np.isnan(estimator._min_norm(np.ones(model.layout.m))).all()


def test_trouble_names_an_estimate_off_the_plant(crane, recorded):
    spec, model, path, _ = crane
    sensing = resolve(spec, {"noise": {"positions": 2e-4}, "quantization": {"lengths": 1e-3}, "delay_periods": 2})
    estimator = Estimator(model, path, sensing)
    q = recorded.q[20]
    estimator.q[:] = q
    assert estimator.trouble(q) is None  # an estimate on the state, far from the origin
    estimator.q[0] = q[0] + ESTIMATE_LIMIT  # on the limit: still the crane's
    assert estimator.trouble(q) is None
    estimator.q[0] = q[0] + 0.75
    message = estimator.trouble(q)
    assert message == (
        "the controller's estimate of the state from the measurements (positions noise 0.0002, lengths noise 0 "
        "quantisation 0.001, delay 2 control period(s)) was 0.75 away from the plant's state (m; unitless for the "
        "axes): the sensing is far too coarse for this crane; lower its noise, quantisation or delay "
        "(docs/sensing.md)")
    estimator.q[0] = np.nan
    assert "was not finite: the sensing is far too coarse" in estimator.trouble(q)
    bad = q.copy()
    bad[1] = np.inf
    assert estimator.trouble(bad) is None  # the plant's own state not finite: nothing to say


def test_describe_says_what_makes_an_estimate_differ(crane):
    spec = crane[0]
    assert describe(resolve(spec, {"noise": {}})) == "no noise, quantisation or delay"
    assert describe(resolve(spec, {"noise": {"axes": 1e-4}, "delay_periods": 1})) == (
        "axes noise 0.0001, delay 1 control period(s)")
    assert describe(resolve(spec, {"quantization": {"positions": 1e-3}})) == "positions noise 0 quantisation 0.001"


def test_reset_starts_the_estimate_at_rest_at_q0(crane, recorded):
    spec, model, path, _ = crane
    estimator = Estimator(model, path, resolve(spec, CASES["delay 1, predicted"]))
    estimator.reset(recorded.q[0])
    estimator.estimate(recorded.q[5], recorded.t[5])
    estimator.reset(recorded.q[3])
    np.testing.assert_array_equal(estimator.q, recorded.q[3])
    assert not estimator.qd.any()
    assert estimator.trouble(recorded.q[3]) is None


def test_a_sensing_that_leaves_motions_free_is_refused_with_the_coordinates(crane):
    """Positions and winch lengths only: the bodies' axes are left to the constraints, which cannot give them
    all. The count of free motions is the nullity of φ_q's unmeasured columns (numpy's rank at the start)."""
    spec, model, path, start = crane
    loose = Sensing.model_validate({"groups": [{"name": "r", "coordinates": [
        "SU.r", "CC.r", "L1.length", "L2.length", "L3.length"]}]})
    with pytest.raises(SpecError) as err:
        check_measurable(model, loose, source="probe")
    coords = model.layout.coordinates
    unmeasured = [i for i, c in enumerate(coords) if ".u_" in c or ".v_" in c or ".w_" in c]
    phi_q = model.term("phi_q", start.q, np.zeros(len(coords)), *path.signal_arrays(0.0))
    rows = np.array(model.manifest["layout"]["independent_constraint_rows"])
    rank = np.linalg.matrix_rank(phi_q[rows][:, unmeasured])
    free = len(unmeasured) - rank
    axes = ", ".join(f"{b}.{a}_{x}" for b in ("CC", "SU") for a, xs in (("u", "yz"), ("v", "xz"), ("w", "xy"))
                     for x in xs)
    assert str(err.value) == (
        "invalid model spec probe:\n  sensing: expected the measured coordinates to determine the others through the "
        f"constraints, found {len(unmeasured)} unmeasured coordinates with only {rank} independent constraints on "
        f"them ({free} free motion(s)); not determined: {axes}. Measure more: each body's r and two of its axes (the "
        "third follows from the orthonormality rows) always suffice, a winch cable's length follows from its cable row")
    assert free > 0


def test_an_override_names_the_first_unknown_key_and_the_known_ones(crane):
    spec = crane[0]
    with pytest.raises(SpecError) as err:
        resolve(spec, {"zeta": 1, "alpha": 2, "seed": 3})
    assert str(err.value) == (
        "invalid model spec sensing:\n  sensing.alpha: expected one of the known keys (noise, quantization, groups, "
        "delay_periods, seed, velocity_filter_s, projection_iterations, predict_delay, max_speed, max_axis_rate, "
        "max_coast_periods), found unknown key 'alpha'")


def test_an_override_starts_from_the_specs_own_section():
    """With a [sensing] section, an override changes only what it names: the section's groups stay (without one,
    it starts from the default groups: every coordinate)."""
    data = raw_spec("acroboter")
    data["sensing"] = {"groups": [{"name": "tracker", "noise": 1e-4, "coordinates": ["CC.r", "CC.u", "CC.v", "SU"]}],
                       "seed": 1}
    spec = parse_spec(data)
    chosen = resolve(spec, {"seed": 9, "delay_periods": 1})
    assert [g.name for g in chosen.groups] == ["tracker"] and chosen.groups[0].noise == 1e-4
    assert (chosen.seed, chosen.delay_periods) == (9, 1)
    assert [g.name for g in resolve(parse_spec(raw_spec("acroboter")), {"seed": 9}).groups] == [
        "positions", "axes", "lengths"]


@pytest.mark.parametrize("override, message", [
    ({"noise": 5}, "sensing.noise: expected a table {group: value}, found 5"),
    ({"quantization": {"nothing": 1e-3}},
     "sensing.quantization.nothing: expected one of the groups positions, axes, lengths, found 'nothing'"),
    ({"delay_periods": -1}, "sensing.delay_periods: expected a whole number 0 <= delay_periods <= 1000 (control "
                            "periods), found -1"),
    ({"groups": [{"name": "tracker", "coordinates": ["SU"], "noise": -1}]},
     "sensing.groups[0].noise: expected 0 <= noise <= 1 (m or unitless), found -1"),
])
def test_a_bad_override_is_a_spec_error_in_process(crane, override, message):
    """In-process (the CLI's tests run a subprocess, which a mutation run's trampolines do not reach)."""
    with pytest.raises(SpecError) as err:
        resolve(crane[0], override, source="--sensing-*")
    assert str(err.value).startswith("invalid model spec --sensing-*:\n  " + message)


def test_groups_given_as_read_only_mappings_take_overrides(crane):
    from types import MappingProxyType

    groups = [MappingProxyType({"name": "all", "coordinates": ["CC", "SU", "L1.length", "L2.length", "L3.length"]})]
    chosen = resolve(crane[0], {"groups": groups, "noise": {"all": 2e-4}})
    assert [(g.name, g.noise) for g in chosen.groups] == [("all", 2e-4)]


def test_the_estimator_is_the_python_one_unless_asked(crane):
    """make_estimator's default is the reference estimator (the compiled one only with fast=True); none for an
    ideal sensing."""
    from acroboter.sim.fast_estimator import FastEstimator, make_estimator

    spec, model, path, _ = crane
    sensing = resolve(spec, CASES["delay 1, predicted"])
    chosen = make_estimator(model, path, sensing)
    assert type(chosen) is Estimator and not isinstance(chosen, FastEstimator)
    assert make_estimator(model, path, resolve(spec, {"noise": {}})) is None


def test_an_override_with_names_the_crane_lacks_is_refused_in_process(crane):
    spec = crane[0]
    with pytest.raises(SpecError) as err:
        resolve(spec, {"groups": [{"name": "a", "coordinates": ["SU.r"]}, {"name": "b", "coordinates": ["SU"]}]})
    assert str(err.value) == ("invalid model spec sensing:\n  sensing.groups[1] (b).coordinates[0]: expected each "
                              "coordinate in one group, found SU.r_x also in group 'a'")
    with pytest.raises(TypeError) as wrong:
        resolve(spec, 5)
    assert str(wrong.value) == "sensing: expected None, False, a mapping or a Sensing, found int"


def test_a_refused_sensing_names_the_spec_by_default(crane):
    spec, model, _, _ = crane
    loose = Sensing.model_validate({"groups": [{"name": "r", "coordinates": ["SU.r", "CC.r"]}]})
    with pytest.raises(SpecError, match=r"^invalid model spec sensing:\n  sensing: expected the measured"):
        check_measurable(model, loose)
