"""The statics along a path (acroboter.planning.checks.static_needs), solved by continuation and kept per crane and
path: each place's equilibrium against one solved on its own from the nominal configuration, on every shipped
crane; the kept needs are a copy, used again (no solve), and another path or another redundant crane's preferred
tensions are solved again."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import SHIPPED_NAMES

import acroboter
from acroboter.planning import checks
from acroboter.planning.geometry import PathGeometry
from acroboter.sim.statics import EquilibriumError, solve_equilibrium

# The places the tests solve (the planner: 101, and every corner): steps four times the planner's, a harder
# continuation (the redundant cranes' equilibria cost 0.1 s each).
PLACES = 26


@pytest.fixture
def few_places(monkeypatch):
    monkeypatch.setattr(checks, "STATIC_SAMPLES", PLACES)


@pytest.fixture
def counted(monkeypatch):
    """The equilibrium solves static_needs makes, counted."""
    calls = []
    real = checks.solve_equilibrium
    monkeypatch.setattr(checks, "solve_equilibrium", lambda *a, **k: calls.append(1) or real(*a, **k))
    return calls


@pytest.mark.parametrize("name", SHIPPED_NAMES)
def test_the_continued_statics_are_each_places_own_equilibrium(name, few_places):
    """Every fifth place, and the last, against the solve from the nominal configuration alone. Where that solve
    finds none (the redundant-task crane at its corner s = 0.7: its 250,000 evaluations run out, and planning that
    path stopped there with "no static equilibrium" until the continuation), against the solve from the place
    before's own equilibrium: a continuation over one step, not the whole path's."""
    crane = acroboter.Crane.from_example(name)
    geometry = PathGeometry(crane.desired())
    taus, _, needs = checks.static_needs(crane.model, geometry)
    for k in sorted({*range(0, taus.size, 5), taus.size - 1}):
        try:
            alone = solve_equilibrium(crane.model, checks._AtRest(geometry, float(taus[k])))
        except EquilibriumError:
            before = solve_equilibrium(crane.model, checks._AtRest(geometry, float(taus[k - 1])))
            alone = solve_equilibrium(crane.model, checks._AtRest(geometry, float(taus[k])), near=before)
        assert np.abs(needs[k] - alone.inputs).max() <= 1e-7 * max(1.0, np.abs(alone.inputs).max()), (k, taus[k])


def test_the_kept_needs_are_a_copy_used_again_and_another_path_is_solved_again(few_places, counted, tmp_path):
    from acroboter.model.spec_edits import with_path

    crane = acroboter.Crane.from_example("acroboter")
    geometry = PathGeometry(crane.desired())
    needs = checks.static_needs(crane.model, geometry)[2]
    solved = len(counted)
    assert solved == needs.shape[0]
    kept = needs.copy()
    needs[:] = -1.0  # a caller that writes into its answer changes nothing kept
    again = checks.static_needs(crane.model, PathGeometry(crane.desired()))[2]
    assert np.array_equal(again, kept) and len(counted) == solved  # kept: not solved again
    lift = tmp_path / "lift.toml"
    lift.write_text(with_path(acroboter.example_spec("acroboter").read_text(), [[0.0, 0.0, 0.0], [0.0, 0.0, 0.1]],
                              yaw_deg=0.0))
    other = acroboter.Crane.from_toml(lift)
    moved = checks.static_needs(other.model, PathGeometry(other.desired()))[2]
    assert moved.shape == (PLACES, kept.shape[1]) and len(counted) == solved + PLACES  # its own places, solved
    checks.clear_static_needs()
    checks.static_needs(crane.model, geometry)
    assert len(counted) == 2 * solved + PLACES


def test_a_redundant_cranes_preferred_tensions_are_part_of_what_is_kept(monkeypatch, counted, tmp_path):
    """The four-cable crane's preferred tensions are a run-time setting (not in the model's hash), yet they choose its
    internal force at rest: a crane that prefers another one is solved again, and its needs are nearer its own
    preference than the first crane's are."""
    monkeypatch.setattr(checks, "STATIC_SAMPLES", 11)
    crane = acroboter.Crane.from_example("acroboter_4cable")
    needs = checks.static_needs(crane.model, PathGeometry(crane.desired()))[2]
    solved = len(counted)
    text = acroboter.example_spec("acroboter_4cable").read_text()
    assert text.count("preferred = 20.0") == 4
    path = tmp_path / "acroboter_4cable.toml"
    path.write_text(text.replace("preferred = 20.0", "preferred = 24.0", 1))  # winch 1 only
    other = acroboter.Crane.from_toml(path)
    assert other.spec.model_hash() == crane.spec.model_hash()
    moved = checks.static_needs(other.model, PathGeometry(other.desired()))[2]
    assert len(counted) == 2 * solved
    winches = [i for i, name in enumerate(crane.inputs) if name.startswith("tension")]
    preferred = np.array([24.0, 20.0, 20.0, 20.0])
    nearer = np.linalg.norm(moved[:, winches] - preferred, axis=1)
    assert (nearer < np.linalg.norm(needs[:, winches] - preferred, axis=1) - 0.1).all()


def test_the_redundant_task_crane_has_its_statics_where_the_nominal_start_found_none():
    """Shrunk from a review: the redundant-task crane (the default crane's mechanics, the task with a redundant
    servo-constraint) has no equilibrium from the nominal configuration at its corner s = 0.7 within the solve's
    250,000 evaluations, so `plan` refused its path ("no static equilibrium at s = 0.700", not its real reason: 6
    inputs for 7 servo-constraints) until the statics were continued along it. There it needs what the default
    crane needs at the same place, solved from nominal."""
    default = acroboter.Crane.from_example("acroboter")
    redundant = acroboter.Crane.from_example("acroboter_redundant_task")
    taus, _, needs = checks.static_needs(redundant.model, PathGeometry(redundant.desired()))
    corner = int(np.flatnonzero(taus == 7.0)[0])
    oracle = solve_equilibrium(default.model, checks._AtRest(PathGeometry(default.desired()), 7.0)).inputs
    assert np.abs(needs[corner] - oracle).max() <= 1e-9 * np.abs(oracle).max()


def test_a_crane_the_retiming_cannot_take_is_refused_before_its_statics(counted):
    """The redundant-task crane has no ideal motion (6 inputs for 7 servo-constraints): `plan` says so before it
    solves a single equilibrium along the path (it used to solve them all, and refused at s = 0.7 for a wrong
    reason: above)."""
    from acroboter.planning.ideal_motion import PlanningError

    crane = acroboter.Crane.from_example("acroboter_redundant_task")
    with pytest.raises(PlanningError, match="6 inputs for 7 servo-constraints"):
        crane.plan(certify=False)
    assert counted == []
