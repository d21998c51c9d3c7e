"""The statics along a path (acroboter.planning.checks.static_needs), solved by continuation and kept per (model,
path): each place's equilibrium against one solved on its own from the nominal configuration, on every shipped crane
the planner takes (hypothesis draws the places); the kept needs are a copy, and another path is solved again."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import SHIPPED_NAMES
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import acroboter
from acroboter.planning import checks
from acroboter.planning.geometry import PathGeometry
from acroboter.sim.statics import solve_equilibrium

_CRANES: dict = {}


def crane_and_needs(name: str):
    """The crane, its path's geometry and its static needs at 26 places (steps four times the planner's: a harder
    continuation; the redundant cranes' equilibria cost 0.1 s each)."""
    if name not in _CRANES:
        crane = acroboter.Crane.from_example(name)
        geometry = PathGeometry(crane.desired())
        with pytest.MonkeyPatch.context() as patch:
            patch.setattr(checks, "STATIC_SAMPLES", 26)
            _CRANES[name] = crane, geometry, checks.static_needs(crane.model, geometry)
    return _CRANES[name]


@pytest.mark.parametrize("name", SHIPPED_NAMES)
@settings(max_examples=2, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(place=st.floats(0.0, 1.0))
def test_the_continued_statics_are_each_places_own_equilibrium(name, place):
    crane, geometry, (taus, _, needs) = crane_and_needs(name)
    k = int(round(place * (taus.size - 1)))
    alone = solve_equilibrium(crane.model, checks._AtRest(geometry, float(taus[k])))  # from the nominal start
    assert np.abs(needs[k] - alone.inputs).max() <= 1e-7 * max(1.0, np.abs(alone.inputs).max())


def test_the_kept_needs_are_a_copy_and_another_path_is_solved_again(monkeypatch):
    crane, geometry, (_, _, needs) = crane_and_needs("acroboter")
    monkeypatch.setattr(checks, "STATIC_SAMPLES", 26)  # as crane_and_needs asked
    kept = needs.copy()
    needs[:] = -1.0  # a caller that writes into its answer changes nothing kept
    again = checks.static_needs(crane.model, geometry)[2]
    assert np.array_equal(again, kept)
    other = acroboter.Crane.from_toml(_shifted_spec(crane))
    moved = checks.static_needs(other.model, PathGeometry(other.desired()))[2]
    assert moved.shape == (26, again.shape[1])  # its own places (the default path has 31: its corners too)


def _shifted_spec(crane):
    import tempfile
    from pathlib import Path

    from acroboter.model.spec_edits import with_path

    text = acroboter.example_spec("acroboter").read_text()
    path = Path(tempfile.mkdtemp(prefix="acroboter-needs-")) / "lift.toml"
    path.write_text(with_path(text, [[0.0, 0.0, 0.0], [0.0, 0.0, 0.1]], yaw_deg=0.0))
    return path


def test_a_redundant_cranes_preferred_tensions_are_part_of_what_is_kept(monkeypatch):
    """The four-cable crane's preferred tensions are a run-time setting (not in the model's hash), yet they choose its
    internal force at rest: a crane that prefers another one is solved again, and its needs are nearer its own
    preference than the first crane's are."""
    import tempfile
    from pathlib import Path

    monkeypatch.setattr(checks, "STATIC_SAMPLES", 11)  # (see crane_and_needs)
    crane = acroboter.Crane.from_example("acroboter_4cable")
    needs = checks.static_needs(crane.model, PathGeometry(crane.desired()))[2]
    text = acroboter.example_spec("acroboter_4cable").read_text()
    assert text.count("preferred = 20.0") == 4
    path = Path(tempfile.mkdtemp(prefix="acroboter-needs-")) / "acroboter_4cable.toml"
    path.write_text(text.replace("preferred = 20.0", "preferred = 24.0", 1))  # winch 1 only
    other = acroboter.Crane.from_toml(path)
    assert other.spec.model_hash() == crane.spec.model_hash()
    moved = checks.static_needs(other.model, PathGeometry(other.desired()))[2]
    winches = [i for i, name in enumerate(crane.inputs) if name.startswith("tension")]
    preferred = np.array([24.0, 20.0, 20.0, 20.0])
    nearer = np.linalg.norm(moved[:, winches] - preferred, axis=1)
    assert (nearer < np.linalg.norm(needs[:, winches] - preferred, axis=1) - 0.1).all()
