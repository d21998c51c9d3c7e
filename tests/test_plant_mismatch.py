"""A plant that differs from the controller's model (acroboter.model.physical, `plant_params`).

Oracles:
(a) the one library's parametric plant at perturbed parameters against plants generated from a
    perturbed *spec* (a modified TOML): the same kind of library loaded through the cache, and one
    generated with the parameters folded in as constants and a numeric M⁻¹ (today's code path);
(b) at the spec's values, the parametric plant against the folded one of the same spec (whose
    plant_step.c is the one before plant parameters existed, arithmetic for arithmetic): terms and
    energy bit for bit, steps and runs to round-off (why not bit for bit: test_nominal_steps...);
(c) an analytic steady state: SU and CC 10 % heavier in the plant, no integral action, a hold;
and the checks of names and values, in the API and the CLI.
"""

from __future__ import annotations

import json
import math
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import acroboter
from acroboter.codegen.emit_c import generate
from acroboter.control.controllers import make_controller
from acroboter.model.physical import PlantParameterError, parameter_names, parameter_values, resolve
from acroboter.model.spec import load_spec
from acroboter.runtime.cache import load_model
from acroboter.sim.plant import Plant
from acroboter.sim.simulation import simulate
from acroboter.sim.statics import desired_path, start_targets

REPO = Path(__file__).resolve().parent.parent
SPEC = REPO / "model_spec" / "acroboter.toml"
# The perturbed crane: the SU 10 % heavier, and one parameter of every other kind moved too.
PERTURBED = {
    "SU.mass": 8.8,
    "CC.inertia.xx": 0.33,
    "SU.damping.translational": 0.6,
    "SU.points.b1.z": 0.055,
    "main.length": 1.52,
    "L2.winch.reflected_inertia": 0.06,
    "gravity.z": -9.8,
}


def perturbed_toml(tmp: Path) -> Path:
    """model_spec/acroboter.toml with PERTURBED written into it (textual edits, checked to apply)."""
    text = SPEC.read_text()
    edits = [
        ('name = "acroboter"', 'name = "acroboter_plant_mismatch_test"'),
        ("mass = 8.0", "mass = 8.8"),
        ("inertia = [[0.3, 0.0, 0.0]", "inertia = [[0.33, 0.0, 0.0]"),
        ("b1 = { radius = 0.15, angle_deg = 90.0, height = 0.05 }",
         "b1 = { radius = 0.15, angle_deg = 90.0, height = 0.055 }"),
        ("length = 1.5", "length = 1.52"),
        ('ends = ["CC.a2", "SU.b2"]\nwinch = { reflected_inertia = 0.05 }',
         'ends = ["CC.a2", "SU.b2"]\nwinch = { reflected_inertia = 0.06 }'),
        ("gravity = [0.0, 0.0, -9.81]", "gravity = [0.0, 0.0, -9.8]"),
    ]
    for old, new in edits:
        assert text.count(old) == 1, old
        text = text.replace(old, new)
    # the SU's damping is the second body's `damping = {...}` line
    head, su = text.split('name = "SU"')
    su = su.replace("damping = { translational = 0.5,", "damping = { translational = 0.6,", 1)
    path = tmp / "acroboter_plant_mismatch_test.toml"
    path.write_text(head + 'name = "SU"' + su)
    return path


@pytest.fixture(scope="module")
def crane():
    return acroboter.Crane.from_toml(SPEC)


def folded_model(spec, root: Path):
    """`spec`'s library generated with the plant's parameters folded in (plant_params is empty)."""
    generate(spec, root, parametric_plant=False)
    return load_model(spec, generated_dir=root)


@pytest.fixture(scope="module")
def perturbed(tmp_path_factory):
    """(spec, its library through the cache, its folded library) of the perturbed TOML."""
    tmp = tmp_path_factory.mktemp("perturbed")
    spec = load_spec(perturbed_toml(tmp))
    return spec, load_model(spec), folded_model(spec, tmp / "folded")


