"""Cables that only pull (acroboter/sim/plant.py): slack and taut transitions against independent oracles.

- free fall of the SU on slack winch cables (closed form with linear drag), and the SU dragging the
  drums on taut ones (the effective mass m + Σ I_r (∂L_i/∂z)² of the symmetric crane);
- a ball on a string from a fixed hook (a test spec built into a temporary folder): the pendulum
  goes slack where the analytic tension vanishes, flies on the ballistic parabola, comes taut where
  the parabola meets the string's sphere, and the inelastic impact removes the radial velocity;
- the taut crane under MLM over the whole path: never slack, and the same motion as a plain
  bilateral (rigid) solve with scipy's solve_ivp;
- the energy balance ΔT + ΔU = W_u + W_anchor − E_d + impacts across transitions, each impact's
  ΔT ≤ 0, and the records and summary figures.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np
import pytest
from conftest import build_in, load_with_start, rigid_plant_rhs
from scipy.integrate import quad, solve_ivp
from scipy.optimize import brentq

from acroboter.control.controllers import Gains, make_controller
from acroboter.model.spec import load_spec, parse_spec
from acroboter.runtime.cache import load_model
from acroboter.sim.plant import Plant
from acroboter.sim.records import Scenario, summarize
from acroboter.sim.result import Result
from acroboter.sim.simulation import setup_default, simulate
from acroboter.sim.statics import desired_path, solve_equilibrium

REPO = Path(__file__).resolve().parent.parent
G = 9.81


@pytest.fixture(scope="module")
def crane():
    return load_with_start(REPO / "model_spec" / "acroboter.toml")


class OpenLoop:
    """A 'controller' that returns a given input; it loads the state and signals into the model's
    buffers as the real controllers do (simulate records σ and φ from them)."""

    name = "open-loop"

    def __init__(self, model, path, u_of_t, limit_state=None):
        self.model, self.path, self.u_of_t = model, path, u_of_t
        self.limit_state = np.zeros(model.layout.l, dtype=np.int8) if limit_state is None else limit_state

    def compute(self, q, qd, t):
        self.model.q[:] = q
        self.model.qd[:] = qd
        self.model.signals[:] = self.path.flat(t)
        return self.u_of_t(t)

    def saturation(self) -> bool:
        return False  # no limits: an open-loop input is applied as given


def winch_geometry(spec):
    """Drop and length of the (symmetric) winch cables at the start, from the spec's numbers."""
    cc, su = spec.body("CC"), spec.body("SU")
    a, b = cc.point("a1"), su.point("b1")
    drop = (cc.initial_position[2] + a[2]) - (su.initial_position[2] + b[2])
    radial = math.hypot(a[0] - b[0], a[1] - b[1])
    return drop, math.hypot(drop, radial)


# --- (a) the SU on slack and on unpowered winch cables -------------------------------------------------


