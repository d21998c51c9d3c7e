"""Integral action on the servo-constraints (issue 12, item 3): σ̈ + 2k_D σ̇ + k_P² σ + k_I ∫σ dt = 0.

Oracles:
- ki = 0 against the code before integral action: u of every method and recovery at recorded states,
  and digests of closed-loop runs and of `acroboter run --duration 2` (tests/data/
  integral_action_baseline.json, recorded with git HEAD e647694); and against itself with a nonzero z
  fed in (0·z must leave every generated output's bits alone).
- a plant heavier than the controller's model (SU and CC mass × 1.1): the PD law's steady error, and
  the integral action's settling time predicted from the roots of s³ + 2k_D s² + k_P² s + k_I with
  the disturbance the PD run measures (a linear model: independent of the controllers' code).
- anti-windup: a winch limit that binds during a lift and then frees; z is frozen over every period
  after a saturated step, and the overshoot after the limit frees is smaller than without it.
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
import re
from pathlib import Path

import numpy as np
import pytest
from conftest import numeric_environment

import acroboter
import acroboter.api.crane
from acroboter.cli import run
from acroboter.codegen.export_step import ExportError, build_step
from acroboter.control.controllers import make_controller
from acroboter.control.path import TrajectoryPath
from acroboter.model import spec_edits
from acroboter.model.settings import Gains
from acroboter.model.spec import SpecError, load_spec
from acroboter.runtime.cache import load_model
from acroboter.sim.simulation import setup_default, simulate
from acroboter.sim.statics import solve_equilibrium, start_targets

REPO = Path(__file__).resolve().parent.parent
DEFAULT = REPO / "model_spec" / "acroboter.toml"
BASELINE = json.loads((Path(__file__).parent / "data" / "integral_action_baseline.json").read_text())
TIMING = {"control_step_us", "sim_wall_s"}
KP = KD = 5.0  # the default spec's (checked below)
# The integrator's pole at 30 % of the PD law's double pole (-5): with kp = kd = 5 the cubic is
# (s + 1.5)(s² + 8.5 s + 12.25), roots -1.5, -1.839, -6.661 (docs/integral_action.md).
POLE = 1.5
KI = POLE * (KP**2 - 2 * KD * POLE + POLE**2)  # 18.375 1/s³
# The measured settling time (at the 50 Hz instants) against the roots' prediction: within two control
# periods (0.04 s, 1 %). Measured 2026-12-02: 4.00 s against 3.992 s for mlm, penalty and iterative-3
# (0.2 %: the crossing falls between two instants, so up to one period is sampling). The rectangle rule
# for the integral gives 4.04 s (0.048 s off): caught, but by less than one period, so its robust catch
# is tests/test_control_law.py.
SETTLING_PERIODS = 2



# Bit for bit only where LAPACK, numpy and CasADi are the ones the baseline was recorded with. Entries changed on
# purpose later were re-recorded in the environment of that day (BASELINE["rerecorded"]: a list, each record with
# its reason; the last record that lists an entry holds its environment).
RERECORDED = BASELINE.get("rerecorded", [])


def recorded_environment(kind: str, key=None) -> dict:
    """The environment entry `key` of `kind` ("steps": "spec/case", "closed_loop": index, "cli_run") was recorded
    with."""
    environment = BASELINE["environment"]
    for record in RERECORDED:
        if record.get("cli_run", False) if kind == "cli_run" else key in record.get(kind, ()):
            environment = record["environment"]
    return environment


def same_environment(kind: str, key=None) -> bool:
    return recorded_environment(kind, key) == numeric_environment()


def digest(a: np.ndarray) -> str:
    return hashlib.sha256(np.ascontiguousarray(a, dtype=float).tobytes()).hexdigest()


RERECORD = ("the digests are of runs of the code before integral action (git e647694): to re-record them for "
            "this environment, run that commit's closed loops (tests/data/integral_action_baseline.json's 'about') "
            "in a worktree of it with this environment's packages and write the digests and environment here")


def flat(figures: dict, prefix: str = "") -> dict:
    """A summary's nested figures as one level ("cables.L1.max_tension_N": ...), for pytest.approx."""
    out = {}
    for key, value in figures.items():
        if isinstance(value, dict):
            out.update(flat(value, f"{prefix}{key}."))
        else:
            out[f"{prefix}{key}"] = value
    return out


