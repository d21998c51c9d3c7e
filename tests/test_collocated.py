"""The methods against each other on a collocated toy (H = −σ_qᵀ): Penalty → MLM as α grows,
Iterative Penalty → MLM as the iterations grow, and the recoveries projected, eq12, eq15 agree."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from conftest import build_in

from acroboter.control.controllers import Gains, make_controller
from acroboter.model.spec import load_spec

TOY = Path(__file__).resolve().parent / "specs" / "collocated_toy.toml"


@pytest.fixture(scope="module")
def toy(tmp_path_factory):
    """The toy is a test spec: generated and compiled into a temporary folder."""
    return build_in(tmp_path_factory.mktemp("toy"), load_spec(TOY))


def states(toy, count=4, seed=5, aligned=True):
    """States on the constraint manifold (orthonormal axes, rigid velocities) along the path.

    H = −σ_qᵀ holds exactly while the body's axes are the world's (no torque ever turns it); at
    another attitude H = −[R; 0] spans the same forces (collocated) but is not −σ_qᵀ itself.
    """
    spec, model, path = toy
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(count):
        rot, _ = np.linalg.qr(rng.standard_normal((3, 3)))
        rot = rot * np.sign(np.linalg.det(rot)) if not aligned else np.eye(3)
        omega, t = rng.standard_normal(3), rng.uniform(0.0, path.duration)
        q = np.concatenate([path.position(t)[0] + 0.01 * rng.standard_normal(3), rot.T.reshape(-1)])
        qd = np.concatenate([0.1 * rng.standard_normal(3), *(np.cross(omega, rot[:, k]) for k in range(3))])
        out.append((q, qd, t))
    return out


def test_the_toy_is_collocated(toy):
    spec, model, path = toy
    for q, qd, t in states(toy):
        s, sd, sdd = path.signal_arrays(t)
        terms = model.evaluate("model_terms", q, qd, s, sd, sdd)
        np.testing.assert_array_equal(terms["input_matrix"], -terms["sigma_q"].T)


def _solve(toy, method, q, qd, t, **gains):
    spec, model, path = toy
    c = make_controller(method, model, path, Gains.from_spec(spec, **gains))
    u = c.compute(q, qd, t).copy()
    return u, c.qdd.copy()


def _rel(a, b):
    return np.abs(a - b).max() / max(1.0, np.abs(b).max())


def test_penalty_approaches_mlm_as_alpha_grows(toy):
    for q, qd, t in states(toy):
        u_ref, qdd_ref = _solve(toy, "mlm", q, qd, t)
        gaps = []
        for alpha in (1e2, 1e4, 1e6, 1e8):
            u, qdd = _solve(toy, "penalty", q, qd, t, alpha_geometric=alpha, alpha_servo=alpha)
            gaps.append((_rel(u, u_ref), _rel(qdd, qdd_ref)))
        gaps = np.array(gaps)
        assert np.all(np.diff(gaps[:, 0]) < 0) and np.all(np.diff(gaps[:, 1]) < 0)  # monotone
        assert gaps[0, 0] > 1e-3  # at small α the difference is real ...
        assert gaps[-1].max() < 1e-6  # ... and at large α it is gone (it falls about like 1/α)


def test_iterative_penalty_approaches_mlm_as_iterations_grow(toy):
    for q, qd, t in states(toy):
        u_ref, qdd_ref = _solve(toy, "mlm", q, qd, t)
        gaps = [_rel(_solve(toy, f"iterative-{n}", q, qd, t, alpha_geometric=1e3, alpha_servo=1e3)[0], u_ref)
                for n in (1, 2, 4, 8)]
        assert all(b < a for a, b in zip(gaps, gaps[1:], strict=False))
        assert gaps[0] > 1e-3 and gaps[-1] < 1e-8


def test_one_iteration_is_the_penalty_method(toy):
    for q, qd, t in states(toy):
        a = _solve(toy, "penalty", q, qd, t)
        b = _solve(toy, "iterative-1", q, qd, t)
        np.testing.assert_array_equal(a[0], b[0])


@pytest.mark.parametrize("method", ["penalty", "iterative-3"])
def test_projected_eq12_and_eq15_agree_when_collocated(toy, method):
    for q, qd, t in states(toy):
        u = {r: _solve(toy, method, q, qd, t, recovery=r)[0] for r in ("projected", "eq12", "eq15", "eq13")}
        for r in ("eq12", "eq15", "eq13"):
            assert _rel(u[r], u["projected"]) < 1e-9, r


@pytest.mark.parametrize("kappa", [0.0, 0.5, 1.0])
def test_every_kappa_gives_eq15_when_collocated(toy, kappa):
    """H = −σ_qᵀ with orthonormal σ_q rows: the pseudo-inverse and the transpose approximation agree,
    so the κ blend must return u = λ̂ for every κ (it would not with the paper's printed +σ_q)."""
    for q, qd, t in states(toy):
        u15 = _solve(toy, "penalty", q, qd, t, recovery="eq15")[0]
        assert _rel(_solve(toy, "penalty", q, qd, t, recovery="kappa", kappa=kappa)[0], u15) < 1e-9


def test_at_another_attitude_projected_and_eq12_still_agree_but_eq15_does_not(toy):
    """Collocated in range but H ≠ −σ_qᵀ: the pseudo-inverse recoveries agree, u = λ̂ does not."""
    for q, qd, t in states(toy, aligned=False):
        u = {r: _solve(toy, "penalty", q, qd, t, recovery=r)[0] for r in ("projected", "eq12", "eq15")}
        assert _rel(u["eq12"], u["projected"]) < 1e-9
        assert _rel(u["eq15"], u["projected"]) > 1e-2
