"""Input limits and tension distribution in closed loop (the cables-and-limits issue).

Oracles: the analytic statics of the four-cable crane (m_SU g L / (4 · drop) per cable), a dense
numpy solve of the constrained dynamics for MLM's servo-constraint accelerations, the unbounded
controller for a crane whose limits are never reached, and the limits themselves.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from conftest import load_with_start

from acroboter.cli import run
from acroboter.control.controllers import Gains, make_controller, unbounded
from acroboter.model.spec_edits import with_winch_limits
from acroboter.runtime.cache import load_model
from acroboter.sim.records import Scenario, summarize
from acroboter.sim.simulation import setup_default, simulate
from acroboter.sim.statics import desired_path, solve_equilibrium

REPO = Path(__file__).resolve().parent.parent
FOUR_CABLE = REPO / "model_spec" / "acroboter_4cable.toml"
METHODS = ("mlm", "penalty", "iterative-3", "iterative-5")


@pytest.fixture(scope="module")
def four_cable():
    return load_with_start(FOUR_CABLE)


@pytest.fixture(scope="module")
def four_cable_runs(four_cable):
    spec, model, path, start = four_cable
    plant = setup_default(model, path)
    runs = {}
    for method in METHODS:
        controller = make_controller(method, model, path, Gains.from_spec(spec))
        result = simulate(model, path, controller, plant, start.q, path.duration, spec.controller.rate_hz,
                          spec.simulation.step)
        runs[method] = (result, summarize(result, Scenario.from_model(model), model.layout))
    return runs


@pytest.mark.parametrize("method", METHODS)
def test_four_cable_crane_tracks_within_its_tension_limits(four_cable, four_cable_runs, method):
    spec, model, _, _ = four_cable
    result, summary = four_cable_runs[method]
    lower, upper, _ = spec.input_limits()
    winches = Scenario.from_model(model).winch_inputs
    assert len(winches) == 4 and lower[winches].tolist() == [5.0] * 4 and upper[winches].tolist() == [300.0] * 4
    tensions = result.u[:, winches]
    assert result.t[-1] == pytest.approx(55.0)
    assert np.all(tensions >= 5.0) and np.all(tensions <= 300.0), (tensions.min(), tensions.max())
    # the internal force is fixed: no pair of cables pulling against each other at kilonewtons
    assert np.ptp(tensions) < 0.6  # measured 0.27..0.31 N (2026-12-02); 1.9x
    # measured 0.0614..0.0621 mm over the 55 s path, as on the three-cable crane; bound 1.3x
    assert summary["max_position_error_mm"] < 0.08
    assert np.isfinite(result.u).all()


def test_four_cable_static_tensions_equal_the_analytic_statics(four_cable):
    """Symmetric crane: each of the four cables carries m_SU g L / (4 · drop) at rest."""
    spec, model, path, start = four_cable
    cc, su = spec.body("CC"), spec.body("SU")
    a, b = cc.point("a1"), su.point("b1")
    drop = (cc.initial_position[2] + a[2]) - (su.initial_position[2] + b[2])
    length = math.hypot(drop, math.hypot(a[0] - b[0], a[1] - b[1]))
    expected = su.mass * -spec.gravity[2] * length / (4 * drop)
    assert expected == pytest.approx(20.07, abs=0.01)
    # MLM distributes exactly (lexicographic); the penalty fit's weighted secondary objective (towards
    # the spec's preferred 20 N) and its soft penalty leave 9e-7 (Penalty) and 5e-8 (Iterative-5).
    for method, rel in (("mlm", 1e-9), ("iterative-5", 1e-6), ("penalty", 1e-5)):
        u = make_controller(method, model, path, Gains.from_spec(spec)).compute(start.q, np.zeros(model.layout.n), 0.0)
        np.testing.assert_allclose(u[:4], expected, rtol=rel, err_msg=method)
        np.testing.assert_allclose(u[4:], 0.0, atol=1e-6, err_msg=method)


def test_redundant_mlm_realises_the_servo_constraints_exactly(four_cable, four_cable_runs):
    """Seven inputs for six servo-constraints: the distributed u still gives σ̈ = −2k_D σ̇ − k_P² σ."""
    spec, model, path, _ = four_cable
    result, _ = four_cable_runs["mlm"]
    mlm = make_controller("mlm", model, path, Gains.from_spec(spec))
    kp, kd = spec.controller.kp, spec.controller.kd
    lay = model.layout
    for k in (400, 1500, 2500):
        q, qd, t = result.q[k], result.qd[k], result.t[k]
        u = mlm.compute(q, qd, t).copy()
        terms = model.evaluate("model_terms", q, qd, *path.signal_arrays(t))
        m = terms["phi_q"].shape[0]
        kkt = np.block([[terms["mass_matrix"], terms["phi_q"].T], [terms["phi_q"], np.zeros((m, m))]])
        rhs = np.concatenate([terms["input_matrix"] @ u - terms["bias_forces"], -terms["gamma"]])
        qdd = np.linalg.solve(kkt, rhs)[: lay.n]
        servo_ddot = terms["sigma_q"] @ qdd + terms["gamma_s"]
        target = -2 * kd * terms["sigma_dot"] - kp**2 * terms["sigma"]
        np.testing.assert_allclose(servo_ddot, target, atol=1e-9)


def test_limits_that_are_never_reached_change_nothing():
    """Default crane: the controllers with the spec's limits give the unbounded inputs bit for bit."""
    spec, model, path, start = load_with_start(REPO / "model_spec" / "acroboter.toml")
    gains = Gains.from_spec(spec)
    plant = setup_default(model, path)
    reference = simulate(model, path, make_controller("mlm", model, path, gains), plant, start.q, 10.0,
                         spec.controller.rate_hz, spec.simulation.step)
    for method in ("mlm", "penalty", "iterative-3"):
        bounded = make_controller(method, model, path, gains)
        free = make_controller(method, model, path, gains, limits=unbounded(spec))
        for k in range(0, len(reference.t), 50):
            state = (reference.q[k], reference.qd[k], reference.t[k])
            u_bounded = bounded.compute(*state).copy()
            assert not bounded.limit_state.any()
            assert u_bounded.tobytes() == free.compute(*state).tobytes(), (method, k)


