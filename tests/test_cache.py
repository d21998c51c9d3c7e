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


def _tiny_sources(folder, answer: int):
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "answer.h").write_text(f"#define ANSWER {answer}\n")
    (folder / "answer.c").write_text('#include "answer.h"\nint answer(void) { return ANSWER; }\n')
    return [folder / "answer.c"]


def test_exported_code_compiled_once_is_copied_from_the_cache_and_a_damaged_copy_is_compiled_again(tmp_path,
                                                                                                     monkeypatch):
    """runtime.exported.compile_shared keeps what it compiled (bench compiled the same controllers on every call,
    18 of its 23 s): the same sources again are not compiled, each load gets a copy of its own, another header is
    another library, as is another compiler version, and a kept library whose bytes its checksum does not name is
    compiled again, not loaded."""
    import subprocess

    from acroboter.runtime import exported

    cache, compiles = tmp_path / "cache", []
    real_run = subprocess.run

    def counted(cmd, *args, **kwargs):
        if "-shared" in cmd:
            compiles.append(cmd)
        return real_run(cmd, *args, **kwargs)

    monkeypatch.setattr(exported.subprocess, "run", counted)
    first = exported.compile_shared(_tiny_sources(tmp_path / "a", 42), tmp_path / "a" / "libanswer.so", "a", cache)
    second = exported.compile_shared(_tiny_sources(tmp_path / "b", 42), tmp_path / "b" / "libanswer.so", "b", cache)
    assert first.answer() == second.answer() == 42 and len(compiles) == 1
    assert (tmp_path / "b" / "libanswer.so").read_bytes() == (tmp_path / "a" / "libanswer.so").read_bytes()
    other = exported.compile_shared(_tiny_sources(tmp_path / "c", 7), tmp_path / "c" / "libanswer.so", "c", cache)
    assert other.answer() == 7 and len(compiles) == 2  # the header is part of what was compiled
    (entry,) = [p for p in (cache / "exported").rglob("libanswer.so")
                if exported.compiled_key(_tiny_sources(tmp_path / "a", 42))[:16] in p.parent.name]
    entry.write_bytes(entry.read_bytes()[:-1] + b"\x01")  # one byte changed
    again = exported.compile_shared(_tiny_sources(tmp_path / "d", 42), tmp_path / "d" / "libanswer.so", "d", cache)
    assert again.answer() == 42 and len(compiles) == 3
    assert os.stat(tmp_path / "d" / "libanswer.so").st_mode & 0o700 == 0o700  # a library, as cc leaves it
    key = exported.compiled_key(_tiny_sources(tmp_path / "a", 42))
    monkeypatch.setattr(exported, "_compiler_identity", lambda compiler: f"{compiler}\ngcc (another) 99.1")
    assert exported.compiled_key(_tiny_sources(tmp_path / "a", 42)) != key  # another compiler's version