def differing(got: dict, recorded: dict) -> list[str]:
    """The figures of `recorded` that `got` misses: numbers beyond 1e-6 relative and 1e-6 absolute in their
    units (mm, deg, N, s: a figure near zero, such as a 4e-7 N thrust of a saturated run, moves by 1e-7 N
    on another CPU), anything else unequal."""
    got, recorded = flat(got), flat(recorded)
    out = []
    for key, value in recorded.items():
        other = got.get(key)
        if isinstance(value, float) and isinstance(other, float | int) and not isinstance(other, bool):
            if other != pytest.approx(value, rel=1e-6, abs=1e-6):
                out.append(f"{key}: {other} (recorded {value})")
        elif other != value:
            out.append(f"{key}: {other} (recorded {value})")
    return out


def closed_loop_comparable(spec: str, kind: str, key=None) -> bool:
    """Whether the closed-loop digests apply here (the baseline's numpy, scipy, CasADi and machine). Where
    they do not, the caller compares the recorded figures to a tolerance instead (never a silent skip)."""
    same = same_environment(kind, key)
    if not same:
        print(f"\n{spec}: baseline recorded with {recorded_environment(kind, key)}, this is {numeric_environment()}: "
              f"figures compared to 1e-6 instead of digests; {RERECORD}")
    return same
    # The nominal plant is the folded step (plant_step_folded), the same arithmetic as the baseline's
    # plant_step: its C differs only by an (empty) parameter input, so the digests are compared as they are.


def with_winch_limits(tmp: Path, high: float, name: str | None = None) -> Path:
    """The default crane with its winches held to [0, high] N, written to tmp/limited.toml (named `name`)."""
    text = spec_edits.with_winch_limits(DEFAULT.read_text(), high, 0.0)
    if name is not None:
        text = text.replace('name = "acroboter"', f'name = "{name}"', 1)
    path = tmp / "limited.toml"
    path.write_text(text)
    return path


@pytest.fixture(scope="module")
def cranes(tmp_path_factory) -> dict[str, acroboter.Crane]:
    tmp = tmp_path_factory.mktemp("integral")
    return {"acroboter": acroboter.Crane.from_toml(DEFAULT),
            "acroboter_4cable": acroboter.Crane.from_example("acroboter_4cable"),
            # max 26.78 N on every winch: a 2 s run needs 26.82 N (the baseline's saturating case)
            "saturating": acroboter.Crane.from_toml(with_winch_limits(tmp, 26.78))}


def test_the_default_gains_are_the_ones_this_file_assumes():
    c = load_spec(DEFAULT).controller
    assert (c.kp, c.kd, c.ki) == (KP, KD, 0.0)


# --- (a) ki = 0 is today's law, bit for bit ---------------------------------------------------------


@pytest.mark.parametrize("function", ["mlm_terms", "penalty_terms", "mlm_bounded_terms", "penalty_bounded_terms"])
def test_zero_ki_leaves_every_generated_output_bit_for_bit(cranes, function):
    """0·z adds ±0: with ki = 0 a nonzero z changes no bit; with ki ≠ 0 ρ_s moves by exactly k_I z."""
    crane = cranes["acroboter"]
    model, k = crane.model, crane.layout.k
    rng = np.random.default_rng(7)
    q = crane.equilibrium().q + 1e-3 * rng.standard_normal(crane.layout.n)  # off the manifold: every term nonzero
    fn = model.functions[function]
    model.parameters_owner = None  # the controllers reload their gains

    def outputs(ki: float, z: np.ndarray) -> dict[str, np.ndarray]:
        model.q[:] = q
        model.qd[:] = 0.01 * np.arange(q.size)
        model.signals[:] = crane.path.flat(3.0)
        p = Gains.from_spec(crane.spec, ki=ki).parameter_vector(k)
        p[p.size - k :] = z
        model.p[:] = p
        fn.call()
        return {name: value.copy() for name, value in fn.outputs.items()}

    reference = outputs(0.0, np.zeros(k))
    z = rng.standard_normal(k) * np.array([1e-3, 1e3, 1.0, 1e-300, 1e300, 7.0])[:k]
    for name, value in outputs(0.0, z).items():
        assert value.tobytes() == reference[name].tobytes(), name
    if function == "penalty_terms":  # the wiring: ρ_s = PD + k_I z, and nothing else moves
        shifted = outputs(0.7, np.linspace(-1, 1, k))
        np.testing.assert_allclose(shifted["rho_s"] - reference["rho_s"], 0.7 * np.linspace(-1, 1, k), rtol=1e-12,
                                   atol=1e-13)
        assert shifted["rho"].tobytes() == reference["rho"].tobytes()
        assert shifted["penalty_matrix"].tobytes() == reference["penalty_matrix"].tobytes()
    model.parameters_owner = None