@pytest.fixture(scope="module")
def folded_nominal(tmp_path_factory):
    return folded_model(load_spec(SPEC), tmp_path_factory.mktemp("folded_nominal"))


def spec_value(spec, name: str) -> float:
    from acroboter.model.physical import parameter_names, parameter_values

    return float(parameter_values(spec)[parameter_names(spec).index(name)])


def plant(model, params=None):
    sim = model.spec.simulation
    return Plant(model, desired_path(model), sim.baumgarte_zeta, sim.baumgarte_omega, params)


def replay(p: Plant, q0: np.ndarray, inputs: np.ndarray, substeps: int, h: float):
    """The states, start-of-period tensions and mechanical energies of a plant under given held inputs."""
    n = p.n
    x = p.initial_state(q0)
    table = p.stage_table(0.0, h, len(inputs) * substeps)
    states, tensions, energies = [], [], []
    for k, u in enumerate(inputs):
        p.advance(x, u, h, table, k * substeps, substeps)
        states.append(x.copy())
        tensions.append(p.start_tension.copy())
        energies.append(p.mechanical_energy(x[:n], x[n : 2 * n]))
    return np.array(states), np.array(tensions), np.array(energies)


def pay_out_then_pull_in(p: Plant, q0, u0, h=0.002):
    """The winches pay out (−50 N) for 20 ms, then pull in (100 N): slack cables and impacts."""
    x = p.initial_state(q0)
    sub = round(0.02 / h)
    table = p.stage_table(0.0, h, 25 * sub)
    states = []
    for k in range(25):
        u = u0.copy()
        u[:3], u[3:] = (-50.0 if k == 0 else 100.0), 0.0
        p.advance(x, u, h, table, k * sub, sub)
        states.append(x.copy())
    return np.array(states), [(e.cable, e.kind) for e in p.events], np.array([e.t for e in p.events]), p.impact_energy


def relative(a, b) -> float:
    return float(np.abs(np.asarray(a) - np.asarray(b)).max() / np.abs(np.asarray(b)).max())


# --- names and values ---------------------------------------------------------------------------------


def test_names_follow_the_spec_and_values_are_the_specs(crane):
    names = parameter_names(crane.spec)
    assert len(names) == len(set(names)) == 40
    assert {"gravity.z", "SU.mass", "CC.inertia.zz", "SU.damping.rotational", "SU.points.b3.x", "main.length",
            "L1.winch.reflected_inertia"} <= set(names)
    assert "SU.inertia.xy" not in names  # zero in the spec: a structural zero, no parameter
    values = crane.plant_parameters()
    assert values["SU.mass"] == 8.0 and values["main.length"] == 1.5 and values["gravity.z"] == -9.81
    assert values["SU.points.b1.y"] == pytest.approx(0.15, abs=1e-15)  # a polar point as x, y, z
    vector = resolve(crane.spec, {"SU.mass": 8.8, "SU.points.b1.z": 0.06})
    expected = parameter_values(crane.spec)
    expected[names.index("SU.mass")], expected[names.index("SU.points.b1.z")] = 8.8, 0.06
    assert np.array_equal(vector, expected)


@pytest.mark.parametrize("params, message", [
    ({"SU.mas": 8.8}, "unknown plant parameter(s) 'SU.mas'"),
    ({"SU.inertia.xy": 0.01}, "a product of inertia that is zero in the spec"),
    ({"SU.mass": -1.0}, "bodies[1].mass: expected 1e-6 <= mass <= 1e6 (kg), found -1"),
    ({"SU.mass": 0.0}, "bodies[1].mass"),
    ({"main.length": 0.0}, "cables[0].length: expected 1e-6 <= length <= 1e4 (m), found 0"),
    ({"L1.winch.reflected_inertia": -0.1}, "reflected_inertia"),
    ({"SU.damping.rotational": -1.0}, "damping.rotational"),
    ({"SU.inertia.zz": 1.0}, "triangle inequality"),
    ({"SU.mass": math.nan}, "bodies[1].mass: expected 1e-6 <= mass <= 1e6 (kg), found nan"),
    ({"SU.mass": 1e308}, "bodies[1].mass: expected 1e-6 <= mass <= 1e6 (kg), found 1e+308"),
    ({"SU.mass": "heavy"}, "SU.mass: expected a number, found 'heavy'"),
])
def test_bad_names_and_values_are_refused_before_any_work(crane, params, message):
    with pytest.raises(PlantParameterError) as err:
        crane.simulate("mlm", duration=0.1, plant_params=params, warm_up=0)
    assert message in str(err.value)
    if "unknown" in message:
        assert "SU.mass, SU.inertia.xx" in str(err.value)  # names the valid ones
    assert isinstance(err.value, ValueError)


