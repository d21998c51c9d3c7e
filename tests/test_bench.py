"""A cheap guard against a regression to per-step casadi.Function calls: the compiled control step
must be at least 3x faster than the same solver on casadi.Function calls (typically 15-30x), and
both backends must give the same input. Not a timing goal: the benchmark reports those."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from acroboter.cli.bench import time_steps
from acroboter.control.controllers import Gains, make_controller
from acroboter.model.spec import load_spec
from acroboter.runtime.cache import load_model
from acroboter.runtime.casadi_backend import CasadiModel
from acroboter.sim.statics import desired_path, solve_equilibrium

SPEC = Path(__file__).resolve().parent.parent / "model_spec" / "acroboter.toml"


@pytest.fixture(scope="module")
def backends():
    spec = load_spec(SPEC)
    compiled, casadi_model = load_model(spec), CasadiModel(spec)
    path = desired_path(compiled)
    start = solve_equilibrium(compiled, path)
    rng = np.random.default_rng(0)
    states = [(start.q + 1e-3 * rng.standard_normal(start.q.size), 1e-2 * rng.standard_normal(start.q.size), t)
              for t in np.linspace(0.0, 50.0, 40)]
    return spec, compiled, casadi_model, states


@pytest.mark.parametrize("method", ["mlm", "penalty", "iterative-3"])
def test_compiled_path_is_much_faster_and_agrees(backends, method):
    spec, compiled, casadi_model, states = backends
    gains = Gains.from_spec(spec)
    fast = make_controller(method, compiled, desired_path(compiled), gains)
    slow = make_controller(method, casadi_model, desired_path(casadi_model), gains)
    for q, qd, t in states[:5]:
        np.testing.assert_allclose(fast.compute(q, qd, t), slow.compute(q, qd, t), rtol=1e-9, atol=1e-9)
    ratio = np.median(time_steps(slow, states, 1)) / np.median(time_steps(fast, states, 3))
    assert ratio > 3.0, f"compiled path only {ratio:.1f}x faster than casadi.Function calls"
