"""The plant's substep loop in C (acroboter.runtime.plant_loop) against Python's loop, and the path's one-instant
rows against its table: the same numbers to the bit, on experiments nobody chose.

Oracle: the reference loop in Python (Plant._advance_python), which the C loop replaces for speed. Both call the
same generated RK4 step, so any difference at all (a substep skipped, an event missed or taken twice, a tension
recorded at the wrong substep, a stage row off by one) is a bug. The experiments are the plant fuzzer's open-loop
drives (acroboter.studies.plant_differential.random_experiment), whose cables go slack and snap taut, so the C loop
stops at events and Python resolves them between its calls.
"""

from __future__ import annotations

import ctypes
import random
import types

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from acroboter import Crane
from acroboter.control.path import DesiredPath
from acroboter.sim.open_loop import held_path
from acroboter.sim.plant import InvariantError, Plant, SimulationError
from acroboter.studies.plant_differential import consistent_velocity, experiment_of, input_value

SPECS = ("acroboter", "acroboter_4cable")


@pytest.fixture(scope="module")
def cranes():
    return {name: Crane.from_example(name) for name in SPECS}


def drive(crane, experiment, compiled: bool, periods: int | None = None):
    """The own plant through `experiment` a control period per advance; its states, events and tensions."""
    spec, lay = crane.spec, crane.layout
    start = crane.equilibrium()
    path = held_path(spec, lay, crane.path, experiment.duration)
    plant = Plant(crane.model, path, spec.simulation.baumgarte_zeta, spec.simulation.baumgarte_omega)
    assert plant.use_compiled_loop(compiled) == compiled
    x = plant.initial_state(start.q, consistent_velocity(plant, start.q, experiment))
    period, h = 1.0 / spec.controller.rate_hz, spec.simulation.step
    substeps = round(period / h)
    static = dict(zip(lay.inputs, start.inputs, strict=True))
    periods = int(round(experiment.duration / period)) if periods is None else periods
    states, tensions, ending = [], [], "ran"
    for k in range(periods):
        t = k * period
        u = np.array([input_value(static[name], experiment.programs.get(name, []), t) for name in lay.inputs])
        try:
            plant.advance(x, u, h, plant.stage_table(t, h, substeps), 0, substeps)
        except (InvariantError, SimulationError) as err:
            ending = str(err)
            break
        states.append(x.copy())
        tensions.append(np.concatenate([plant.start_tension, plant.start_active, plant.cable_gap]))
        if not np.isfinite(x).all() or np.abs(x[: plant.n]).max() > 100.0:
            ending = "left any sensible motion"
            break
    return np.array(states), np.array(tensions), list(plant.events), ending


def assert_same_run(crane, experiment, periods=None):
    a = drive(crane, experiment, compiled=False, periods=periods)
    b = drive(crane, experiment, compiled=True, periods=periods)
    assert a[3] == b[3]
    assert a[0].shape == b[0].shape
    assert np.array_equal(a[0], b[0]), "the C loop's states are not the Python loop's to the bit"
    assert np.array_equal(a[1], b[1]), "tensions, masks or gaps differ"
    assert a[2] == b[2], "the cable events differ"
    return a


@settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(name=st.sampled_from(SPECS), seed=st.integers(0, 2**31 - 1))
def test_the_c_loop_is_the_python_loop_to_the_bit(cranes, name, seed):
    experiment = experiment_of(name, seed)
    assert_same_run(cranes[name], experiment, periods=min(100, int(round(experiment.duration * 50))))


@pytest.mark.parametrize(("name", "seed"), [("acroboter", 906), ("acroboter", 924)])
def test_the_c_loop_through_the_fuzzers_cascades(cranes, name, seed):
    """Seeds whose cables hand the load to each other (docs/plant-fuzz.md): many events, each resolved in Python
    between two calls of the C loop."""
    states, _, events, _ = assert_same_run(cranes[name], experiment_of(name, seed))
    assert len(events) >= 2 and len(states) > 0


def test_a_closed_loop_run_is_the_same_with_the_c_loop(cranes, monkeypatch):
    crane = cranes["acroboter"]
    compiled = crane.simulate("penalty", duration=4.0).run
    monkeypatch.setattr(Plant, "_compiled_loop", lambda self, model: None)  # every plant on Python's loop
    python = crane.simulate("penalty", duration=4.0).run
    assert np.array_equal(python.q, compiled.q) and np.array_equal(python.u, compiled.u)
    assert np.array_equal(python.cable_tension, compiled.cable_tension)


