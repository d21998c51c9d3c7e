"""Measurement instead of state (acroboter/sim/sensing.py, docs/sensing.md).

(a) the projection onto φ(q) = 0 from noisy coordinates, on every shipped crane; (b) without sensing,
or with an ideal one, every method is today's bit for bit (an in-process comparison, and digests
recorded with git HEAD cdbbb88 before sensing existed); (c) 0.2 mm position noise and one period of
delay: every method still tracks; (d) the velocity estimate on a recorded noiseless run, within the
bound the α-β filter's lag gives; and the refusals (SpecError naming the field, CLI exit 2).
"""

from __future__ import annotations

import copy
import hashlib
import json
import math
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
import scipy
import scipy.linalg
from conftest import numeric_environment, raw_spec

import acroboter
from acroboter.api.crane import Crane
from acroboter.model.spec import SpecError, parse_spec
from acroboter.sim.fast_estimator import make_estimator
from acroboter.sim.records import Scenario
from acroboter.sim.sensing import Estimator, is_ideal, resolve

METHODS = ["mlm", "penalty", "iterative-3", "iterative-4", "iterative-5"]
BASELINE = json.loads((Path(__file__).parent / "data" / "sensing_baseline.json").read_text())
# Position noise and delay of (c); the measured figures are printed (pytest -s) and in docs/sensing.md.


class DigestNotApplicable(UserWarning):
    """A golden digest recorded in another environment: not compared, and the summary says so."""


NOISY = {"noise": {"positions": 2e-4}, "delay_periods": 1, "seed": 7}



def digest(a: np.ndarray) -> str:
    return hashlib.sha256(np.ascontiguousarray(a, dtype=float).tobytes()).hexdigest()


@pytest.fixture(scope="module")
def default():
    return Crane.from_example("acroboter")


def every_coordinate(crane: Crane, **fields):
    return resolve(crane.spec, {"noise": {}, **fields})  # the default groups: positions, axes, lengths


# --- (a) projection ------------------------------------------------------------------------------------

@pytest.mark.parametrize("name", acroboter.example_names())
def test_projection_reaches_the_manifold_and_removes_noise(name):
    crane = Crane.from_example(name)
    q_true = crane.equilibrium().q
    signals = crane.path.flat(0.0)
    estimator = Estimator(crane.model, crane.path, every_coordinate(crane, projection_iterations=3))
    rng = np.random.default_rng(12)
    model = crane.model
    for _ in range(5):
        noisy = q_true + 1e-3 * rng.standard_normal(q_true.size)
        projected = estimator.project(noisy.copy(), signals)
        model.q[:] = projected
        model.signals[:] = signals
        model.functions["phi"].call()
        assert np.abs(model.functions["phi"].outputs["phi"]).max() < 1e-10  # every row, the dependent ones too
        assert np.linalg.norm(projected - q_true) < np.linalg.norm(noisy - q_true)


def test_unmeasured_coordinates_are_reconstructed(default):
    """Without the w axes and the winch lengths: the constraints give them back from the rest."""
    spec = default.spec
    groups = [{"name": "tracker", "coordinates": [f"{b.name}.{v}" for b in spec.bodies for v in "ruv"]}]
    estimator = Estimator(default.model, default.path, resolve(spec, {"groups": groups}))
    q_true = default.equilibrium().q
    measured = np.zeros(q_true.size, dtype=bool)
    measured[estimator.index] = True
    q = q_true.copy()
    q[measured] += 1e-3 * np.random.default_rng(3).standard_normal(measured.sum())
    q[~measured] = q_true[~measured] + 0.01  # a poor prior: 10 mm (or 0.01) off
    projected = estimator.project(q, default.path.flat(0.0))
    assert estimator.last_violation < 1e-10
    assert np.abs(projected[~measured] - q_true[~measured]).max() < 2e-3  # back to the noise's scale (1e-3)


def test_a_sensing_that_measures_too_little_is_refused(default):
    data = raw_spec("acroboter")
    data["sensing"] = {"groups": [{"name": "su", "coordinates": ["SU", "L1.length", "L2.length", "L3.length"]}]}
    with pytest.raises(SpecError, match=r"sensing: expected the measured coordinates to determine .* CC\.") as err:
        Crane.from_spec(parse_spec(data))
    assert "free motion" in str(err.value)
    with pytest.raises(SpecError, match="not determined"):
        default.sensing({"groups": [{"name": "r", "coordinates": ["SU.r", "CC.r"]}]})


# --- (b) bit for bit ------------------------------------------------------------------------------------