STEP_CASES = [(spec, key) for spec, entry in BASELINE["steps"].items() for key in entry["u"]]


@pytest.mark.parametrize(("spec", "case"), STEP_CASES)
def test_ki_zero_steps_equal_the_code_before(cranes, spec, case):
    """u of every method and recovery at recorded states: the code before integral action's, bit for bit."""
    crane, entry = cranes[spec], BASELINE["steps"][spec]
    method, *settings = case.split(",")
    overrides = dict(s.split("=") for s in settings)
    t = [float.fromhex(v) for v in entry["t"]]
    q = [np.array([float.fromhex(v) for v in row]) for row in entry["q"]]
    qd = [np.array([float.fromhex(v) for v in row]) for row in entry["qd"]]
    expected = np.array([[float.fromhex(v) for v in row] for row in entry["u"][case]])
    for gains in (crane.gains(**overrides), crane.gains(ki=0.0, **overrides), crane.gains(ki=None, **overrides)):
        c = make_controller(method, crane.model, crane.path, gains)
        got = np.array([c.compute(q[i], qd[i], t[i]).copy() for i in range(len(t))])
        if same_environment("steps", f"{spec}/{case}"):
            assert got.tobytes() == expected.tobytes(), np.abs(got - expected).max()
        else:
            # another CPU's BLAS/libm: 1e-10 N apart on 27 N tensions, and a saturated distribution passes
            # that on to the small inputs (3e-10 N on 0.44 N measured, Intel Xeon against the AMD baseline)
            np.testing.assert_allclose(got, expected, rtol=1e-9, atol=1e-8)


@pytest.mark.parametrize("index", range(len(BASELINE["closed_loop"])))
def test_ki_zero_closed_loop_equals_the_code_before(cranes, index):
    case = BASELINE["closed_loop"][index]
    spec, method = case["spec"], case["method"]
    exact = closed_loop_comparable(spec if spec != "saturating" else "acroboter", "closed_loop", index)
    crane = cranes[spec]
    r = crane.simulate(method, duration=case["duration"], ki=0.0, **case["overrides"])
    figures = {k: v for k, v in r.summary().items() if k not in TIMING and k in case["summary"]}
    if not exact:  # another CPU or LAPACK rounds differently: the code before's figures, to a tolerance
        # except, in a run that reaches a limit, which of the three identical winches sits at it when: the
        # last bit breaks that tie (Intel against the AMD baseline: tension_1 and tension_3 swap their 0.14
        # and 0.16 s at the lower limit); the run's own figures and the number of saturated steps still hold
        at_limit = any(v > 0 for figures_of in case["summary"].get("inputs", {}).values()
                       for k, v in figures_of.items() if k.startswith("time_at_"))
        tie = {"inputs"} if at_limit else set()
        kept = {k: v for k, v in case["summary"].items() if k not in tie}
        assert not differing(figures, kept), (differing(figures, kept), RERECORD)
        assert abs(int(r.saturated.sum()) - case["saturated_steps"]) <= 2, RERECORD
        return
    assert {"u": digest(r.u), "q": digest(r.q), "qd": digest(r.qd)} == {k: case[k] for k in ("u", "q", "qd")}
    assert int(r.saturated.sum()) == case["saturated_steps"]
    # the figures the code before reported (later additions, such as the plant's gaps and energy
    # residual of issue 18, are not in the baseline)
    assert figures == case["summary"]


@pytest.mark.parametrize("method", ["mlm", "penalty", "iterative-3"])
@pytest.mark.parametrize("spec", ["acroboter", "saturating"])
def test_ki_zero_with_a_running_integrator_changes_nothing(cranes, spec, method):
    """The integrator run (z ≠ 0 written into p every step, anti-windup judged) with k_I = 0 in p: the
    same bits as a run that never touches z, saturated steps included."""
    crane = cranes[spec]
    path, start = crane.path, crane.equilibrium()
    runs = []
    for force in (False, True):
        c = make_controller(method, crane.model, path, crane.gains())
        if force:
            c.ki = 1.0  # the controller integrates; the generated functions still read k_I = 0 from p
        z: list[np.ndarray] = []

        def record(_, z=z, c=c):
            z.append(c.integral.copy())

        r = simulate(crane.model, path, c, setup_default(crane.model, path), start.q, 2.0,
                     crane.spec.controller.rate_hz, crane.spec.simulation.step, progress=record)
        runs.append((r, np.array(z)))
    (plain, _), (forced, z) = runs
    assert np.abs(z).max() > 1e-9  # z really ran
    for name in ("u", "q", "qd", "sigma", "saturated", "limit_state"):
        assert getattr(plain, name).tobytes() == getattr(forced, name).tobytes(), name
    if spec == "saturating":
        assert plain.saturated.any()


