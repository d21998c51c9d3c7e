"""The model cache and the library face under bad conditions: damaged entries, unwritable caches,
bad measurements, interrupted generation."""

from __future__ import annotations

import logging
import os
import signal

import numpy as np
import pytest
from conftest import SPEC_DIR

import acroboter
from acroboter.model.spec import load_spec
from acroboter.process.interrupts import remembered_interrupt
from acroboter.runtime.cache import load_model
from acroboter.runtime.compile_library import BuildError


@pytest.fixture(scope="module")
def own_crane(tmp_path_factory):
    """A crane of one's own (the paper's with a heavier SU, same name) in a cache of its own."""
    root = tmp_path_factory.mktemp("own")
    path = root / "heavy.toml"
    path.write_text((SPEC_DIR / "acroboter.toml").read_text().replace("mass = 8.0", "mass = 8.4"))
    cache = root / "cache"
    model = load_model(load_spec(path), cache_dir=cache)
    return load_spec(path), cache, model.source_dir


def test_a_damaged_cache_entry_of_ones_own_crane_is_generated_again(own_crane, caplog):
    spec, cache, source = own_crane
    victim = source / f"{spec.name}_phi.c"
    victim.unlink()
    with caplog.at_level(logging.WARNING, logger="acroboter"):
        model = load_model(spec, cache_dir=cache)
    assert victim.is_file() and "damaged" in caplog.text
    i = model.layout.body_offset["SU"]
    assert model.term("mass_matrix", q=np.zeros(model.layout.n))[i, i] == 8.4


def test_an_unwritable_cache_names_itself_and_the_fix(tmp_path):
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    spec = load_spec(SPEC_DIR / "acroboter.toml")
    with pytest.raises(BuildError, match=r"cannot write the model cache .*a-file/sub.*ACROBOTER_CACHE_DIR"):
        load_model(spec, cache_dir=blocker / "sub")


def test_the_controller_refuses_bad_measurements():
    crane = acroboter.Crane.from_example("acroboter")
    controller = crane.controller("penalty")
    start = crane.equilibrium()
    rest = np.zeros(len(crane.coordinates))
    with pytest.raises(ValueError, match="q: expected finite numbers"):
        controller.step(start.q * np.nan, rest, 0.0)
    with pytest.raises(ValueError, match=r"qd: expected 27 numbers .*shape \(5,\)"):
        controller.step(start.q, rest[:5], 0.0)
    with pytest.raises(ValueError, match="t: expected a finite time"):
        controller.step(start.q, rest, float("nan"))
    # numpy scalars are numbers (a loop over np.arange), a negative duration is not
    result = crane.simulate("iterative", iterations=np.int64(3), kd=np.float32(6.0), duration=np.float64(0.1),
                            warm_up=0)
    assert result.method == "iterative-3"
    with pytest.raises(ValueError, match="duration: expected a positive number"):
        crane.simulate("penalty", duration=-1.0)


def test_plot_to_a_file_leaves_the_callers_backend_alone(tmp_path):
    import matplotlib

    crane = acroboter.Crane.from_example("acroboter")
    result = crane.simulate("penalty", duration=0.2, warm_up=0)
    before = matplotlib.get_backend()
    figure = result.plot(tmp_path / "r.png")
    assert matplotlib.get_backend() == before and (tmp_path / "r.png").stat().st_size > 0
    assert figure.axes[-1].get_legend() is not None


def test_a_remembered_interrupt_is_raised_at_once_outside_casadi_and_once_casadi_returns_inside_it():
    """Outside CasADi Ctrl-C is raised where it lands; inside CasADi (a frame of its module on the stack: its
    SWIG layer swallows an exception raised there) it is raised as soon as CasADi returns to our code."""
    reached = []
    with pytest.raises(KeyboardInterrupt):
        with remembered_interrupt():
            os.kill(os.getpid(), signal.SIGINT)  # delivered now, in our own frame: raised here
            reached.append("never")
    assert reached == []
    casadi_like: dict = {"__name__": "casadi.casadi", "os": os, "signal": signal, "reached": reached}
    exec("def call():\n    os.kill(os.getpid(), signal.SIGINT)\n    reached.append('casadi went on')\n"
         "    return 1\n", casadi_like)
    with pytest.raises(KeyboardInterrupt):
        with remembered_interrupt() as interrupt:
            casadi_like["call"]()  # the signal lands inside it: CasADi finishes its call
            reached.append("never")
            interrupt.check()
    assert reached == ["casadi went on"]