def test_ideal_sensing_is_the_state(default):
    assert is_ideal(default.spec, default.layout, every_coordinate(default))
    assert make_estimator(default.model, default.path, every_coordinate(default)) is None
    assert not is_ideal(default.spec, default.layout, every_coordinate(default, delay_periods=1))


@pytest.mark.parametrize("method", METHODS)
def test_without_sensing_every_method_is_todays_bit_for_bit(default, method):
    plain = default.simulate(method, duration=3.0, warm_up=0)
    ideal_section = raw_spec("acroboter")
    ideal_section["sensing"] = {"groups": [
        {"name": "tracker", "coordinates": ["CC", "SU"], "noise": 0.0},
        {"name": "encoders", "coordinates": ["L1.length", "L2.length", "L3.length"]}], "delay_periods": 0}
    with_section = Crane.from_spec(parse_spec(ideal_section)).simulate(method, duration=3.0, warm_up=0)
    runs = [with_section, default.simulate(method, duration=3.0, warm_up=0, sensing=False),
            default.simulate(method, duration=3.0, warm_up=0, sensing={"noise": {"positions": 0.0}})]
    for other in runs:
        for field in ("q", "qd", "u", "sigma", "phi", "cable_tension"):
            assert np.array_equal(getattr(plain.run, field), getattr(other.run, field)), field
    if BASELINE["environment"] != numeric_environment():
        # the comparison above (the same run with an ideal sensing section, and without sensing, bit for bit)
        # is the oracle; the digests pin today's code to the code before sensing (the penalty methods: to git
        # 61a52a8's, which changed their recovery on purpose) and need the recorded environment. Said in the
        # test summary (a warning), never a silent skip.
        warnings.warn(f"sensing digests not compared: recorded with {BASELINE['environment']}, this is "
                      f"{numeric_environment()}; to re-record tests/data/sensing_baseline.json run git cdbbb88's (mlm) "
                      "and 61a52a8's (penalty methods) "
                      "Crane.from_example('acroboter').simulate(method, duration=3.0, warm_up=0) in a worktree of that "
                      "commit with these packages (its 'about' says how)", DigestNotApplicable, stacklevel=1)
        return
    recorded = BASELINE["runs"][method]
    assert {k: digest(getattr(plain.run, k)) for k in recorded} == recorded  # today's code, before sensing


def test_a_real_sensing_changes_the_run(default):
    """The comparison above can fail: the smallest noise takes another path through the loop."""
    plain = default.simulate("penalty", duration=1.0, warm_up=0)
    noisy = default.simulate("penalty", duration=1.0, warm_up=0, sensing={"noise": {"positions": 1e-12}})
    assert not np.array_equal(plain.run.u, noisy.run.u)
    assert np.abs(plain.run.q - noisy.run.q).max() < 1e-3  # the estimated rates lag a little: the same run otherwise


# --- (c) noise and delay -----------------------------------------------------------------------------

@pytest.mark.parametrize("method", METHODS)
def test_noise_and_delay_still_track(default, method):
    result = default.simulate(method, warm_up=0, sensing=NOISY)
    summary = result.summary()
    assert result.diverged_at is None
    assert np.isfinite(result.run.q).all() and np.isfinite(result.run.u).all()
    print(f"\n{method}: 0.2 mm noise, 1 period delay: max {summary['max_position_error_mm']:.4f} mm, "
          f"rms {summary['rms_position_error_mm']:.4f} mm, yaw {summary['max_yaw_error_deg']:.4f} deg, "
          f"tilt {summary['max_tilt_deg']:.4f} deg, max |phi| {summary['max_constraint_violation']:.1e}")
    assert math.isfinite(summary["max_position_error_mm"])

    # The rms error derived from the noise: the measurement noise through the projection onto the
    # manifold (linearised: P = I − φ_qᵀ(φ_q φ_qᵀ)⁻¹φ_q, then σ_q), averaged over the run's states, times
    # the noise gain of the sampled loop (PD law on a double integrator, α-β filter, one period of
    # delay carried forward), added in quadrature to the same run without noise (path and delay).
    # Measured 2026-12-02: 0.0966 (mlm) / 0.0978 mm against 0.1020 / 0.1031 mm derived (0.95x: a
    # 55 s sample of a noise-driven rms, ~5 % spread); within ±15 %. k_P for k_P² in the servo law
    # gives 0.141..0.154 mm (1.3x over), the α-β velocity gain off by the period 0.19 (mlm) and
    # 2.9 mm (penalty, iterative).
    estimator = Estimator(default.model, default.path, resolve(default.spec, NOISY))
    kp, kd = default.spec.controller.kp, default.spec.controller.kd
    gain = loop_noise_gain(kp, kd, estimator.period, estimator.sensing.velocity_filter_s)
    assert gain == pytest.approx(0.3645, abs=1e-4)  # per axis, σ_error / σ_noise
    clean = default.simulate(method, warm_up=0, sensing={**NOISY, "noise": {"positions": 0.0}}).summary()
    noise_rms = gain * projected_noise(default, estimator, result.run)
    derived = 1e3 * math.hypot(noise_rms, 1e-3 * clean["rms_position_error_mm"])
    print(f"rms {summary['rms_position_error_mm']:.4f} mm, derived {derived:.4f} mm "
          f"(noise {1e3 * noise_rms:.4f} mm, without noise {clean['rms_position_error_mm']:.4f} mm)")
    assert summary["rms_position_error_mm"] == pytest.approx(derived, rel=0.15)
    # the maximum: measured 0.2818..0.2820 mm; bound 1.4x (a 55 s maximum of a noise-driven error)
    assert summary["max_position_error_mm"] < 0.4


