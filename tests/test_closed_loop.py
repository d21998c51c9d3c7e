"""Closed-loop acceptance on the default spec (issue 3): tracking bounds, MLM/penalty overlap,
static tensions at t = 0 against the analytic statics, positive tensions, constraint drift, and the
fixed-step plant against scipy's adaptive integrator and the energy balance."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from conftest import load_with_start, rigid_plant_rhs
from scipy.integrate import solve_ivp

from acroboter.control.controllers import Gains, make_controller
from acroboter.sim.records import Scenario, summarize
from acroboter.sim.simulation import setup_default, simulate

REPO = Path(__file__).resolve().parent.parent
METHODS = ("mlm", "penalty", "iterative-3", "iterative-4", "iterative-5")


@pytest.fixture(scope="module")
def crane():
    return load_with_start(REPO / "model_spec" / "acroboter.toml")


@pytest.fixture(scope="module")
def full_runs(crane):
    """Every method over the whole 55 s path (the paper's scenario)."""
    spec, model, path, start = crane
    plant = setup_default(model, path)
    scenario = Scenario.from_model(model)
    runs = {}
    for method in METHODS:
        controller = make_controller(method, model, path, Gains.from_spec(spec))
        result = simulate(model, path, controller, plant, start.q, path.duration, spec.controller.rate_hz,
                          spec.simulation.step)
        runs[method] = (result, summarize(result, scenario, model.layout))
    return runs


def analytic_static_tension(spec) -> float:
    """m_SU g L / (3 · drop) for the symmetric default crane (docs/model.md §9)."""
    cc, su = spec.body("CC"), spec.body("SU")
    a, b = cc.point("a1"), su.point("b1")
    drop = (cc.initial_position[2] + a[2]) - (su.initial_position[2] + b[2])
    radial = math.hypot(a[0] - b[0], a[1] - b[1])
    length = math.hypot(drop, radial)
    return su.mass * -spec.gravity[2] * length / (3 * drop)


def test_analytic_tension_is_the_design_number(crane):
    assert analytic_static_tension(crane[0]) == pytest.approx(26.75, abs=0.01)


@pytest.mark.parametrize("method, rel", [("mlm", 1e-9), ("iterative-3", 1e-9), ("iterative-5", 1e-9),
                                         ("penalty", 1e-5)])
def test_tensions_at_start_equal_the_static_ones(crane, method, rel):
    spec, model, path, start = crane
    controller = make_controller(method, model, path, Gains.from_spec(spec))
    u = controller.compute(start.q, np.zeros(model.layout.n), 0.0)
    expected = analytic_static_tension(spec)
    np.testing.assert_allclose(u[:3], expected, rtol=rel)
    np.testing.assert_allclose(u[3:], 0.0, atol=1e-9)


@pytest.mark.parametrize("method", METHODS)
def test_every_method_tracks_inside_the_paper_bounds(full_runs, method):
    _, s = full_runs[method]
    # The paper's bounds are 5.3 mm and 1.1°; a correct implementation tracks far better. Measured
    # 2026-12-02 (55 s path): max 0.0614..0.0621 mm, rms 0.0202..0.0213 mm, yaw 0.00019..0.00031°,
    # tilt 0.0037° (mlm) / 0.155° (penalty, iterative). Bounds 1.3x the max, 1.4x the rms, 1.9x the
    # yaw (maxima of a 55 s closed loop: room for another BLAS/numpy, not for a wrong law). With k_P
    # in place of k_P² in the servo law (issue 19) they reach 0.088..0.100 mm, 0.040..0.043 mm rms
    # and 0.00094..0.00107°: caught by each of the three.
    assert s["max_position_error_mm"] < 0.08
    assert s["rms_position_error_mm"] < 0.03
    assert s["max_yaw_error_deg"] < 0.0006
    assert s["max_tilt_deg"] < (0.006 if method == "mlm" else 0.25)  # 1.6x
    assert s["max_constraint_violation"] < 1e-6
    assert s["min_winch_tension_N"] > 0


def test_mlm_and_penalty_paths_overlap(full_runs):
    mlm, penalty = full_runs["mlm"][0], full_runs["penalty"][0]
    rows = slice(0, 3)
    gap = np.linalg.norm(mlm.sigma[:, rows] - penalty.sigma[:, rows], axis=1)  # same desired path
    assert gap.max() < 0.03e-3  # measured 0.0146 mm (2026-12-02); 2x (was 0.5 mm)


def test_the_run_follows_the_whole_path(full_runs, crane):
    result, _ = full_runs["mlm"]
    path = crane[2]
    assert result.t[-1] == pytest.approx(path.duration)
    realized = result.sigma[:, :3] + result.desired[:, :3]
    # The column is 0.25 x 0.25 x 0.1 m: the realized path spans it.
    np.testing.assert_allclose(np.ptp(realized, axis=0), [0.25, 0.25, 0.1], atol=1e-3)
    assert np.degrees(result.desired[-1, 3] - result.desired[0, 3]) == pytest.approx(90.0)


def test_eq12_drops_the_winch_tension_while_projected_holds_it(crane):
    """Design §8: on this non-collocated crane eq. 12 gives zero winch tension."""
    spec, model, path, start = crane
    qd0 = np.zeros(model.layout.n)
    eq12 = make_controller("penalty", model, path, Gains.from_spec(spec, recovery="eq12"))
    projected = make_controller("penalty", model, path, Gains.from_spec(spec, recovery="projected"))
    assert np.abs(eq12.compute(start.q, qd0, 0.0)[:3]).max() < 1e-9
    assert projected.compute(start.q, qd0, 0.0)[:3] == pytest.approx([26.75] * 3, abs=0.01)


def test_penalty_input_differs_slightly_from_mlm_by_design(crane, full_runs):
    """Not collocated: the projected recovery is a least-squares fit, close to MLM's u but not equal."""
    spec, model, path, _ = crane
    result, _ = full_runs["mlm"]
    mlm = make_controller("mlm", model, path, Gains.from_spec(spec))
    penalty = make_controller("penalty", model, path, Gains.from_spec(spec))
    k = len(result.t) // 3
    u_mlm = mlm.compute(result.q[k], result.qd[k], result.t[k]).copy()
    u_pen = penalty.compute(result.q[k], result.qd[k], result.t[k]).copy()
    rel = np.abs(u_pen[:3] - u_mlm[:3]) / np.abs(u_mlm[:3])
    assert 0 < rel.max() < 0.02


def test_fixed_step_plant_agrees_with_solve_ivp(crane):
    spec, model, path, start = crane
    n = model.layout.n
    plant = setup_default(model, path)
    # A held input off the balance, so that the crane really moves during the second.
    u = start.inputs + np.array([1.5, -1.0, 0.5, 0.02, 0.3, -0.2])
    x = plant.initial_state(start.q)
    h = spec.simulation.step
    steps = round(1.0 / h)
    for i in range(steps):
        plant.step(x, i * h, u, h)
    sim = spec.simulation
    ref = solve_ivp(rigid_plant_rhs(model, path, u, sim.baumgarte_zeta, sim.baumgarte_omega), (0.0, 1.0),
                    np.concatenate([start.q, np.zeros(n)]), method="DOP853", rtol=1e-11, atol=1e-12)
    assert ref.success
    moved = np.abs(ref.y[:n, -1] - start.q).max()
    assert moved > 1e-3  # the check means something only if the state moved
    # positions of both bodies (r rows) to 1e-6 m; all coordinates to the same order
    np.testing.assert_allclose(x[:n], ref.y[:n, -1], atol=1e-6, rtol=0)


def test_energy_balance(crane):
    """ΔT + ΔU = work of the inputs + work of the moving anchor − damping losses, over any stretch."""
    spec, model, path, start = crane
    plant = setup_default(model, path)
    controller = make_controller("mlm", model, path, Gains.from_spec(spec))
    result = simulate(model, path, controller, plant, start.q, 8.0, spec.controller.rate_hz, spec.simulation.step,
                      energy=True)
    e = result.energy
    balance = e["mechanical"] - (e["work_inputs"] + e["work_anchors"] - e["dissipated"])
    # Each term is not trivially small (the check would be vacuous otherwise) ...
    assert np.ptp(e["work_inputs"]) > 1e-3
    assert np.ptp(e["work_anchors"]) > 1e-4
    assert e["dissipated"][-1] > 1e-6
    # ... and over every stretch [a, b] the balance holds to the integrator's accuracy.
    # (Leaving out any one term breaks it by at least ~1e-2 J; RK4 at 2 ms keeps it near 1e-12 J.)
    drift = balance - balance[0]
    scale = np.abs(e["work_inputs"]).max() + np.abs(e["work_anchors"]).max() + e["dissipated"].max()
    assert np.abs(drift).max() < 1e-6 * scale