def _recorded_columns(data: bytes) -> bytes:
    """The CSV as it was when the baseline was recorded (with --state): without the moving anchors'
    columns, the cables' gaps and the energy residual, and with the winch lengths' old unitless names
    (all changed later), by the same writer."""
    rows = list(csv.reader(io.StringIO(data.decode(), newline="")))
    keep = [i for i, name in enumerate(rows[0])
            if not (name.startswith("anchor_") or name.endswith("_gap_m") or name == "energy_residual_J")]
    rows[0] = [re.sub(r"\.length_m(_per_s)?$", lambda m: ".length" + ("_per_s" if m.group(1) else ""), name)
               for name in rows[0]]
    text = io.StringIO(newline="")
    csv.writer(text).writerows([row[i] for i in keep] for row in rows)
    return text.getvalue().encode()


def test_the_run_command_with_ki_zero_writes_what_it_wrote_before(tmp_path, capsys):
    """`acroboter run --duration 2`: its CSVs and figures as before integral action; --ki 0 the same."""
    base = BASELINE["cli_run"]
    argv = [a for a in base["argv"] if a != "run"]
    csvs = {}
    for extra in ([], ["--ki", "0"]):
        out = tmp_path / ("ki0" if extra else "plain")
        assert run.main([*argv, *extra, "--out", str(out), "--quiet", "--spec", str(DEFAULT)]) == 0
        csvs[bool(extra)] = {p.name: _recorded_columns(p.read_bytes()) for p in sorted(out.glob("*.csv"))}
        summary = json.loads((out / "summary.json").read_text())
        assert summary["provenance"]["gains"]["ki"] == 0.0
    capsys.readouterr()
    assert csvs[False] == csvs[True]
    exact = closed_loop_comparable("acroboter", "cli_run")
    if exact:
        assert {name: hashlib.sha256(data).hexdigest() for name, data in csvs[False].items()} == base["csv"]
    for method, figures in summary["methods"].items():
        recorded = base["methods"][method]  # the figures reported then (later additions are not in it)
        got = {k: v for k, v in figures.items() if k not in TIMING and k in recorded}
        if exact:
            assert got == recorded, method
        else:
            assert not differing(got, recorded), (method, differing(got, recorded), RERECORD)
    assert sorted(summary) == base["summary_keys"]


# --- (b) a plant heavier than the model ------------------------------------------------------------


@pytest.fixture(scope="module")
def heavy(tmp_path_factory):
    """(nominal model, heavy model, their paths, q0): the plant's SU and CC 10 % heavier."""
    text = DEFAULT.read_text().replace('name = "acroboter"', 'name = "acroboter_heavier_plant"', 1)
    text, count = re.subn(r'(name = "(?:CC|SU)"\nmass = )([0-9.]+)',
                          lambda m: f"{m.group(1)}{float(m.group(2)) * 1.1!r}", text)
    assert count == 2
    path_heavy = tmp_path_factory.mktemp("heavy") / "acroboter_heavier_plant.toml"
    path_heavy.write_text(text)
    spec_n, spec_h = load_spec(DEFAULT), load_spec(path_heavy)
    assert [b.mass for b in spec_h.bodies] == pytest.approx([1.1 * b.mass for b in spec_n.bodies])
    model_n, model_h = load_model(spec_n), load_model(spec_h)  # the heavy one generated and compiled into the cache
    assert model_h.layout.coordinates == model_n.layout.coordinates  # one q layout for controller and plant
    assert model_h.layout.signals == model_n.layout.signals
    target, yaw = start_targets(model_n)
    duration = 10.0

    def hold(t):  # a hold at the start point: the error at rest is the steady error
        t = np.atleast_1d(t)
        still = np.zeros((t.size, 3))
        return np.tile(target, (t.size, 1)), still, still

    path_n = TrajectoryPath(spec_n, model_n.layout, hold, duration, yaw)
    path_h = TrajectoryPath(spec_h, model_h.layout, hold, duration, yaw)
    q0 = solve_equilibrium(model_n, path_n).q  # the model's static start: the heavier plant sags from it
    return model_n, model_h, path_n, path_h, q0, duration


