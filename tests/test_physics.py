"""Physics of the compiled model, on every shipped spec: what must hold whatever the numbers are.

Signals are s = [moving anchors' xyz | x_d, y_d, z_d, yaw_d] (acroboter.model.layout). At the start the
anchor sits at its spec position and the targets are the tracked point's initial position, yaw 0.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import Crane
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from acroboter.model.layout import body_rotation
from acroboter.model.spec import BodyThrust, BodyTorque, PositionTask, WinchTension

AXIS = {"u": 0, "v": 1, "w": 2}


def random_state(crane: Crane, rng: np.random.Generator, spread: float = 0.05):
    """A state near the start that satisfies no constraint exactly: q, qd, s, sd, sdd."""
    lay = crane.layout
    q = crane.q0 + spread * rng.standard_normal(lay.n)
    s = crane.s0 + spread * rng.standard_normal(lay.n_signals)
    return q, rng.standard_normal(lay.n), s, rng.standard_normal(lay.n_signals), rng.standard_normal(lay.n_signals)


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    a, _ = np.linalg.qr(rng.standard_normal((3, 3)))
    return a * np.sign(np.linalg.det(a))  # a proper rotation


def body_slices(crane: Crane, body: str) -> tuple[slice, list[slice]]:
    i = crane.layout.body_offset[body]
    return slice(i, i + 3), [slice(i + 3 * k, i + 3 * k + 3) for k in (1, 2, 3)]


def anchor_signal_slices(crane: Crane) -> list[slice]:
    return [slice(j, j + 3) for j in crane.layout.anchor_signal.values()]


# --- mass matrix ---------------------------------------------------------------------------------


def test_mass_matrix_is_symmetric_positive_definite_and_constant(crane):
    rng = np.random.default_rng(1)
    m0 = crane.term("mass_matrix")
    assert m0.shape == (crane.layout.n, crane.layout.n)
    np.testing.assert_array_equal(m0, m0.T)
    assert np.linalg.eigvalsh(m0).min() > 0
    for _ in range(2):
        np.testing.assert_array_equal(crane.term("mass_matrix", *random_state(crane, rng, spread=1.0)), m0)


def test_mass_matrix_carries_each_body_mass_and_winch_inertia(crane):
    m = crane.term("mass_matrix")
    for body in crane.spec.bodies:
        r, _ = body_slices(crane, body.name)
        np.testing.assert_array_equal(m[r, r], body.mass * np.eye(3))
    for cable in crane.spec.cables:
        if cable.winch is not None:
            i = crane.layout.winch_index[cable.name]
            assert m[i, i] == cable.winch.reflected_inertia


def test_bias_force_at_rest_is_the_weight(crane):
    """c(q, 0) = dU/dq: -m g on each centre of mass, nothing else (damping vanishes at rest)."""
    rng = np.random.default_rng(2)
    q, _, s, _, _ = random_state(crane, rng)
    c = crane.term("bias_forces", q=q, s=s)
    expected = np.zeros(crane.layout.n)
    for body in crane.spec.bodies:
        r, _ = body_slices(crane, body.name)
        expected[r] = -body.mass * np.array(crane.spec.gravity)
    np.testing.assert_allclose(c, expected, rtol=0, atol=1e-12)


# --- constraints ------------------------------------------------------------------------------------


def test_constraints_and_task_hold_at_the_nominal_start(crane):
    np.testing.assert_allclose(crane.term("phi"), 0.0, atol=1e-12)
    np.testing.assert_allclose(crane.term("sigma"), 0.0, atol=1e-12)


def test_a_disturbed_start_violates_the_constraints(crane):
    """The check above can fail: lower the SU by 1 cm and the cables no longer fit."""
    q = crane.q0.copy()
    r, _ = body_slices(crane, crane.spec.task[0].body)
    q[r.start + 2] -= 0.01
    assert np.abs(crane.term("phi", q=q)).max() > 1e-3


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_translating_the_whole_crane_keeps_the_constraints(crane, seed):
    """Everything, moving anchors included, translates with v: phi_dot = phi_q qd + phi_s sd = 0."""
    if any(a.name not in crane.layout.anchor_signal for a in crane.spec.anchors):
        pytest.skip("a fixed anchor cannot translate")
    rng = np.random.default_rng(seed)
    q, _, s, _, _ = random_state(crane, rng)
    v = rng.standard_normal(3)
    qd, sd = np.zeros(crane.layout.n), np.zeros(crane.layout.n_signals)
    for body in crane.spec.bodies:
        qd[body_slices(crane, body.name)[0]] = v
    for sl in anchor_signal_slices(crane):
        sd[sl] = v
    np.testing.assert_allclose(crane.term("phi_dot", q=q, qd=qd, s=s, sd=sd), 0.0, atol=1e-12)
    sd[:] = 0  # the anchor left behind: the main cable stretches
    assert np.abs(crane.term("phi_dot", q=q, qd=qd, s=s, sd=sd)).max() > 1e-3


@pytest.mark.parametrize("axis", ["vertical", "random"])
def test_rotating_the_crane_about_its_anchor_keeps_the_constraints(crane, axis):
    """A rigid rotation about an axis through the (fixed) anchor: r' = w x (r - A), e' = w x e, L' = 0.

    The orthonormality and cable rows are rotation invariant everywhere; a redundant row w − u×v is
    only covariant (its rate is ω × (w − u×v)), so it is checked where it holds: proper rotations.
    """
    rng = np.random.default_rng(3)
    q, _, s, _, _ = random_state(crane, rng)
    if crane.layout.redundant_rows:
        oriented = _oriented_state(crane, rng)
        for body in crane.spec.bodies:  # random positions, proper orthonormal axes
            r, _ = body_slices(crane, body.name)
            oriented[r] = q[r]
        q = oriented
    [anchor] = anchor_signal_slices(crane) or [None]
    centre = s[anchor] if anchor is not None else np.array(crane.spec.anchors[0].position)
    omega = np.array([0.0, 0.0, 0.7]) if axis == "vertical" else rng.standard_normal(3)
    qd = np.zeros(crane.layout.n)
    for body in crane.spec.bodies:
        r, axes = body_slices(crane, body.name)
        qd[r] = np.cross(omega, q[r] - centre)
        for e in axes:
            qd[e] = np.cross(omega, q[e])
    np.testing.assert_allclose(crane.term("phi_dot", q=q, qd=qd, s=s), 0.0, atol=1e-12)
    stretched = qd.copy()  # not rigid: the tracked body's centre moves 10 % faster than the rest
    r, _ = body_slices(crane, crane.spec.task[0].body)
    stretched[r] *= 1.1
    assert np.abs(crane.term("phi_dot", q=q, qd=stretched, s=s)).max() > 1e-4


# --- actuators: virtual work -------------------------------------------------------------------------


def _oriented_state(crane: Crane, rng: np.random.Generator) -> np.ndarray:
    """q0 with every body turned to a random orientation (orthonormal axes)."""
    q = crane.q0.copy()
    for body in crane.spec.bodies:
        _, axes = body_slices(crane, body.name)
        rot = random_rotation(rng)
        for k, e in enumerate(axes):
            q[e] = rot[:, k]
    return q


def _body_displacement(crane: Crane, q: np.ndarray, body: str, dr, dtheta) -> np.ndarray:
    """dq of a small rigid displacement of one body: dr of its centre, rotation dtheta of its axes."""
    dq = np.zeros(crane.layout.n)
    r, axes = body_slices(crane, body)
    dq[r] = dr
    for e in axes:
        dq[e] = np.cross(dtheta, q[e])
    return dq


@pytest.mark.parametrize("seed", [0, 1])
def test_torque_actuator_does_virtual_work_n_dot_dtheta(crane, seed):
    rng = np.random.default_rng(seed)
    q = _oriented_state(crane, rng)
    h = crane.term("input_matrix", q=q)
    torques = [(j, a) for j, a in enumerate(crane.spec.actuators) if isinstance(a, BodyTorque)]
    assert torques
    for j, act in torques:
        dtheta, dr, tau = 1e-3 * rng.standard_normal(3), 1e-3 * rng.standard_normal(3), 2.5
        n = tau * q[body_slices(crane, act.body)[1][AXIS[act.axis]]]
        work = tau * h[:, j] @ _body_displacement(crane, q, act.body, np.zeros(3), dtheta)
        assert work == pytest.approx(n @ dtheta, rel=1e-12, abs=1e-15)
        assert h[:, j] @ _body_displacement(crane, q, act.body, dr, np.zeros(3)) == 0.0  # no work on translation
        others = np.ones(crane.layout.n, bool)
        others[body_slices(crane, act.body)[1][0].start : body_slices(crane, act.body)[1][2].stop] = False
        assert not h[others, j].any()  # acts on the body's axes only


@pytest.mark.parametrize("seed", [0, 1])
def test_thrust_actuator_does_virtual_work_f_dot_dr(crane, seed):
    rng = np.random.default_rng(seed)
    q = _oriented_state(crane, rng)
    h = crane.term("input_matrix", q=q)
    thrusts = [(j, a) for j, a in enumerate(crane.spec.actuators) if isinstance(a, BodyThrust)]
    if not thrusts:
        pytest.skip(f"spec {crane.spec.name} has no thrust actuator")
    for j, act in thrusts:
        dr, dtheta, f = 1e-3 * rng.standard_normal(3), 1e-3 * rng.standard_normal(3), 3.0
        _, axes = body_slices(crane, act.body)
        force = f * q[axes[AXIS[act.axis]]]
        arm = sum(x * q[e] for x, e in zip(act.point, axes, strict=True))  # world offset of the point of action
        work = f * h[:, j] @ _body_displacement(crane, q, act.body, dr, dtheta)
        assert work == pytest.approx(force @ (dr + np.cross(dtheta, arm)), rel=1e-12, abs=1e-15)


def test_winch_tension_pulls_the_cable_in(crane):
    h = crane.term("input_matrix")
    for j, act in enumerate(crane.spec.actuators):
        if isinstance(act, WinchTension):
            expected = np.zeros(crane.layout.n)
            expected[crane.layout.winch_index[act.cable]] = -1.0  # u dL < 0 when L grows against the tension
            np.testing.assert_array_equal(h[:, j], expected)


# --- statics ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("crane", ["acroboter"], indirect=True)
def test_winch_tensions_balance_gravity_at_the_start(crane):
    """Least squares over (lambda, u) of phi_q^T lambda - H u = -c at q0, qd = 0: the SU hangs on its winches."""
    spec, lay = crane.spec, crane.layout
    phi_q, h, c = crane.term("phi_q"), crane.term("input_matrix"), crane.term("bias_forces")
    system = np.hstack([phi_q.T, -h])
    assert np.linalg.matrix_rank(system) == system.shape[1]  # the balance is unique
    x, *_ = np.linalg.lstsq(system, -c, rcond=None)
    lam, u = x[: lay.m], x[lay.m :]
    np.testing.assert_allclose(system @ x, -c, atol=1e-9)  # an exact equilibrium, not a fit

    # analytic: the SU's weight on three equal cables, each rising `drop` over its length L_i
    su = spec.body("SU")
    g = -spec.gravity[2]
    winches = [(j, a) for j, a in enumerate(spec.actuators) if isinstance(a, WinchTension)]
    assert len(winches) == 3
    for j, act in winches:
        cable = next(cb for cb in spec.cables if cb.name == act.cable)
        top, bottom = (_world_point(crane, end) for end in cable.ends)
        drop, length = top[2] - bottom[2], np.linalg.norm(top - bottom)
        assert drop == pytest.approx(0.70, abs=1e-12) and crane.q0[lay.winch_index[cable.name]] == length
        assert u[j] == pytest.approx(su.mass * g * length / (3 * drop), rel=1e-9)
        assert f"{u[j]:.4g}" == "26.75"  # docs/model.md §9
        i = lay.constraints.index(f"cable {cable.name}")
        assert u[j] == pytest.approx(2 * length * lam[i], rel=1e-9)  # u_i = 2 L_i lambda_i
    for j, act in enumerate(spec.actuators):
        if not isinstance(act, WinchTension):
            assert abs(u[j]) < 1e-9, act.name  # the fans do nothing at rest
    main = next(cb for cb in spec.cables if cb.winch is None)
    lam_main = lam[lay.constraints.index(f"cable {main.name}")]
    assert 2 * main.length * lam_main == pytest.approx(sum(b.mass for b in spec.bodies) * g, rel=1e-9)


def _world_point(crane: Crane, end: str) -> np.ndarray:
    body_name, point = end.split(".")
    body = crane.spec.body(body_name)
    return np.array(body.initial_position) + body_rotation(body.initial_yaw_deg) @ np.array(body.point(point))


# --- derivatives against finite differences ----------------------------------------------------------

state = st.integers(0, 2**32 - 1)


def _central(f, h):
    return (f(h) - f(-h)) / (2 * h)


def _jacobian_fd(crane, name: str, q: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Central finite differences of a model term in q, one column per coordinate."""
    n = crane.layout.n
    return np.column_stack([
        _central(lambda t, k=k: crane.term(name, q=q + t * np.eye(n)[k], s=s), 1e-6) for k in range(n)
    ])