def spec_with_winch_limits(tmp_path: Path, source: Path, low: float, high: float) -> Path:
    """The spec file with `limits = [low, high]` on every winch (limits need no regeneration)."""
    path = tmp_path / source.name
    path.write_text(with_winch_limits(source.read_text(), high, low))
    return path


def run_cli(capsys, *args) -> tuple[int, str, dict]:
    code = run.main([*args, "--no-plots", "--quiet"])
    out = capsys.readouterr().out
    summary = json.loads((Path(args[args.index("--out") + 1]) / "summary.json").read_text())
    return code, out, summary


def test_saturation_is_reported_not_hidden(tmp_path, capsys):
    """Max 26.9 N: above the static 26.75 N, below what the path needs (27.06 N): a saturated run."""
    spec_path = spec_with_winch_limits(tmp_path, REPO / "model_spec" / "acroboter.toml", 0.0, 26.9)
    out = tmp_path / "results"
    code, stdout, summary = run_cli(capsys, "--spec", str(spec_path), "--method", "mlm,penalty", "--out", str(out))
    assert code == 0
    feasibility = summary["path_feasibility"]
    assert feasibility["feasible"] is False
    assert feasibility["input"].startswith("tension_") and feasibility["needed"] > 26.9
    assert 20.0 < feasibility["first_infeasible_s"] < 30.0
    assert summary["input_limits"]["tension_1"] == {"min": 0.0, "max": 26.9, "preferred": 13.45, "unit": "N"}
    assert summary["input_limits"]["thrust_u"]["min"] is None  # unbounded
    for method in ("mlm", "penalty"):
        s = summary["methods"][method]
        assert s.get("diverged_at_s") is None
        assert s["saturated"] is True
        assert s["max_winch_tension_N"] <= 26.9
        held = [v["time_at_upper_limit_s"] for k, v in s["inputs"].items() if k.startswith("tension_")]
        assert max(held) > 0.1
        assert s["max_position_error_while_saturated_mm"] is not None
    assert stdout.strip().splitlines()[-1].startswith("the path was not feasible with these limits")


def test_max_below_the_static_need_is_infeasible_from_the_start(tmp_path, capsys):
    """Max 26 N < 26.75 N: the check names t = 0 and the input; the run has no NaN and says so."""
    spec_path = spec_with_winch_limits(tmp_path, REPO / "model_spec" / "acroboter.toml", 0.0, 26.0)
    out = tmp_path / "results"
    code, stdout, summary = run_cli(capsys, "--spec", str(spec_path), "--method", "mlm,penalty,iterative-3",
                                    "--duration", "1.0", "--out", str(out))
    assert code == 0
    feasibility = summary["path_feasibility"]
    assert feasibility["feasible"] is False and feasibility["first_infeasible_s"] == 0.0
    # symmetric: each winch needs the same; the one furthest out (by round-off) is named
    assert feasibility["input"] in ("tension_1", "tension_2", "tension_3")
    assert feasibility["needed"] == pytest.approx(26.75, abs=0.01)
    assert feasibility["limit"] == 26.0
    for s in summary["methods"].values():
        assert s["saturated"] is True and s["max_winch_tension_N"] <= 26.0
        assert math.isfinite(s["max_position_error_mm"]) and s["max_position_error_mm"] > 1.0  # the load sinks
    assert f"{feasibility['input']} would need 26.75 N" in stdout.strip().splitlines()[-1]