def run_cli(*args, tmp: Path):
    return subprocess.run([sys.executable, "-m", "acroboter", "run", *args, "--out", str(tmp), "--no-plots",
                           "--quiet"], capture_output=True, text=True)


def test_cli_checks_plant_parameters_and_records_them(tmp_path):
    bad = run_cli("--plant-param", "SU.mas=8.8", "--duration", "0.1", tmp=tmp_path / "a")
    assert bad.returncode == 2 and "unknown plant parameter(s) 'SU.mas'" in bad.stderr and "SU.mass" in bad.stderr
    assert not (tmp_path / "a" / "summary.json").exists()
    negative = run_cli("--plant-param", "SU.mass=-1", "--duration", "0.1", tmp=tmp_path / "b")
    assert negative.returncode == 2 and "bodies[1].mass" in negative.stderr
    malformed = run_cli("--plant-param", "SU.mass", "--duration", "0.1", tmp=tmp_path / "c")
    assert malformed.returncode == 2 and "NAME=VALUE" in malformed.stderr
    good = run_cli("--method", "mlm", "--duration", "0.5", "--plant-param", "SU.mass=8.8",
                   "--plant-param", "CC.mass=11", tmp=tmp_path / "d")
    assert good.returncode == 0, good.stderr
    summary = json.loads((tmp_path / "d" / "summary.json").read_text())
    assert summary["provenance"]["plant_params"] == {"SU.mass": 8.8, "CC.mass": 11.0}
    assert "plant differs from the model: SU.mass=8.8, CC.mass=11" in good.stdout


# --- (a) the parametric plant at perturbed parameters = plants generated from the perturbed spec ------------


def test_perturbed_parameters_equal_a_perturbed_spec(crane, perturbed):
    """The same held inputs (the mismatched closed loop's) through the nominal library's plant at
    PERTURBED, the perturbed spec's library at its own values, and its folded library."""
    spec, model, folded = perturbed
    run = crane.simulate("mlm", duration=3.0, plant_params=PERTURBED, warm_up=0)
    assert run.diverged_at is None
    start = crane.equilibrium()
    substeps = round(1.0 / (spec.controller.rate_hz * spec.simulation.step))
    h = spec.simulation.step
    ours = replay(plant(crane.model, PERTURBED), start.q, run.u[:-1], substeps, h)
    # the run itself is this replay (the controller's inputs, the same plant)
    assert np.array_equal(ours[0][:, : crane.layout.n], run.q[1:])
    # its own values given explicitly: the parametric step (without parameters a plant takes the folded one)
    theirs = replay(plant(model, {name: spec_value(spec, name) for name in PERTURBED}), start.q, run.u[:-1],
                    substeps, h)
    constant = replay(plant(folded), start.q, run.u[:-1], substeps, h)
    for a, b in zip(ours, theirs, strict=True):
        assert np.array_equal(a, b)  # the same C function of the same numbers
    for a, b in zip(ours, constant, strict=True):
        assert relative(a, b) < 1e-12  # seen: 1e-15 (states), 2e-15 (tensions)
    # and not the nominal plant: the perturbation is seen (the SU sags by ~4 cm)
    nominal = replay(plant(crane.model), start.q, run.u[:-1], substeps, h)
    assert relative(nominal[0], ours[0]) > 1e-3