def run_heavy(heavy, method: str, ki: float):
    model_n, model_h, path_n, path_h, q0, duration = heavy
    spec = model_n.spec
    controller = make_controller(method, model_n, path_n, Gains.from_spec(spec, ki=ki))
    plant = setup_default(model_h, path_h)
    return simulate(model_n, path_n, controller, plant, q0, duration, spec.controller.rate_hz, spec.simulation.step)


def predicted_settling(kp: float, kd: float, ki: float, disturbance: float, threshold: float) -> float:
    """The last time |σ(t)| ≥ threshold for σ = d / P(s) (a constant acceleration deficit d, from rest):
    σ(t) = d Σ_i exp(p_i t) / P'(p_i) over the distinct roots p_i of P = s³ + 2kd s² + kp² s + ki."""
    poly = np.array([1.0, 2 * kd, kp**2, ki])
    roots = np.roots(poly)
    assert np.all(roots.real < 0) and np.min(np.abs(np.subtract.outer(roots, roots)) + np.eye(3)) > 1e-3
    residues = 1.0 / np.polyval(np.polyder(poly), roots)
    t = np.arange(0.0, 60.0, 1e-3)
    sigma = disturbance * np.real(np.exp(np.outer(t, roots)) @ residues)
    above = np.nonzero(np.abs(sigma) >= threshold)[0]
    return float(t[above[-1] + 1])


@pytest.mark.parametrize("method", ["mlm", "penalty", "iterative-3"])
def test_integral_action_removes_the_steady_error_of_a_heavier_plant(heavy, method):
    pd = run_heavy(heavy, method, 0.0)
    rest = pd.t >= pd.t[-1] - 1.0  # the last second: steady
    steady = pd.sigma[rest, 2]
    assert np.ptp(steady) < 1e-4  # settled
    error = float(steady.mean())
    # The controller's tensions carry the model's weight: the SU sinks until k_P² |σ| makes up the rest.
    assert -0.060 < error < -0.020  # tens of mm (the issue: ~38 mm)

    pi = run_heavy(heavy, method, KI)
    norm = np.linalg.norm(pi.sigma[:, :3], axis=1)
    assert norm[-50:].max() < 1e-4  # the last second: below 0.1 mm
    above = np.nonzero(norm >= 1e-3)[0]
    measured = float(pi.t[above[-1] + 1])
    # The linear oracle: the deficit d = k_P² σ_PD acting on σ̈ + 2k_D σ̇ + k_P² σ + k_I ∫σ.
    predicted = predicted_settling(KP, KD, KI, KP**2 * abs(error), 1e-3)
    assert 3.0 < predicted < 5.0
    period = 1.0 / heavy[0].spec.controller.rate_hz
    assert abs(measured - predicted) <= SETTLING_PERIODS * period + 1e-9, (measured, predicted)


# --- (c) anti-windup ----------------------------------------------------------------------------------


LIFT_START, LIFT_TIME, LIFT = 1.0, 1.0, 0.1  # s, s, m: a quintic lift whose acceleration needs ~28.3 N


@pytest.fixture(scope="module")
def limited(tmp_path_factory):
    # max 27.5 N on every winch: above the static 26.75 N, below what the lift's acceleration asks
    crane = acroboter.Crane.from_toml(with_winch_limits(tmp_path_factory.mktemp("lift"), 27.5))
    target, _ = start_targets(crane.model)

    def lift(t):
        t = np.atleast_1d(np.asarray(t, dtype=float))
        tau = np.clip((t - LIFT_START) / LIFT_TIME, 0.0, 1.0)
        moving = (tau > 0) & (tau < 1)
        pos = np.tile(target, (t.size, 1))
        vel, acc = np.zeros((t.size, 3)), np.zeros((t.size, 3))
        pos[:, 2] += LIFT * (10 * tau**3 - 15 * tau**4 + 6 * tau**5)
        vel[:, 2] = moving * LIFT * (30 * tau**2 - 60 * tau**3 + 30 * tau**4) / LIFT_TIME
        acc[:, 2] = moving * LIFT * (60 * tau - 180 * tau**2 + 120 * tau**3) / LIFT_TIME**2
        return pos, vel, acc

    return crane, crane.desired(lift, 8.0)