def _assert_close(got, want, rel=1e-6):
    scale = max(np.abs(want).max(), 1.0)
    np.testing.assert_allclose(got, want, rtol=0, atol=rel * scale)


@settings(max_examples=8, deadline=None)
@given(data=st.data())
def test_phi_q_matches_finite_differences(crane, data):
    n, ns = crane.layout.n, crane.layout.n_signals
    q = crane.q0 + data.draw(hnp.arrays(np.float64, n, elements=st.floats(-0.3, 0.3)), label="q - q0")
    s = crane.s0 + data.draw(hnp.arrays(np.float64, ns, elements=st.floats(-0.3, 0.3)), label="s - s0")
    _assert_close(crane.term("phi_q", q=q, s=s), _jacobian_fd(crane, "phi", q, s))


@settings(max_examples=8, deadline=None)
@given(seed=state)
def test_sigma_q_matches_finite_differences(crane, seed):
    rng = np.random.default_rng(seed)
    q, _, s, _, _ = random_state(crane, rng, spread=0.3)
    _assert_close(crane.term("sigma_q", q=q, s=s), _jacobian_fd(crane, "sigma", q, s))


@settings(max_examples=8, deadline=None)
@given(seed=state)
def test_velocity_and_acceleration_terms_match_finite_differences_in_time(crane, seed):
    """Along q(t) = q + t qd (qdd = 0), s(t) = s + t sd + t^2/2 sdd: d/dt phi = phi_dot, d/dt phi_dot = gamma."""
    rng = np.random.default_rng(seed)
    q, qd, s, sd, sdd = random_state(crane, rng, spread=0.3)

    def at(name, t):
        return crane.term(name, q=q + t * qd, qd=qd, s=s + t * sd + 0.5 * t * t * sdd, sd=sd + t * sdd, sdd=sdd)

    h = 1e-5
    for value, rate, accel in (("phi", "phi_dot", "gamma"), ("sigma", "sigma_dot", "gamma_s")):
        _assert_close(at(rate, 0.0), _central(lambda t, n=value: at(n, t), h))
        _assert_close(at(accel, 0.0), _central(lambda t, n=rate: at(n, t), h))


def test_tracked_point_is_the_position_task(crane):
    """sigma_1..3 = r_SU - r_d: moving the target by d moves sigma by -d."""
    task = next(t for t in crane.spec.task if isinstance(t, PositionTask))
    p = crane.layout.path_signal
    s = crane.s0.copy()
    s[p : p + 3] += [0.01, -0.02, 0.03]
    np.testing.assert_allclose(crane.term("sigma", s=s)[:3], [-0.01, 0.02, -0.03], atol=1e-15)
    assert task.body in crane.layout.body_offset