def test_perturbed_events_and_impacts_equal_a_perturbed_spec(crane, perturbed):
    """Slack cables, re-tension impacts and their energy: the plant's numpy side (plant_terms,
    plant_energy, the fixed lengths, the tension tolerance) is the perturbed crane's too."""
    spec, model, folded = perturbed
    start = crane.equilibrium()
    ours = pay_out_then_pull_in(plant(crane.model, PERTURBED), start.q, start.inputs)
    constant = pay_out_then_pull_in(plant(folded), start.q, start.inputs)
    nominal = pay_out_then_pull_in(plant(crane.model), start.q, start.inputs)
    assert len(ours[1]) >= 6 and ours[1] == constant[1]  # seen: 7 (three cables slack and taut, ...)
    assert np.abs(ours[2] - constant[2]).max() < 1e-12
    assert relative(ours[0], constant[0]) < 1e-12 and ours[3] == pytest.approx(constant[3], rel=1e-12)
    assert ours[3] != pytest.approx(nominal[3], rel=1e-3)
    p, q = plant(crane.model, PERTURBED), plant(folded)
    assert p.tension_tol == q.tension_tol
    x = p.initial_state(start.q)
    n = crane.layout.n
    qd = np.linspace(-0.1, 0.1, n)
    assert p.mechanical_energy(start.q, qd) == pytest.approx(q.mechanical_energy(start.q, qd), rel=1e-14)
    for name, value in p._terms_at(x, 1.0).items():
        assert relative(value, q._terms_at(x, 1.0)[name]) < 1e-14, name


# --- (b) the spec's values: today's plant ---------------------------------------------------------------


def test_nominal_terms_are_the_models_bit_for_bit(crane, folded_nominal):
    p, today = plant(crane.model), plant(folded_nominal)
    run = crane.simulate("penalty", duration=2.0, warm_up=0)
    n = crane.layout.n
    for k in range(0, len(run.time), 10):
        x = np.concatenate([run.q[k], run.qd[k] + 0.01, np.zeros(3)])
        t = run.time[k]
        ours, theirs = p._terms_at(x, t), today._terms_at(x, t)
        s, sd, sdd = np.split(crane.path.table(np.array([t]))[0], 3)
        model = crane.model.evaluate("model_terms", q=x[:n], qd=x[n : 2 * n], s=s, sd=sd, sdd=sdd)
        for name in ours:
            assert np.array_equal(ours[name], theirs[name]) and np.array_equal(ours[name], model[name]), name
        # T + U to an ulp: folded, −m·(g_z·z) was built as the constant (−m g_z)·z (see below)
        assert p.mechanical_energy(x[:n], x[n : 2 * n]) == pytest.approx(
            today.mechanical_energy(x[:n], x[n : 2 * n]), rel=1e-15, abs=0)
    assert p.tension_tol == today.tension_tol
    assert np.array_equal(p._inverse_mass(), today._inverse_mass())


def test_nominal_steps_agree_with_todays_to_round_off(crane, folded_nominal):
    """Not bit for bit, and why: building the folded code, CasADi multiplies constants out
    (c₁·(c₂·x) becomes (c₁c₂)·x, e.g. M⁻¹'s 1/m with the 2ξ of φ_q); with the parameters as inputs
    each such product rounds once more, by at most an ulp. So a step agrees to ~1e-16 relative,
    with every mask (all taut, and cables slack)."""
    p, today = plant(crane.model), plant(folded_nominal)
    run = crane.simulate("mlm", duration=2.0, warm_up=0)
    h = crane.spec.simulation.step
    table = p.stage_table(0.0, h, len(run.time))
    worst = 0.0
    for k in range(0, len(run.time) - 1, 5):
        for mask in ([1, 1, 1, 1], [1, 0, 1, 1], [0, 1, 1, 0], [1, 0, 0, 0]):
            outs = []
            for pl in (p, today):
                pl._x[:] = np.concatenate([run.q[k], run.qd[k], np.zeros(3)])
                pl._u[:] = run.u[k]
                pl._settings[:] = (h, pl.zeta, pl.omega)
                pl.cable_active = mask
                pl._step.point_input(pl._stage_input, table.ctypes.data + 2 * k * table.strides[0])
                pl._step.call()
                outs.append([pl._x_next.copy(), pl._tension.copy(), pl._gap.copy()])
                pl._step.point_input(pl._stage_input, pl._stage.ctypes.data)
            x_ours, x_today = outs
            worst = max(worst, relative(x_ours[0], x_today[0]), relative(x_ours[1], x_today[1]))
            assert np.abs(x_ours[2] - x_today[2]).max() < 1e-15  # gaps, m
    assert worst < 1e-13  # seen: 4e-16