def test_redundancy_absorbs_one_weak_winch(tmp_path, four_cable):
    """Four cables, one capped at 15 N (its share is 20 N): the others take over, the path stays feasible."""
    spec, model, path, start = four_cable
    lower, upper, preferred = spec.input_limits()
    upper[0] = 15.0
    controller = make_controller("mlm", model, path, Gains.from_spec(spec), limits=(lower, upper, preferred))
    plant = setup_default(model, path)
    result = simulate(model, path, controller, plant, start.q, 10.0, spec.controller.rate_hz, spec.simulation.step)
    s = summarize(result, Scenario.from_model(model), model.layout)
    assert result.u[:, 0].max() <= 15.0 and (result.limit_state[:, 0] == 1).mean() > 0.9
    assert result.u[:, 1:4].max() > 22.0  # the others pull harder
    assert s["max_position_error_mm"] < 0.05  # and the task is still met (measured 0.0326 mm, 2026-12-02; 1.5x)
    # on a limit, but not saturated: the servo-constraint accelerations are realised as asked
    assert s["inputs"]["tension_1"]["time_at_upper_limit_s"] > 9.0
    assert not result.saturated.any() and s["saturated"] is False


def test_a_weak_winch_is_neither_infeasible_nor_saturated_in_the_run(tmp_path, capsys):
    """Redundancy absorbs it for every method; the run's last line does not call the path infeasible."""
    text = FOUR_CABLE.read_text().replace('cable = "L1"\nlimits = [5.0, 300.0]', 'cable = "L1"\nlimits = [5.0, 15.0]')
    text = text.replace("preferred = 20.0              #", "preferred = 10.0              #", 1)
    spec_path = tmp_path / "four_cable_weak.toml"
    spec_path.write_text(text)
    assert "limits = [5.0, 15.0]" in text
    code, stdout, summary = run_cli(capsys, "--spec", str(spec_path), "--method", "mlm,penalty", "--duration", "10",
                                    "--out", str(tmp_path / "results"))
    assert code == 0
    assert summary["path_feasibility"]["feasible"] is True
    for s in summary["methods"].values():
        # measured 0.0326 (mlm) / 0.0288 mm (penalty), 2026-12-02; bound 1.5x (was 1.0 mm)
        assert s["saturated"] is False and s["max_position_error_mm"] < 0.05
        assert s["inputs"]["tension_1"]["time_at_upper_limit_s"] > 5.0
    assert "not feasible" not in stdout


def test_an_undecided_check_is_not_called_passed(tmp_path, capsys):
    """More servo-constraints than inputs: the check cannot decide, and the last line says so."""
    spec_path = spec_with_winch_limits(tmp_path, REPO / "model_spec" / "acroboter_redundant_task.toml", 0.0, 26.0)
    code, stdout, summary = run_cli(capsys, "--spec", str(spec_path), "--method", "penalty", "--duration", "1.0",
                                    "--out", str(tmp_path / "results"))
    assert code == 0 and summary["path_feasibility"]["feasible"] is None
    last = stdout.strip().splitlines()[-1]
    assert last.startswith("the path was not feasible with these limits") and "could not decide" in last


def test_a_reversed_winch_reports_its_tension_as_gain_times_u(tmp_path):
    """gain = −1 (reversed mounting): u ≈ −26.75, the cable pulls with +26.75 N and never goes slack."""
    from conftest import raw_spec

    from acroboter.codegen.emit_c import generate
    from acroboter.model.spec import parse_spec

    data = raw_spec("acroboter")
    data["name"] = "acroboter_reversed_winch"
    data["actuators"][0]["gain"] = -1.0
    spec = parse_spec(data)
    assert spec.input_limits()[0][0] == -math.inf and spec.input_limits()[1][0] == 0.0  # pulling is u <= 0
    generate(spec, tmp_path / "generated")
    model = load_model(spec, generated_dir=tmp_path / "generated", cache_dir=tmp_path / "build")
    path = desired_path(model)
    start = solve_equilibrium(model, path)
    controller = make_controller("mlm", model, path, Gains.from_spec(spec))
    result = simulate(model, path, controller, setup_default(model, path), start.q, 2.0, spec.controller.rate_hz,
                      spec.simulation.step)
    s = summarize(result, Scenario.from_model(model), model.layout)
    assert result.u[:, 0].max() < -26.0  # the input itself is negative
    assert 26.0 < s["min_winch_tension_N"] <= s["max_winch_tension_N"] < 28.0
    assert s["cables"]["L1"]["time_slack_s"] == 0.0 and s["cables"]["L1"]["min_tension_N"] > 26.0
    assert not result.limit_state.any()