def run_lift(limited, method: str, anti_windup: bool):
    crane, path = limited
    controller = make_controller(method, crane.model, path, crane.gains(ki=KI))
    controller.anti_windup = anti_windup
    z = []
    r = simulate(crane.model, path, controller, setup_default(crane.model, path),
                 solve_equilibrium(crane.model, path).q,
                 path.duration, crane.spec.controller.rate_hz, crane.spec.simulation.step,
                 progress=lambda _: z.append(controller.integral.copy()))
    return r, np.array(z)


@pytest.mark.parametrize("method", ["mlm", "penalty"])
def test_the_integrator_does_not_wind_up_on_a_limit(limited, method):
    guarded, z = run_lift(limited, method, True)
    free, z_free = run_lift(limited, method, False)
    saturated = np.nonzero(guarded.saturated)[0]
    assert saturated.size >= 10  # the limit binds for a while ...
    assert guarded.t[saturated[-1]] < LIFT_START + LIFT_TIME  # ... and frees again during the lift
    # Conditional integration: z holds over every period that follows a saturated step.
    held = saturated[saturated + 1 < len(z)]
    assert np.array_equal(z[held + 1], z[held])
    assert np.abs(z[saturated[0] : saturated[-1] + 1, 2]).max() == np.abs(z[saturated[0], 2])
    # Without it z grows through the saturation, and the SU overshoots the lift's end by more.
    stretch = slice(saturated[0], saturated[-1] + 1)
    assert np.abs(z_free[stretch, 2]).max() > 1.5 * np.abs(z[stretch, 2]).max()
    after = guarded.t > LIFT_START
    overshoot, overshoot_free = guarded.sigma[after, 2].max(), free.sigma[after, 2].max()
    assert 0 < overshoot < 0.75 * overshoot_free
    for r in (guarded, free):  # both settle on the target
        assert np.linalg.norm(r.sigma[-1, :3]) < 1e-4


# --- settings, refusals ---------------------------------------------------------------------------------


def test_ki_is_a_controller_setting_checked_for_stability(tmp_path, capsys):
    raw = DEFAULT.read_text()
    assert load_spec(DEFAULT).controller.ki == 0.0  # absent: no integral action
    assert "ki" in acroboter.model.controller_parameters.OVERRIDES
    crane = acroboter.Crane.from_toml(DEFAULT)
    assert crane.gains(ki=KI).ki == KI
    with pytest.raises(ValueError, match="ki"):
        crane.gains(ki=-1.0)
    with pytest.raises(ValueError, match="Routh"):
        crane.gains(ki=2 * KD * KP**2)  # the stability bound itself
    assert crane.gains(ki=0.999 * 2 * KD * KP**2).ki > 0
    bad = tmp_path / "unstable.toml"
    bad.write_text(raw.replace("kd = 5.0\n", "kd = 5.0\nki = 300.0\n", 1))
    with pytest.raises(SpecError, match="controller.ki") as err:
        load_spec(bad)
    assert "250" in str(err.value)
    good = tmp_path / "integral.toml"
    good.write_text(raw.replace("kd = 5.0\n", f"kd = 5.0\nki = {KI}\n", 1))
    assert load_spec(good).controller.ki == KI
    assert run.main(["--spec", str(DEFAULT), "--ki", "300", "--duration", "0.1", "--no-plots", "--quiet",
                     "--out", str(tmp_path / "out")]) == 2
    assert "Routh" in capsys.readouterr().err


def test_the_exported_step_refuses_integral_action():
    spec = load_spec(DEFAULT)
    with pytest.raises(ExportError, match="integral action"):
        build_step(spec, "penalty", Gains.from_spec(spec, ki=KI))


def test_the_api_simulates_with_ki_and_resets_z(cranes):
    crane = cranes["acroboter"]
    result = crane.simulate("penalty", duration=1.0, ki=KI)
    assert result.summary()["max_position_error_mm"] < 0.04  # measured 0.0252 mm (2026-12-02); 1.6x
    controller = crane.controller("mlm", ki=KI)
    start = crane.equilibrium()
    offset = start.q.copy()
    offset[crane.coordinates.index("SU.r_z")] -= 0.01  # 10 mm low
    for k in range(3):
        controller.step(offset, 0 * offset, 0.02 * k)
    z = controller.integral[crane.scenario.position_rows.start + 2]  # the vertical row
    assert z == pytest.approx(-0.01 * 0.04, rel=1e-6)  # trapezoid over two periods of a constant error
    controller.reset()
    assert not controller.integral.any()
    controller.step(offset, 0 * offset, 0.0)
    controller.step(offset, 0 * offset, 0.0)  # no time passes: nothing integrated
    assert not controller.integral.any()
