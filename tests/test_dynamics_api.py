"""The dynamics terms as public API (crane.mass_matrix, bias_forces, input_matrix, constraints,
constraint_jacobian, servo_error, servo_jacobian), each against an oracle that shares no code
with the generated model: the closed-form mass matrix of natural coordinates from the spec's numbers,
gravity at rest, central finite differences for the Jacobians, the static equilibrium's balance, and
a displacement of the tracked point read back as the task's error."""

from __future__ import annotations

import numpy as np
import pytest

from acroboter import Crane

GRAVITY = 9.81


@pytest.fixture(scope="module", params=["acroboter", "lab_crane", "acroboter_4cable"])
def crane(request):
    return Crane.from_example(request.param)


def test_mass_matrix_is_the_closed_form_of_natural_coordinates(crane):
    """Per body [[m I3, 0], [0, J ⊗ I3]] with J = ½ tr(I_G) E − I_G on (u, v, w); the drums' reflected
    inertia on the winch lengths; nothing else (docs/model.md §2)."""
    lay = crane.layout
    expected = np.zeros((lay.n, lay.n))
    for body in crane.spec.bodies:
        i = lay.body_offset[body.name]
        inertia = np.array(body.inertia, dtype=float)
        j = 0.5 * np.trace(inertia) * np.eye(3) - inertia
        block = np.kron(np.block([[np.array([[body.mass]]), np.zeros((1, 3))], [np.zeros((3, 1)), j]]), np.eye(3))
        expected[i : i + 12, i : i + 12] = block
    for cable in crane.spec.cables:
        if cable.winch is not None:
            k = lay.winch_index[cable.name]
            expected[k, k] = cable.winch.reflected_inertia
    q = crane.equilibrium().q
    np.testing.assert_allclose(crane.mass_matrix(q), expected, rtol=1e-12, atol=1e-12)


def test_bias_forces_at_rest_are_gravity(crane):
    lay = crane.layout
    q = crane.equilibrium().q
    c = crane.bias_forces(q, np.zeros(lay.n))
    gravity = np.asarray(crane.spec.gravity, dtype=float)
    expected = np.zeros(lay.n)
    for body in crane.spec.bodies:
        i = lay.body_offset[body.name]
        expected[i : i + 3] = -body.mass * gravity  # ∂U/∂r = −m g
    np.testing.assert_allclose(c, expected, rtol=1e-12, atol=1e-9)
    assert abs(np.linalg.norm(gravity) - GRAVITY) < 1e-9


def test_the_static_start_balances(crane):
    """At the static equilibrium: c = H u − φ_qᵀ λ, φ = 0, σ = 0."""
    start = crane.equilibrium()
    q, lay = start.q, crane.layout
    balance = crane.input_matrix(q) @ start.inputs - crane.constraint_jacobian(q).T @ start.multipliers
    np.testing.assert_allclose(crane.bias_forces(q, np.zeros(lay.n)), balance, atol=1e-8)
    assert np.abs(crane.constraints(q)).max() < 1e-9
    assert np.abs(crane.servo_error(q)).max() < 1e-9


def test_jacobians_are_the_derivatives_of_their_functions(crane):
    """Central differences (h = 1e-6) of φ and σ at a perturbed, moving state."""
    rng = np.random.default_rng(5)
    q = crane.equilibrium().q + 1e-3 * rng.normal(size=crane.layout.n)
    t, h = 3.7, 1e-6
    for function, jacobian in ((crane.constraints, crane.constraint_jacobian),
                               (crane.servo_error, crane.servo_jacobian)):
        numeric = np.column_stack([(function(q + h * e, t) - function(q - h * e, t)) / (2 * h)
                                   for e in np.eye(crane.layout.n)])
        np.testing.assert_allclose(jacobian(q, t), numeric, atol=1e-7)


def test_servo_constraints_read_a_displacement_of_the_tracked_point(crane):
    lay = crane.layout
    task = next(t for t in crane.spec.task if t.kind == "position")
    q = crane.equilibrium().q.copy()
    shift = np.array([0.01, -0.02, 0.005])
    i = lay.body_offset[task.body]
    q[i : i + 3] += shift
    np.testing.assert_allclose(crane.servo_error(q)[:3], shift, atol=1e-9)


def test_a_winch_input_pulls_on_its_length_coordinate():
    crane = Crane.from_example("acroboter")
    lay = crane.layout
    h = crane.input_matrix(crane.equilibrium().q)
    assert h.shape == (lay.n, lay.l)
    for k, cable in enumerate(("L1", "L2", "L3")):
        column = np.zeros(lay.n)
        column[lay.winch_index[cable]] = -1.0  # u > 0 pulls the cable in (docs/model.md §4)
        np.testing.assert_array_equal(h[:, k], column)


@pytest.mark.parametrize("call, message", [
    (lambda c: c.mass_matrix(np.zeros(3)), "q: expected 27 finite numbers"),
    (lambda c: c.mass_matrix(np.full(27, np.nan)), "q: expected 27 finite numbers .* found non-finite"),
    (lambda c: c.mass_matrix("abc"), "q: expected 27 finite numbers"),
    (lambda c: c.bias_forces(np.zeros(27), None), "qd: expected 27 finite numbers"),
    (lambda c: c.constraints(np.zeros(27), t=float("nan")), "t: expected a finite time"),
    (lambda c: c.servo_error(np.zeros(27), t=True), "t: expected a finite time"),
])
def test_bad_arguments_are_named(call, message):
    crane = Crane.from_example("acroboter")
    with pytest.raises(ValueError, match=message):
        call(crane)