def test_nominal_runs_are_todays_to_the_loops_own_round_off(crane, folded_nominal):
    """Whole closed loops: MLM agrees to 1e-15 relative; the penalty methods (α = 1e7) amplify an
    ulp of the state to ~1e-11 over the 55 s path, as much as they do with today's plant started 1
    ulp away, so the parametric plant is bounded by that."""
    spec = crane.spec
    start = crane.equilibrium()
    rate, h = spec.controller.rate_hz, spec.simulation.step

    def closed_loop(method, model, q0):
        controller = make_controller(method, crane.model, crane.path, crane.gains())
        return simulate(crane.model, crane.path, controller, plant(model), q0, crane.path.duration, rate, h)

    ulp = start.q + np.spacing(start.q) * (np.arange(crane.layout.n) == 14)
    for method, bound in (("mlm", 1e-14), ("penalty", 1e-9)):
        today, ours, nudged = (closed_loop(method, crane.model if m == "ours" else folded_nominal, q0)
                               for m, q0 in (("today", start.q), ("ours", start.q), ("today", ulp)))
        assert relative(ours.q, today.q) < bound
        assert relative(ours.q, today.q) <= 10 * relative(nudged.q, today.q)
        assert relative(ours.cable_tension, today.cable_tension) <= 10 * max(
            relative(nudged.cable_tension, today.cable_tension), 1e-14)
    # events and impacts: the same transitions at the same times
    ours = pay_out_then_pull_in(plant(crane.model), start.q, start.inputs)
    today = pay_out_then_pull_in(plant(folded_nominal), start.q, start.inputs)
    assert ours[1] == today[1] and np.abs(ours[2] - today[2]).max() < 1e-12
    assert relative(ours[0], today[0]) < 1e-12 and ours[3] == pytest.approx(today[3], rel=1e-12)


# --- (c) the analytic steady state of a heavier load --------------------------------------------------------


def hold(crane, seconds: float) -> acroboter.SampledTrajectory:
    point, _ = start_targets(crane.model)
    return acroboter.SampledTrajectory([0.0, seconds], [point, point], np.zeros((2, 3)), np.zeros((2, 3)))


def vertical_gain(crane, q: np.ndarray) -> float:
    """Σ_i I_r,i (∂L_i/∂z_SU)² at q: the drums' inertia as the SU's vertical motion sees it."""
    spec, lay = crane.spec, crane.layout

    def world(end: str) -> np.ndarray:
        body, point = end.split(".")
        i = lay.body_offset[body]
        axes = q[i + 3 : i + 12].reshape(3, 3).T  # columns u, v, w
        return q[i : i + 3] + axes @ np.array(spec.body(body).point(point))

    total = 0.0
    for cable in spec.cables:
        if cable.winch is not None:
            d = world(cable.ends[0]) - world(cable.ends[1])
            total += cable.winch.reflected_inertia * (d[2] / q[lay.winch_index[cable.name]]) ** 2
    return total