def loop_noise_gain(kp: float, kd: float, T: float, tau: float) -> float:
    """The steady-state σ of the position error per unit σ of white position noise, one axis: the plant
    a double integrator held over each period, the command −k_P² x̂ − 2k_D v̂ from the measurement one
    period old (x̂ the measurement, v̂ its α-β filter with both poles at e^(−T/τ)), carried forward over
    the delay with the commanded accelerations. Exact, by the discrete Lyapunov equation."""
    pole = math.exp(-T / tau)
    alpha, beta = 1 - pole**2, (1 - pole) ** 2

    def step(s, n):  # s = x, v (plant), xf, vf (filter), a1, a2 (last two commands), y1 (last measurement)
        x, v, xf, vf, a1, a2, y1 = s
        xf, vf = xf + T * vf + 0.5 * T * T * a2, vf + T * a2
        r = y1 - xf
        xf, vf = xf + alpha * r, vf + beta / T * r
        a = -kp**2 * (y1 + T * vf + 0.5 * T * T * a1) - 2 * kd * (vf + T * a1)
        return np.array([x + T * v + 0.5 * T * T * a, v + T * a, xf, vf, a, a1, x + n])

    F = np.column_stack([step(e, 0.0) for e in np.eye(7)])
    G = step(np.zeros(7), 1.0)
    assert np.abs(np.linalg.eigvals(F)).max() < 1
    return math.sqrt(scipy.linalg.solve_discrete_lyapunov(F, np.outer(G, G))[0, 0])


def projected_noise(crane, estimator, run, every: int = 25) -> float:
    """The rms over the run of the task position's noise after the projection onto φ = 0, linearised
    (the projection's minimal-norm Gauss–Newton steps) at the run's states: |σ_q P diag(noise)|_F."""
    model, rows = crane.model, estimator.rows
    position = Scenario.from_model(model).position_rows
    noisy = estimator.noise > 0
    phi_q, sigma_q = model.functions["phi_q"], model.functions["sigma_q"]
    variance = []
    for k in range(0, len(run.t), every):
        model.q[:] = run.q[k]
        model.signals[:] = crane.path.flat(run.t[k])
        phi_q.call()
        sigma_q.call()
        a = phi_q.outputs["phi_q"][rows]
        p = np.eye(a.shape[1]) - a.T @ np.linalg.solve(a @ a.T, a)
        j = sigma_q.outputs["sigma_q"][position] @ p[:, estimator.index[noisy]] * estimator.noise[noisy]
        variance.append(float((j**2).sum()))
    return math.sqrt(np.mean(variance))


def test_a_tracker_without_encoders_still_tracks(default):
    """w axes and winch lengths unmeasured: rebuilt through the constraints every step."""
    groups = [{"name": "positions", "coordinates": ["CC.r", "SU.r"], "noise": 2e-4},
              {"name": "axes", "coordinates": ["CC.u", "CC.v", "SU.u", "SU.v"]}]
    result = default.simulate("penalty", duration=10.0, warm_up=0, sensing={**NOISY, "groups": groups})
    assert result.diverged_at is None and np.isfinite(result.run.u).all()
    # measured 2026-12-02: 0.2887 mm over these 10 s; bound 1.4x (a maximum of a noise-driven error)
    assert result.summary()["max_position_error_mm"] < 0.4


def test_the_seed_repeats_a_run(default):
    a = default.simulate("penalty", duration=1.0, warm_up=0, sensing=NOISY)
    b = default.simulate("penalty", duration=1.0, warm_up=0, sensing=NOISY)
    c = default.simulate("penalty", duration=1.0, warm_up=0, sensing={**NOISY, "seed": 8})
    assert np.array_equal(a.run.u, b.run.u) and not np.array_equal(a.run.u, c.run.u)