def test_slack_winch_cables_let_the_su_fall_freely(crane, tmp_path):
    """u = −50 N on every winch: the drums push, a cable cannot, so the winch cables go slack at once
    and the SU falls under gravity and its own linear drag c: z̈ = −g − (c/m) ż (closed form below).
    The drums spin out freely (I_r L̈ = −u) and the main cable holds the CC alone."""
    spec, model, path, start = crane
    lay = model.layout
    su = spec.body("SU")
    m, c = su.mass, su.damping.translational
    u = start.inputs.copy()
    u[:3], u[3:] = -50.0, 0.0
    limit = np.array([-1, -1, -1, 0, 1, 0], dtype=np.int8)  # recorded as given (a controller's limit_state)
    plant = setup_default(model, path)
    # the SU falls 0.1 m, inside the 0.5 m divergence band; the drums (I_r L̈ = 50 N) pay out 9.8 m, within the 10 m
    # their default capacity leaves (acroboter.model.physical.drum_capacities: the run would stop there)
    duration = 0.14
    result = simulate(model, path, OpenLoop(model, path, lambda t: u, limit), plant, start.q, duration,
                      spec.controller.rate_hz, spec.simulation.step, energy=True)
    # the plant reports the winch cables slack from the first step on, with no tension, and no re-tension
    names = result.cable_names
    assert names == ["main", "L1", "L2", "L3"]
    assert (result.cable_active[:, 1:] == 0).all() and (result.cable_active[:, 0] == 1).all()
    assert np.abs(result.cable_tension[:, 1:]).max() == 0.0
    assert sorted((e.cable, e.kind, e.t) for e in plant.events) == [(c, "slack", 0.0) for c in (1, 2, 3)]
    # the main cable carries the CC's weight alone (the CC is at rest at the start)
    np.testing.assert_allclose(result.cable_tension[0, 0], spec.body("CC").mass * G, rtol=1e-9)

    t = result.t
    z0 = start.q[lay.body_offset["SU"] + 2]
    tau = m / c
    z_exact = z0 - G * tau * (t - tau * (1 - np.exp(-t / tau)))
    vz_exact = -G * tau * (1 - np.exp(-t / tau))
    z = result.q[:, lay.body_offset["SU"] + 2]
    vz = result.qd[:, lay.body_offset["SU"] + 2]
    np.testing.assert_allclose(z, z_exact, atol=1e-9, rtol=0)
    # vertical acceleration (finite differences of the recorded velocity) = the exact mean acceleration
    acc = np.diff(vz) / np.diff(t)
    acc_exact = np.diff(vz_exact) / np.diff(t)
    np.testing.assert_allclose(acc, acc_exact, rtol=1e-6)
    assert abs(acc[0] + G) < 1e-3 * G  # that is g, less the drag of a slow fall
    # horizontal: nothing acts
    xy = slice(lay.body_offset["SU"], lay.body_offset["SU"] + 2)
    assert np.abs(result.q[:, xy] - start.q[xy]).max() < 1e-12
    # the drums: I_r L̈ = −u, from rest
    for cable in ("L1", "L2", "L3"):
        i, inertia = lay.winch_index[cable], spec.cables[names.index(cable)].winch.reflected_inertia
        np.testing.assert_allclose(result.q[:, i], start.q[i] + 0.5 * (50.0 / inertia) * t**2, rtol=1e-12)

    # records and summary
    s = summarize(result, Scenario.from_model(model), model.layout)
    period = 1.0 / spec.controller.rate_hz
    held = len(t) - 1  # instants followed by a held control period
    for cable in ("L1", "L2", "L3"):
        assert s["cables"][cable] == {"time_slack_s": pytest.approx(held * period), "transitions": 1,
                                      "min_tension_N": 0.0, "max_tension_N": 0.0}
    assert s["cables"]["main"]["time_slack_s"] == 0.0 and s["cables"]["main"]["transitions"] == 0
    assert s["cables"]["main"]["min_tension_N"] > 0
    assert s["inputs"]["tension_1"] == {"time_at_lower_limit_s": pytest.approx(held * period),
                                        "time_at_upper_limit_s": 0.0,
                                        "max_position_error_while_at_limit_mm": s["max_position_error_mm"]}
    assert s["inputs"]["thrust_u"] == {"time_at_lower_limit_s": 0.0,
                                       "time_at_upper_limit_s": pytest.approx(held * period),
                                       "max_position_error_while_at_limit_mm": s["max_position_error_mm"]}
    assert s["inputs"]["yaw_torque"] == {"time_at_lower_limit_s": 0.0, "time_at_upper_limit_s": 0.0,
                                         "max_position_error_while_at_limit_mm": None}
    assert result.limit_state.shape == (len(t), lay.l) and (result.limit_state == limit).all()
    assert "max_position_error_mm" in s and "control_step_us" in s  # the existing keys stay
    np.testing.assert_array_equal(result.energy["impacts"], 0.0)
    Result(result, lay, Scenario.from_model(model), spec.name).to_csv(tmp_path / "run.csv")
    with (tmp_path / "run.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == len(t)
    assert rows[0]["cable_L1_slack"] == "1" and rows[0]["cable_main_slack"] == "0"
    assert float(rows[0]["cable_main_tension_N"]) == pytest.approx(spec.body("CC").mass * G, rel=1e-9)


def test_taut_winch_cables_drag_the_drums(crane):
    """u = 0 on every winch: the SU falls and pulls the cables off the drums, which stay taut.

    At the start the crane is at rest and 3-fold symmetric about the vertical through the SU, and the
    climbing unit does not accelerate (the path starts from rest): the CC's acceleration is symmetric,
    so it is vertical, and the vertical main cable forbids that; nothing turns it about z. So at t = 0
    the CC does not accelerate and the SU translates down alone, with T = ½ (m + Σ I_r (∂L_i/∂z)²) ż²,
    ∂L_i/∂z = −drop / L: z̈(0) = −m g / (m + 3 I_r (drop/L)²), and each cable's tension is the drum's
    I_r L̈ = I_r (drop/L) |z̈(0)|, the main cable's the CC's weight plus the cables' vertical pull."""
    spec, model, path, start = crane
    lay = model.layout
    su, cc = spec.body("SU"), spec.body("CC")
    inertia = spec.cables[1].winch.reflected_inertia
    drop, length = winch_geometry(spec)
    slope = drop / length
    a_exact = su.mass * G / (su.mass + 3 * inertia * slope**2)
    assert a_exact < 0.99 * G  # the drums matter (1.8 %): the 1e-6 check tells them apart from a free fall

    plant = setup_default(model, path)
    u = start.inputs.copy()
    u[:] = 0.0
    x = plant.initial_state(start.q)
    h = 1e-3
    vz = []
    for i in range(2):
        plant.step(x, i * h, u, h)
        if i == 0:
            tension0 = plant.start_tension.copy()
        vz.append(x[lay.n + lay.body_offset["SU"] + 2])
    # v(t) = a t + j t²/2 + …: a = 2 v(h)/h − v(2h)/(2h) + O(h²)
    a0 = -(2 * vz[0] / h - vz[1] / (2 * h))
    assert a0 == pytest.approx(a_exact, rel=1e-6)
    cc_velocity = x[lay.n + lay.body_offset["CC"] : lay.n + lay.body_offset["CC"] + 12]
    assert np.abs(cc_velocity).max() < 1e-8  # the CC (nearly) does not move
    np.testing.assert_allclose(tension0[1:], inertia * slope * a_exact, rtol=1e-6)
    np.testing.assert_allclose(tension0[0], cc.mass * G + 3 * slope * inertia * slope * a_exact, rtol=1e-6)
    # the cables stay taut while the SU falls
    for i in range(2, 100):
        plant.step(x, i * h, u, h)
        assert (plant.start_tension > 0).all()
    assert plant.transitions.sum() == 0 and (plant.cable_active == 1).all()


# --- (b) a ball on a string --------------------------------------------------------------------------

BALL = {
    "name": "cable_ball",
    "description": "test spec: a ball on a string from a fixed hook",
    "gravity": [0.0, 0.0, -G],
    "anchors": [{"name": "hook", "position": [0.0, 0.0, 2.0]}],
    "bodies": [{"name": "ball", "mass": 1.5, "inertia": [[0.01, 0.0, 0.0], [0.0, 0.01, 0.0], [0.0, 0.0, 0.01]],
                "initial_position": [0.0, 0.0, 1.0], "points": {"c": [0.0, 0.0, 0.0]}}],
    "cables": [{"name": "string", "ends": ["hook", "ball.c"], "length": 1.0}],
    "actuators": [{"name": "lift", "kind": "body_thrust", "body": "ball", "axis": "w"}],
    "task": [{"kind": "position", "body": "ball"}],
    "path": {"waypoints": [[0.0, 0.0, 0.0], [0.1, 0.0, 0.0]], "mean_speed": 0.1},
    "controller": {"rate_hz": 50.0, "kp": 5.0, "kd": 5.0,
                   "penalty": {"alpha_geometric": 1e7, "alpha_servo": 1e7, "omega": 10.0, "mu": 1.0}},
    "simulation": {"step": 0.002, "baumgarte_zeta": 1.0, "baumgarte_omega": 20.0},
}
HOOK, LENGTH, MASS = np.array([0.0, 0.0, 2.0]), 1.0, 1.5
GRAVITY = np.array([0.0, 0.0, -G])
H = 0.002


def ball_on_a_string(tmp_path_factory, data: dict):
    """(model, path, plant) of a ball spec (BALL or a variant), generated and compiled into a temporary folder."""
    spec = parse_spec(data, f"{data['name']} (test)")
    _, model, path = build_in(tmp_path_factory.mktemp(data["name"]), spec)
    sim = spec.simulation
    return model, path, Plant(model, path, sim.baumgarte_zeta, sim.baumgarte_omega)


@pytest.fixture(scope="module")
def ball(tmp_path_factory):
    """The ball is a test spec: generated and compiled into a temporary folder."""
    model, _, plant = ball_on_a_string(tmp_path_factory, BALL)
    return model, plant


def unforced_flight(plant, velocity, steps, length=LENGTH):
    """The ball from the bottom of its string (at rest on its sphere, under the hook at its start) with a velocity;
    unforced, `steps` steps of H. Returns the times, the states, the start-of-step tensions and the end-of-step
    gaps (the first: the start's)."""
    q0 = np.concatenate([HOOK - [0.0, 0.0, length], np.eye(3).reshape(-1)])
    x = plant.initial_state(q0, np.concatenate([velocity, np.zeros(9)]))
    table = plant.stage_table(0.0, H, steps)
    states, tensions, gaps = [x.copy()], [], [plant.cable_gap[0]]
    for i in range(steps):
        plant.advance(x, np.zeros(1), H, table, i, 1)
        states.append(x.copy())
        tensions.append(plant.start_tension[0])
        gaps.append(plant.cable_gap[0])
    return H * np.arange(steps + 1), np.array(states), np.array(tensions), np.array(gaps)


def throw(ball, velocity, seconds):
    """The ball from the bottom of the string with a velocity, unforced, for `seconds`. Returns times, states
    after every step, the start-of-step tensions and the plant."""
    _, plant = ball
    t, states, tensions, _ = unforced_flight(plant, velocity, round(seconds / H))
    return t, states, tensions, plant


def energy_balance(plant, states):
    """T + U − (W_u + W_anchor − E_d) at every state (the impacts are the caller's to subtract)."""
    n = plant.n
    return np.array([plant.mechanical_energy(x[:n], x[n : 2 * n]) - (x[2 * n] + x[2 * n + 1] - x[2 * n + 2])
                     for x in states])


def first_contact(p, v, after: float) -> float:
    """First τ > `after` where the parabola p + v τ + ½ g τ² is back on the string's sphere."""
    def f(tau):
        d = p + v * tau + 0.5 * GRAVITY * tau**2 - HOOK
        return d @ d - LENGTH**2

    taus = np.linspace(after, 5.0, 50001)
    values = np.array([f(tau) for tau in taus])
    k = int(np.argmax(values > 0))
    assert values[k] > 0 and values[k - 1] <= 0
    return brentq(f, taus[k - 1], taus[k], xtol=1e-15, rtol=1e-15)


def test_a_pendulum_whirled_too_slowly_goes_slack_flies_and_snaps_taut(ball):
    """v0² = 3.5 g L at the bottom: the string's tension m (v0²/L − 2g + 3g cos θ) vanishes at
    cos θ_s = (2g − v0²/L) / (3g) = −1/2 (θ_s = 120°), reached at t_s = ∫ L dθ / v(θ) (quad). From
    there the ball flies on a parabola until it is back on the sphere |p − hook| = L."""
    v0 = math.sqrt(3.5 * G * LENGTH)
    t, states, tensions, plant = throw(ball, np.array([v0, 0.0, 0.0]), 1.4)
    n = plant.n

    # taut phase: the tension is the pendulum's m (v²/L + g cos θ) at the plant's own state
    p, v = states[:, :3], states[:, n : n + 3]
    cos_theta = -(p[:, 2] - HOOK[2]) / LENGTH
    expected_tension = MASS * (np.einsum("ij,ij->i", v, v) / LENGTH + G * cos_theta)
    slack_event, taut_event = plant.events
    assert slack_event.kind == "slack" and taut_event.kind == "taut"
    taut_steps = t[:-1] < slack_event.t - 1e-12
    np.testing.assert_allclose(tensions[taut_steps], expected_tension[:-1][taut_steps], rtol=1e-6,
                               atol=1e-6 * MASS * G)
    assert tensions[0] == pytest.approx(MASS * (v0**2 / LENGTH + G), rel=1e-9)

    # goes slack at the analytic time: located inside its step (it was the first step that started after it, a
    # step late, and the string pushed until then), to the integrator's accuracy
    cos_s = (2 * G - v0**2 / LENGTH) / (3 * G)
    theta_s = math.acos(cos_s)
    t_s, _ = quad(lambda th: LENGTH / math.sqrt(v0**2 - 2 * G * LENGTH * (1 - math.cos(th))), 0.0, theta_s,
                  epsabs=1e-13, epsrel=1e-13)
    assert abs(slack_event.t - t_s) < 1e-6, (slack_event.t, t_s)

    # comes taut where the analytic parabola (from the analytic slack state) meets the sphere
    p_s = HOOK + LENGTH * np.array([math.sin(theta_s), 0.0, -math.cos(theta_s)])
    v_s = math.sqrt(v0**2 - 2 * G * LENGTH * (1 - cos_s)) * np.array([math.cos(theta_s), 0.0, math.sin(theta_s)])
    t_taut = t_s + first_contact(p_s, v_s, 1e-6)
    assert abs(taut_event.t - t_taut) < 1e-6, (taut_event.t, t_taut)

    # while slack: the ballistic parabola through the plant's first state after it went slack (RK4 is exact
    # on a quadratic), to 1e-9 m
    k_s = int(np.argmax(t > slack_event.t))
    flying = (t >= t[k_s]) & (t <= taut_event.t)
    dt = t[flying] - t[k_s]
    parabola = p[k_s] + np.outer(dt, v[k_s]) + 0.5 * np.outer(dt**2, GRAVITY)
    np.testing.assert_allclose(p[flying], parabola, atol=1e-9, rtol=0)
    assert (tensions[flying[:-1]] == 0).all()

    # the impact: inelastic, it takes out exactly the radial velocity: ΔT = −½ m (v⁻·n)²
    tau = taut_event.t - t[k_s]
    p_hit = p[k_s] + v[k_s] * tau + 0.5 * GRAVITY * tau**2
    v_hit = v[k_s] + GRAVITY * tau
    normal = (p_hit - HOOK) / np.linalg.norm(p_hit - HOOK)
    assert abs(np.linalg.norm(p_hit - HOOK) - LENGTH) < 1e-8  # located on the sphere
    assert taut_event.delta_kinetic < 0
    assert taut_event.delta_kinetic == pytest.approx(-0.5 * MASS * (v_hit @ normal) ** 2, rel=1e-6)
    assert plant.impact_energy == taut_event.delta_kinetic
    assert_event_log_consistent(plant, [True])
    # after it, taut again: the string pulls and the ball stays on the sphere
    after = t > taut_event.t + H
    np.testing.assert_allclose(np.linalg.norm(p[after] - HOOK, axis=1), LENGTH, atol=1e-9)
    assert (tensions[after[:-1]] > 0).all()

    # (d) energy: no inputs, a fixed hook, no damping: T + U − impacts is constant to RK4's accuracy
    # over the whole run, across both transitions
    balance = energy_balance(plant, states)
    balance[t > taut_event.t] -= plant.impact_energy
    scale = MASS * v0**2 / 2
    assert np.abs(balance - balance[0]).max() < 1e-7 * scale  # seen: 7e-9 · scale
    assert abs(taut_event.delta_kinetic) > 0.5 * scale  # (so an impact left out could not hide)


def test_a_radial_throw_loses_all_its_radial_velocity(ball):
    """Thrown straight up at v0 from the bottom: slack at once (the ball moves towards the hook),
    back at the bottom at exactly 2 v0 / g with −v0, and the inelastic impact stops it dead:
    T⁺ = 0, ΔT = −½ m v0². Then it hangs at rest with tension m g."""
    v0 = 2.0
    t, states, tensions, plant = throw(ball, np.array([0.0, 0.0, v0]), 0.6)
    n = plant.n
    slack_event, taut_event = plant.events
    assert (slack_event.kind, slack_event.t) == ("slack", 0.0)
    assert taut_event.kind == "taut"
    assert taut_event.t == pytest.approx(2 * v0 / G, abs=1e-9)
    assert taut_event.delta_kinetic == pytest.approx(-0.5 * MASS * v0**2, rel=1e-9)
    assert_event_log_consistent(plant, [True])
    flying = t <= taut_event.t
    np.testing.assert_allclose(states[flying, 2], HOOK[2] - LENGTH + v0 * t[flying] - 0.5 * G * t[flying] ** 2,
                               atol=1e-9, rtol=0)
    after = t > taut_event.t
    assert np.abs(states[after, n : 2 * n]).max() < 1e-9  # at rest: no radial velocity left, nothing else
    assert np.abs(states[after, :3] - (HOOK - [0.0, 0.0, LENGTH])).max() < 1e-9
    np.testing.assert_allclose(tensions[after[:-1]][1:], MASS * G, rtol=1e-9)


def assert_event_log_consistent(plant, started_taut):
    """The plant's event log against its own bookkeeping: every event is "slack" or "taut"; each cable's events
    alternate, from the opposite of how it started; `transitions` counts them; the kinetic energy the events
    carry adds up to `impact_energy`; times do not go back (beyond rounding: an event's time is the substep's start
    plus a fraction of it, and two events microseconds apart get it by different sums)."""
    assert all(e.kind in ("slack", "taut") for e in plant.events), {e.kind for e in plant.events}
    for c, taut in enumerate(started_taut):
        kinds = [e.kind for e in plant.events if e.cable == c]
        expected = ["slack", "taut"] if taut else ["taut", "slack"]
        assert kinds == [expected[i % 2] for i in range(len(kinds))], (c, kinds)
        assert plant.transitions[c] == len(kinds)
    assert sum(e.delta_kinetic for e in plant.events) == pytest.approx(plant.impact_energy, rel=1e-12, abs=1e-15)
    times = np.array([e.t for e in plant.events])
    assert (np.diff(times) >= -1e-12 * np.maximum(1.0, np.abs(times[1:]))).all()


@pytest.mark.parametrize("degrees", [0.0, 60.0, 89.0, 91.0, 120.0, 175.0])
def test_probe_gives_the_strings_closed_form_tension_and_never_a_pushing_one(ball, degrees):
    """The ball at rest on its sphere at θ from the bottom: the string's tension is m g cos θ while that pulls
    (θ < 90°); beyond, a string would push, so probe marks it slack, says so in the event log, and reports 0.
    The state is kept as it was."""
    model, plant = ball
    theta = math.radians(degrees)
    q0 = np.concatenate([HOOK + LENGTH * np.array([math.sin(theta), 0.0, -math.cos(theta)]), np.eye(3).reshape(-1)])
    x = plant.initial_state(q0)
    assert plant.start_active[0] == 1.0  # at the string's length: starts taut
    kept = x.copy()
    plant.probe(x, np.zeros(1), 0.25)
    np.testing.assert_array_equal(x, kept)
    if degrees < 90.0:
        assert plant.start_active[0] == 1.0 and plant.events == []
        assert plant.start_tension[0] == pytest.approx(MASS * G * math.cos(theta), rel=1e-9, abs=1e-9 * MASS * G)
    else:
        assert plant.start_active[0] == 0.0 and plant.start_tension[0] == 0.0
        assert [(e.t, e.cable, e.kind, e.delta_kinetic) for e in plant.events] == [(0.25, 0, "slack", 0.0)]
        assert_event_log_consistent(plant, [True])


@pytest.mark.parametrize("steps", [200, 137])
def test_a_return_to_contact_exactly_at_a_step_boundary_is_still_the_impact(ball, steps):
    """Thrown up at v0 = g·steps·H/2, the ball is back at the bottom exactly at the end of a step (RK4 is exact on
    the parabola): it ends that step at contact without stretch, and starts the next one stretching the slack
    string at once, the rare case of an impact at the start of a step. The answer is the radial throw's: taut at
    2 v0/g, ΔT = −½ m v0², then at rest."""
    v0 = G * steps * H / 2
    t, states, tensions, plant = throw(ball, np.array([0.0, 0.0, v0]), (steps + 20) * H)
    n = plant.n
    slack_event, taut_event = plant.events
    assert (slack_event.kind, slack_event.t, taut_event.kind) == ("slack", 0.0, "taut")
    assert taut_event.t == pytest.approx(2 * v0 / G, abs=1e-9)
    assert taut_event.delta_kinetic == pytest.approx(-0.5 * MASS * v0**2, rel=1e-9)
    after = t > taut_event.t + 1e-9
    assert np.abs(states[after, n : 2 * n]).max() < 1e-9
    assert np.abs(states[after, :3] - (HOOK - [0.0, 0.0, LENGTH])).max() < 1e-9
    assert_event_log_consistent(plant, [True])


MOVING_LENGTH = 1.3  # m: not 1, where L², L³ and L·2... would coincide (the generated gap φ/(√(φ + L²) + L))


@pytest.fixture(scope="module")
def moving_hook(tmp_path_factory):
    """The ball on its string from a hook that moves along x with the path (0.3 m in about a second, from rest to
    rest): the plant's stage signals then matter inside a step, at the fractions of it where events are located
    and resolved."""
    ball = {**BALL["bodies"][0], "initial_position": [0.0, 0.0, 2.0 - MOVING_LENGTH]}
    return ball_on_a_string(tmp_path_factory, {
        **BALL, "name": "cable_ball_moving_hook", "bodies": [ball],
        "anchors": [{"name": "hook", "position": [0.0, 0.0, 2.0], "follows_path": ["x"]}],
        "cables": [{**BALL["cables"][0], "length": MOVING_LENGTH}],
        "path": {"waypoints": [[0.0, 0.0, 0.0], [0.3, 0.0, 0.0]], "mean_speed": 0.3}})


def test_a_throw_under_a_moving_hook_flies_and_snaps_taut_where_the_closed_form_says(moving_hook):
    """Thrown straight up from under the hook at rest: slack at once, the ball flies on its parabola (the hook's
    motion does not touch it) until |p(t) − hook(t)| = L, with hook(t) from the path's own formula (brentq). The
    inelastic impact with a hook moving at v_h removes the relative velocity along the string:
    v⁺ = v⁻ − ((v⁻ − v_h)·n) n. Afterwards the string stays at its length from the moving hook. A step that
    located or finished an event with the hook's signals of other instants fails all three."""
    model, path, plant = moving_hook
    start = path.position(0.0)[0]

    def hook(t):
        return HOOK + np.array([path.position(t)[0][0] - start[0], 0.0, 0.0])

    v0, length, steps = 2.0, MOVING_LENGTH, 300
    t, states, _, gaps = unforced_flight(plant, np.array([0.0, 0.0, v0]), steps, length)
    slack_event, taut_event = plant.events
    assert (slack_event.kind, slack_event.t, taut_event.kind) == ("slack", 0.0, "taut")
    p0, vel0 = HOOK - [0.0, 0.0, length], np.array([0.0, 0.0, v0])

    def ball(tau):
        return p0 + vel0 * tau + 0.5 * GRAVITY * tau**2

    def gap(tau):
        return np.linalg.norm(ball(tau) - hook(tau)) - length

    t_taut = brentq(gap, 0.3, 0.5, xtol=1e-15, rtol=1e-15)
    assert abs(hook(t_taut)[0] - HOOK[0]) > 0.05  # the hook has moved by then, and is moving
    v_hook = np.array([path.position(t_taut)[1][0], 0.0, 0.0])
    assert abs(v_hook[0]) > 0.1
    assert taut_event.t == pytest.approx(t_taut, abs=1e-9)
    v_minus = vel0 + GRAVITY * t_taut
    normal = (ball(t_taut) - hook(t_taut)) / length
    v_plus = v_minus - ((v_minus - v_hook) @ normal) * normal
    assert taut_event.delta_kinetic == pytest.approx(0.5 * MASS * (v_plus @ v_plus - v_minus @ v_minus), rel=1e-6)
    flying = t <= taut_event.t
    np.testing.assert_allclose(states[flying, :3], [ball(tau) for tau in t[flying]], atol=1e-9, rtol=0)
    # the plant's reported gap |p − hook| − L, while the string is slack: centimetres below contact
    np.testing.assert_allclose(gaps[flying], [gap(tau) for tau in t[flying]], atol=1e-9, rtol=0)
    assert min(gaps) < -0.05
    after = t > taut_event.t
    lengths = [np.linalg.norm(states[k, :3] - hook(t[k])) for k in np.flatnonzero(after)]
    np.testing.assert_allclose(lengths, length, atol=1e-9, rtol=0)
    assert_event_log_consistent(plant, [True])
    events = list(plant.events)
    # a hand-made table (a plain array of the same rows) and a view of the table start at t = 0 as documented:
    # the same run to the bit
    table = plant.stage_table(0.0, H, steps)
    for other in (np.array(table), table[:]):
        x = plant.initial_state(states[0, : plant.n], states[0, plant.n : 2 * plant.n])
        for i in range(steps):
            plant.advance(x, np.zeros(1), H, other, i, 1)
        np.testing.assert_array_equal(x, states[-1])
        assert plant.events == events


# --- (c) the taut crane under MLM is the rigid plant ---------------------------------------------------


def test_the_taut_crane_under_mlm_is_the_rigid_plant(crane):
    spec, model, path, start = crane
    n = model.layout.n
    plant = setup_default(model, path)
    controller = make_controller("mlm", model, path, Gains.from_spec(spec))
    result = simulate(model, path, controller, plant, start.q, path.duration, spec.controller.rate_hz,
                      spec.simulation.step, energy=True)
    assert result.t[-1] == pytest.approx(path.duration)
    # the whole 55 s: no cable ever went slack, no impact, every tension pulls
    assert (result.cable_active == 1).all()
    assert result.cable_transitions.sum() == 0 and plant.events == []
    assert (result.energy["impacts"] == 0).all()
    assert result.cable_tension.min() > 20.0  # winches ~26.7 N, main cable ~177 N
    np.testing.assert_allclose(result.cable_tension[:, 1:], result.u[:, :3], rtol=1e-3)  # tension ≈ command
    s = summarize(result, Scenario.from_model(model), model.layout)
    assert all(c["time_slack_s"] == 0 and c["transitions"] == 0 for c in s["cables"].values())

    # the first second against the rigid DAE under solve_ivp with the same held inputs, to 1 µm
    sim = spec.simulation
    period = 1.0 / spec.controller.rate_hz
    x = np.concatenate([start.q, np.zeros(n)])
    worst = 0.0
    for k in range(50):
        ref = solve_ivp(rigid_plant_rhs(model, path, result.u[k], sim.baumgarte_zeta, sim.baumgarte_omega),
                        (k * period, (k + 1) * period), x, method="DOP853", rtol=1e-11, atol=1e-12)
        assert ref.success
        x = ref.y[:, -1]
        worst = max(worst, np.abs(result.q[k + 1] - x[:n]).max())
    assert np.abs(result.q[50] - start.q).max() > 1e-5  # it moved
    assert worst < 1e-6  # seen: 1.4e-12 m


# --- (d) energy across transitions on the crane ---------------------------------------------------------


def pay_out_then_pull_in(crane, h):
    """The crane with the winches paying out (u = −50 N) for 20 ms, then pulling in (u = 100 N) for
    0.98 s: slack cables, re-tension impacts (the drums spin out at 20 m/s), the main cable going
    slack and taut. Returns the energy balance at every control instant and the plant."""
    spec, model, path, start = crane
    n = model.layout.n
    plant = setup_default(model, path)
    x = plant.initial_state(start.q)
    sub = round(0.02 / h)
    table = plant.stage_table(0.0, h, 50 * sub)
    balance = []
    for k in range(50):
        u = start.inputs.copy()
        u[:3], u[3:] = (-50.0 if k == 0 else 100.0), 0.0
        balance.append(plant.mechanical_energy(x[:n], x[n : 2 * n])
                       - (x[2 * n] + x[2 * n + 1] - x[2 * n + 2] + plant.impact_energy))
        plant.advance(x, u, h, table, k * sub, sub)
    return np.array(balance), plant


def test_energy_balance_across_slack_and_taut_transitions(crane):
    balance, plant = pay_out_then_pull_in(crane, 0.002)
    kinds = {(e.cable, e.kind) for e in plant.events}
    assert {(1, "slack"), (1, "taut"), (0, "slack"), (0, "taut")} <= kinds  # winch and main cable both switch
    impacts = [e for e in plant.events if e.kind == "taut"]
    assert len(impacts) >= 4
    # every impact takes energy out (the climbing unit moves at under 1e-3 m/s here; ΔT is tens of J)
    total = sum(e.delta_kinetic for e in plant.events)
    assert all(e.delta_kinetic <= 0 for e in plant.events)
    assert total == pytest.approx(plant.impact_energy, rel=1e-12)
    assert plant.impact_energy < -50.0
    assert_event_log_consistent(plant, [True] * len(plant.cable_names))
    # the balance holds to the integrator's accuracy: its drift shrinks as h⁴ (RK4), so it is
    # truncation error, not a term left out (which would not shrink, and is ≥ 0.2 J here)
    drift = np.abs(balance - balance[0]).max()
    assert drift < 1e-4
    balance_half, plant_half = pay_out_then_pull_in(crane, 0.001)
    assert [(e.cable, e.kind) for e in plant_half.events] == [(e.cable, e.kind) for e in plant.events]
    drift_half = np.abs(balance_half - balance_half[0]).max()
    assert 8 < drift / drift_half < 32


def test_the_non_collocated_crane_under_mlm_keeps_its_cables_consistent():
    """acroboter_4input under MLM: its zero dynamics swing up (docs/studies.md, "The non-collocated four-input
    crane"), and from about 24.7 s the winch cables go slack and snap taut dozens of times, some in
    cascades microseconds apart (a slack cable's drum reels in at u/I_r ≈ 600 m/s²). Oracles: the
    complementarity at every instant (a taut cable pulls, a slack one carries nothing and is not
    stretched), the energy balance across all of it with a drift that shrinks like h⁴, and no impact
    that adds energy (beyond round-off; the climbing unit barely moves)."""
    spec = load_spec(REPO / "model_spec" / "acroboter_4input.toml")
    model = load_model(spec)
    path = desired_path(model)
    start = solve_equilibrium(model, path)
    rows = [model.layout.constraints.index(f"cable {c.name}") for c in spec.cables]
    drifts = []
    for h in (0.002, 0.001):
        plant = setup_default(model, path)
        controller = make_controller("mlm", model, path, Gains.from_spec(spec))
        result = simulate(model, path, controller, plant, start.q, 28.5, spec.controller.rate_hz, h, energy=True)
        assert result.cable_transitions.sum() > 10
        assert np.abs(result.cable_gap[0]).max() < 1e-12  # the start's gaps, recorded before any step: at length
        assert np.isfinite(result.cable_gap).all()
        taut = result.cable_active == 1
        assert result.cable_tension[taut].min() >= -plant.tension_tol
        assert (result.cable_tension[~taut] == 0).all()
        phi = result.phi[:, rows]  # |d|² − L²: > 0 stretched
        assert phi[~taut].max() < 1e-9 and np.abs(phi[taut]).max() < 1e-8
        assert max(e.delta_kinetic for e in plant.events) < 1e-9
        assert_event_log_consistent(plant, [True] * len(plant.cable_names))
        e = result.energy
        balance = e["mechanical"] - (e["work_inputs"] + e["work_anchors"] - e["dissipated"] + e["impacts"])
        drifts.append(np.abs(balance - balance[0]).max())
        scale = np.abs(e["work_inputs"]).max()
    assert drifts[0] < 2e-8 * scale  # seen: 6e-9 · scale (3.8e-7 J)
    assert drifts[1] < drifts[0] / 4  # truncation error, not a term left out


def _flight_at(plant, velocity, h: float, seconds: float) -> np.ndarray:
    """The ball from the bottom of its string with a velocity, unforced, in steps of h: the state after each."""
    q0 = np.concatenate([HOOK - [0.0, 0.0, LENGTH], np.eye(3).reshape(-1)])
    x = plant.initial_state(q0, np.concatenate([velocity, np.zeros(9)]))
    steps = round(seconds / h)
    table = plant.stage_table(0.0, h, steps)
    states = []
    for i in range(steps):
        plant.advance(x, np.zeros(1), h, table, i, 1)
        states.append(x.copy())
    return np.array(states)


def test_a_refined_period_leaves_nothing_of_the_attempts_it_undid(ball, monkeypatch):
    """Every period forced to refine (REFINE_RATE < 0: none holds, so each is flown at H, H/2, H/4, H/8 and kept at
    H/16, acroboter.sim.plant_refinement): the attempts undone leave nothing behind. The whirl's event log, its
    bookkeeping and its end state are those of the same flight at H/16 with nothing refined, and the C and Python
    substep loops give the same states, bit for bit."""
    from acroboter.sim import plant_refinement

    _, plant = ball
    velocity = np.array([math.sqrt(3.5 * G * LENGTH), 0.0, 0.0])
    reference = _flight_at(plant, velocity, H / 16, 1.4)
    expected = [(e.t, e.kind, e.delta_kinetic) for e in plant.events]
    assert plant.refined_periods == 0 and [k for _, k, _ in expected] == ["slack", "taut"]
    monkeypatch.setattr(plant_refinement, "REFINE_RATE", -1.0)
    runs = {}
    for compiled in (True, False):
        plant.use_compiled_loop(compiled)
        try:
            runs[compiled] = _flight_at(plant, velocity, H, 1.4)
        finally:
            plant.use_compiled_loop(True)
        assert plant.refined_periods == round(1.4 / H) and plant.finest_step == H / 16
        assert [k for _, k, _ in ((e.t, e.kind, 0) for e in plant.events)] == ["slack", "taut"]
        for (t, kind, delta), event in zip(expected, plant.events, strict=True):
            assert abs(event.t - t) < 1e-9 and event.kind == kind
            assert event.delta_kinetic == pytest.approx(delta, rel=1e-6)
        assert_event_log_consistent(plant, [True])
    np.testing.assert_array_equal(runs[True], runs[False])
    np.testing.assert_allclose(runs[True][-1], reference[-1], rtol=0, atol=1e-9)