@pytest.mark.parametrize("method", ["mlm", "penalty"])
def test_a_heavier_load_sags_by_its_extra_weight_over_the_servo_stiffness(crane, method):
    """SU and CC 10 % heavier in the plant than in the controller's model, no integral action, a
    4 s hold at the start point: the SU settles below its target by

        e = Δm_SU g / (m_eff k_P²),   m_eff = m_SU + Σ_i I_r,i (∂L_i/∂z)²   (the model's masses)

    Derivation. The SU hangs on the winch cables from the CC; cable i's tension is the winch's
    input plus the drum's inertia force, T_i = u_i − I_r L̈_i, and with the CC still (it hangs on the
    fixed-length main cable) L̈_i = (∂L_i/∂z) z̈ at rest, ∂L_i/∂z = −d_z/L (d from the SU's point to
    the CC's). The SU's vertical balance m z̈ = −m g + Σ T_i d_z/L becomes
    m_eff z̈ = −m g + Σ u_i d_z/L. The servo law asks σ̈ = −k_P² e (σ̇ = 0 at rest), so the
    controller, believing its model, sends Σ u_i d_z/L = m g + m_eff (−k_P² e) with its nominal m.
    In the plant, with m + Δm, the steady state (z̈ = 0) is 0 = −Δm g − m_eff k_P² e. The CC's extra
    mass goes into the main cable alone: it does not enter (a second run checks that too). Default
    crane: Δm g = 7.848 N, m_eff = 8 + 3·0.05·(0.7/0.716)² = 8.143 kg, k_P = 5: 38.5 mm."""
    spec = crane.spec
    duration = 4.0
    trajectory = hold(crane, duration)
    start = crane.equilibrium(trajectory, duration)
    su, cc = spec.body("SU").mass, spec.body("CC").mass
    kp = crane.gains().kp
    g = -spec.gravity[2]
    m_eff = su + vertical_gain(crane, start.q)
    predicted = 0.1 * su * g / (m_eff * kp**2)
    assert predicted == pytest.approx(0.0385, abs=5e-4)
    assert getattr(crane.gains(), "ki", 0.0) == 0.0  # no integral action
    result = crane.simulate(method, trajectory=trajectory, duration=duration, warm_up=0,
                            plant_params={"SU.mass": 1.1 * su, "CC.mass": 1.1 * cc})
    last = result.time >= duration - 0.5
    sigma = result.run.sigma[last]
    error = -sigma[:, 2].mean()  # below the target: σ_z < 0
    assert error == pytest.approx(predicted, rel=0.10)  # seen: 38.55 mm against 38.55 mm predicted
    assert np.ptp(sigma[:, 2]) < 1e-3 * predicted  # settled
    assert np.abs(sigma[:, :2]).max() < 1e-3 * predicted  # and only vertically
    cc_only = crane.simulate(method, trajectory=trajectory, duration=duration, warm_up=0,
                             plant_params={"CC.mass": 1.1 * cc})
    assert np.abs(cc_only.run.sigma[last, 2]).max() < 0.02 * predicted
    nominal = crane.simulate(method, trajectory=trajectory, duration=duration, warm_up=0)
    assert np.abs(nominal.run.sigma[:, :3]).max() < 1e-6


def test_a_library_whose_plant_parameters_are_not_the_specs_is_refused_by_name(crane, folded_nominal):
    """The plant reads its parameter vector in the order the library declares. A library that declares other
    parameters than the spec's (a spec edited after the C was generated) is refused, saying how to fix it; a
    library with its parameters folded in refuses overrides (it has no input for them)."""
    from acroboter.runtime.integrity import StaleModelError

    model, path = crane.model, crane.path
    layout = model.manifest["layout"]
    names = list(layout["plant_parameters"])
    try:
        layout["plant_parameters"] = names[::-1]
        with pytest.raises(StaleModelError, match="^" + re.escape(
                f"the plant parameters of {model.source_dir} are not the spec's: regenerate it with `make generate`")
                + "$"):
            Plant(model, path, 1.0, 20.0)
    finally:
        layout["plant_parameters"] = names
    Plant(model, path, 1.0, 20.0)  # as it was
    with pytest.raises(PlantParameterError, match="generated with its physical parameters folded in: it takes no "
                                                  "plant parameters$"):
        Plant(folded_nominal, desired_path(folded_nominal), 1.0, 20.0, {names[0]: 1.0})