def test_quantisation_rounds_to_the_step(default):
    estimator = Estimator(default.model, default.path, resolve(default.spec, {"quantization": {"lengths": 1e-3}}))
    q = default.equilibrium().q
    out = np.zeros(estimator.index.size)
    estimator._sample(q, out)
    lengths = estimator.step > 0
    assert np.allclose(out[lengths] / 1e-3, np.round(out[lengths] / 1e-3), atol=1e-9)
    assert np.abs(out[lengths] - q[estimator.index][lengths]).max() <= 0.5e-3 + 1e-12
    assert np.array_equal(out[~lengths], q[estimator.index][~lengths])


# --- (d) the velocity estimate ----------------------------------------------------------------------

def lag_gain(alpha: float, beta: float, period: float, steps: int = 2000) -> float:
    """Σ_k |h_k|: the α-β filter's velocity error per unit of unmodelled acceleration (the ℓ1 norm of its
    impulse response from acceleration to velocity error), so |v̂ − v| ≤ this × max |a| for any a."""
    x = v = xf = vf = 0.0
    total = 0.0
    for k in range(steps):
        a = 1.0 if k == 0 else 0.0
        x, v = x + period * v + 0.5 * period**2 * a, v + period * a  # the truth over one period
        xf += period * vf  # the filter without the acceleration
        r = x - xf
        xf += alpha * r
        vf += beta / period * r
        total += abs(vf - v)
    return total


def test_velocity_estimate_matches_within_the_filters_lag(default):
    run = default.simulate("penalty", duration=20.0, warm_up=0).run  # noiseless, the plant's q and q̇
    sensing = every_coordinate(default)
    estimator = Estimator(default.model, default.path, sensing)
    T = estimator.period
    bound = lag_gain(estimator.alpha, estimator.beta, T)
    # steady state of a constant acceleration: the velocity lags by T (α/β − 1/2), the ℓ1 gain's core
    assert bound == pytest.approx(T * (estimator.alpha / estimator.beta - 0.5), rel=0.05)
    q, qd = run.q, run.qd
    accel = np.zeros_like(q)
    accel[1:-1] = (q[2:] - 2 * q[1:-1] + q[:-2]) / T**2  # what the filter sees between samples
    worst = np.abs(accel).max(axis=0)
    estimator.reset(q[0])
    errors = np.zeros(len(q))
    for k in range(len(q)):
        _, qd_hat = estimator.estimate(q[k], run.t[k])  # no commanded acceleration fed: all of it is unmodelled
        errors[k] = np.linalg.norm(qd_hat - qd[k])
    tolerance = bound * np.linalg.norm(worst)
    print(f"\nvelocity estimate: max |q̇̂ − q̇| {errors.max():.3e} (tolerance {tolerance:.3e}: lag gain {bound:.4f} s "
          f"× max |q̈| {np.linalg.norm(worst):.3e})")
    assert errors.max() <= 1.05 * tolerance
    assert errors.max() > 0  # the filter ran

    # With the accelerations fed (as the loop feeds the commanded ones) the lag all but vanishes.
    estimator.reset(q[0])
    fed = np.zeros(len(q))
    for k in range(len(q)):
        _, qd_hat = estimator.estimate(q[k], run.t[k])
        fed[k] = np.linalg.norm(qd_hat - qd[k])
        if k + 1 < len(q):
            estimator.applied((qd[k + 1] - qd[k]) / T)  # the plant's mean acceleration over the period
    print(f"with the accelerations fed: max |q̇̂ − q̇| {fed.max():.3e}")
    assert fed.max() < 0.1 * errors.max()


# --- refusals ------------------------------------------------------------------------------------------

@pytest.mark.parametrize("section, field, message", [
    ({"noise": -1.0}, "sensing.groups[0].noise", "expected 0 <= noise <= 1 (m or unitless), found -1"),
    ({"quantization": 0.0}, "sensing.groups[0].quantization", "expected 1e-12 <= quantization <= 1"),
    ({"quantization": -1e-3}, "sensing.groups[0].quantization", "found -0.001"),
    ({"delay_periods": 1.5}, "sensing.delay_periods", "expected a whole number 0 <= delay_periods <= 1000"),
    ({"delay_periods": -1}, "sensing.delay_periods", "0 <= delay_periods <= 1000 (control periods), found -1"),
    ({"coordinates": ["SU.q"]}, "sensing.groups[0] (tracker).coordinates[0]", "found 'SU.q'"),
])
def test_bad_sections_are_spec_errors_naming_the_field(section, field, message):
    data = raw_spec("acroboter")
    group = {"name": "tracker", "coordinates": ["CC", "SU"]}
    top = {}
    for key, value in section.items():
        (top if key == "delay_periods" else group)[key] = value
    data["sensing"] = {"groups": [group], **top}
    with pytest.raises(SpecError) as err:
        parse_spec(copy.deepcopy(data))
    assert any(path == field and message in text for path, text in err.value.problems), err.value.problems