def test_the_loop_falls_back_to_python_where_it_cannot_be_had(cranes, monkeypatch, caplog):
    """No compiler on a worker (the model's library found in the cache, the loop's not built): Python's loop runs,
    with the same numbers, and the warning is said once per process, not once per plant of a study."""
    from acroboter.runtime import plant_loop
    from acroboter.runtime.compile_library import BuildError
    from acroboter.sim import plant as plant_module

    crane = cranes["acroboter"]
    plant = Plant(crane.model, crane.path, 1.0, 20.0)
    assert plant.use_compiled_loop(True)
    assert not plant.use_compiled_loop(False)
    assert plant.use_compiled_loop(True)

    def no_compiler(cache_root):
        raise BuildError("no C compiler 'cc' found: install gcc (or set CC) and run `make build`")

    monkeypatch.setattr(plant_loop, "load_plant_loop", no_compiler)
    monkeypatch.setattr(plant_loop, "_loaded", {})
    monkeypatch.setattr(plant_module, "_LOOP_REFUSED", set())
    with caplog.at_level("WARNING", logger="acroboter.sim.plant"):
        plants = [Plant(crane.model, crane.path, 1.0, 20.0) for _ in range(3)]
    assert not any(p.use_compiled_loop(True) for p in plants)
    assert sum("substep loop runs in Python" in r.getMessage() for r in caplog.records) == 1
    python = crane.simulate("penalty", duration=1.0).run
    monkeypatch.undo()
    assert np.array_equal(python.q, crane.simulate("penalty", duration=1.0).run.q)


@settings(max_examples=40, deadline=None)
@given(name=st.sampled_from(SPECS), times=st.lists(st.floats(-2.0, 80.0), min_size=1, max_size=4))
def test_the_paths_rows_are_its_table_to_the_bit(cranes, name, times):
    """The plant's events evaluate the path at a few instants with `rows` (scalar flat per instant, 30x cheaper);
    the table (vectorized) gives the stage signals of every other substep: they must be the same numbers."""
    path = cranes[name].path
    assert np.array_equal(path.rows(times), path.table(np.array(times)))
    rng = random.Random(len(times))
    t = rng.uniform(0.0, path.duration)
    assert np.array_equal(np.array(path.flat(t)), path.table(np.array([t]))[0])


@settings(max_examples=25, deadline=None)
@given(dx=st.floats(-1.0, 1.0), dy=st.floats(-1.0, 1.0), times=st.lists(st.floats(-2.0, 80.0), min_size=1, max_size=3))
def test_the_rows_are_the_table_with_moving_anchors_off_the_start(cranes, dx, dy, times):
    """A climbing unit whose anchors and path start are not at x = y = 0 (flat adds the anchors' offset in
    another order than table: rows must use table's)."""
    crane = cranes["acroboter"]
    spec = crane.spec
    anchors = [types.SimpleNamespace(name=a.name, position=[a.position[0] + dx, a.position[1] + dy, a.position[2]],
                                     follows_path=a.follows_path) for a in spec.anchors]
    shifted = types.SimpleNamespace(path=spec.path, anchors=anchors)
    path = DesiredPath(shifted, crane.layout, crane.path.start_point + np.array([dx, dy, 0.0]), crane.path.start_yaw)
    assert path._follow, "the spec has moving anchors"
    assert np.array_equal(path.rows(times), path.table(np.array(times)))


def test_a_failing_step_raises_in_either_loop(cranes):
    """A generated step that returns non-zero (a failed inner call) stops the period with an error, in C as in
    Python; it is never skipped."""
    crane = cranes["acroboter"]
    spec = crane.spec
    failing = ctypes.CFUNCTYPE(ctypes.c_int, *[ctypes.c_void_p] * 4, ctypes.c_int)(lambda *args: 1)
    h = spec.simulation.step
    for compiled in (True, False):
        plant = Plant(crane.model, crane.path, spec.simulation.baumgarte_zeta, spec.simulation.baumgarte_omega)
        plant.use_compiled_loop(compiled)
        x = plant.initial_state(crane.equilibrium().q)
        if compiled:
            plant._loop[1].step = ctypes.cast(failing, ctypes.c_void_p).value
        else:
            plant._step.call = lambda: (_ for _ in ()).throw(RuntimeError("plant_step failed"))
        with pytest.raises(RuntimeError, match="failed"):
            plant.advance(x, crane.equilibrium().inputs, h, plant.stage_table(0.0, h, 10), 0, 10)
