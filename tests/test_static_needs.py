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
    if name not in _CRANES:
        crane = acroboter.Crane.from_example(name)
        geometry = PathGeometry(crane.desired())
        _CRANES[name] = crane, geometry, checks.static_needs(crane.model, geometry)
    return _CRANES[name]


@pytest.mark.parametrize("name", SHIPPED_NAMES)
@settings(max_examples=4, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(place=st.floats(0.0, 1.0))
def test_the_continued_statics_are_each_places_own_equilibrium(name, place):
    crane, geometry, (taus, _, needs) = crane_and_needs(name)
    k = int(round(place * (taus.size - 1)))
    alone = solve_equilibrium(crane.model, checks._AtRest(geometry, float(taus[k])))  # from the nominal start
    assert np.abs(needs[k] - alone.inputs).max() <= 1e-7 * max(1.0, np.abs(alone.inputs).max())


def test_the_kept_needs_are_a_copy_and_another_path_is_solved_again():
    crane, geometry, (_, _, needs) = crane_and_needs("acroboter")
    kept = needs.copy()
    needs[:] = -1.0  # a caller that writes into its answer changes nothing kept
    again = checks.static_needs(crane.model, geometry)[2]
    assert np.array_equal(again, kept)
    other = acroboter.Crane.from_toml(_shifted_spec(crane))
    moved = checks.static_needs(other.model, PathGeometry(other.desired()))[2]
    assert moved.shape == again.shape and not np.allclose(moved, again)


def _shifted_spec(crane):
    import tempfile
    from pathlib import Path

    from acroboter.model.spec_edits import with_path

    text = acroboter.example_spec("acroboter").read_text()
    path = Path(tempfile.mkdtemp(prefix="acroboter-needs-")) / "lift.toml"
    path.write_text(with_path(text, [[0.0, 0.0, 0.0], [0.0, 0.0, 0.1]], yaw_deg=0.0))
    return path