@pytest.mark.parametrize("args, message", [
    (["--sensing-noise", "positions=-0.001"],
     "argument --sensing-noise: positions: expected 0 <= noise <= 1 (m or unitless), found -0.001"),
    (["--sensing-delay", "1.5"], "argument --sensing-delay: expected a whole number 0 <= delay_periods <= 1000 "
                                 "(control periods), found 1.5"),
    (["--sensing-delay", "-1"], "argument --sensing-delay: expected a whole number 0 <= delay_periods <= 1000"),
    (["--sensing-delay", "10"], "--sensing-delay: expected a whole number 0 <= delay_periods <= 4 (control periods)"),
    (["--sensing-quantization", "lengths=0"],
     "argument --sensing-quantization: lengths: expected 1e-12 <= quantization <= 1 (m or unitless), found 0"),
    (["--sensing-noise", "nothing=1"], "--sensing-noise nothing: expected one of the groups"),
])
def test_cli_refuses_bad_sensing_with_exit_2(tmp_path, args, message):
    done = subprocess.run([sys.executable, "-m", "acroboter", "run", "--duration", "0.1", "--no-plots",
                           "--out", str(tmp_path), *args], capture_output=True, text=True, timeout=300)
    assert done.returncode == 2, done.stderr
    assert message in done.stderr and "Traceback" not in done.stderr


def test_cli_runs_with_sensing_and_records_it(tmp_path):
    done = subprocess.run([sys.executable, "-m", "acroboter", "run", "--duration", "1", "--no-plots", "--method",
                           "penalty", "--out", str(tmp_path), "--sensing-noise", "positions=0.0002",
                           "--sensing-delay", "1", "--sensing-seed", "7"], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert "controller measures" in done.stdout
    summary = json.loads((tmp_path / "summary.json").read_text())
    sensing = summary["provenance"]["sensing"]
    assert sensing["delay_periods"] == 1 and sensing["seed"] == 7
    assert sensing["groups"][0] == {"name": "positions", "coordinates": ["CC.r", "SU.r"], "noise": 0.0002,
                                    "quantization": None}
    api = Crane.from_example("acroboter").simulate("penalty", duration=1.0, sensing=NOISY).summary()
    assert summary["methods"]["penalty"]["max_position_error_mm"] == pytest.approx(api["max_position_error_mm"])


# --- a sensing far too coarse: its failure names it -----------------------------------------------------


def _with_noise(crane: Crane, group: str, std: float):
    """The default groups with `group`'s noise at `std`, as a Sensing (built unchecked: any range a noise option
    or field may have does not decide what this test sees)."""
    chosen = every_coordinate(crane, noise={group: 0.0})
    groups = [g.model_copy(update={"noise": std}) if g.name == group else g for g in chosen.groups]
    return chosen.model_copy(update={"groups": groups})


@pytest.mark.parametrize("method", ["penalty", "mlm"])
def test_a_noise_far_beyond_the_crane_is_named_as_the_cause(default, method):
    """Issue 24: a positions noise of 1e6 ended in 'the penalty matrix ... is not positive definite: check the
    penalty numbers' (MLM: 'the constraints are redundant'). Issue 38: no such sample reaches the controller now:
    each one's projection does not converge, the estimator coasts on its prediction (code 4) and after
    max_coast_periods + 1 rejected in a row the estimate is lost; the run stops there, naming the sensing."""
    for std in (1e6, 1.0):
        result = default.simulate(method, duration=1.0, warm_up=0, sensing=_with_noise(default, "positions", std))
        assert result.diverged_at == pytest.approx(0.2)  # 11 periods of 20 ms: 10 coasted, the 11th lost
        assert (result.step_codes == 4).all() and result.step_codes.size == 10
        assert result.run.divergence.startswith(
            f"the controller's estimate was lost: 11 samples in a row rejected, the last the projection did not "
            f"converge (sensing: positions noise {std:g})")
        assert np.abs(result.u - result.u[0]).max() < 1.0  # coasting on the model: the inputs stayed sane
    # a noise the crane can live with says nothing of the kind
    fine = default.simulate(method, duration=0.2, warm_up=0, sensing=_with_noise(default, "positions", 1e-4))
    assert fine.diverged_at is None
