"""A lighter install (docs/extras.md): the core runs without MuJoCo, the animation's encoders and Dask; a command
that needs a missing extra exits 2 with the one `pip install` line that fixes it, before any work (nothing
written, nothing built); the library raises MissingExtraError (an ImportError) with that line; a missing core
dependency is one line, never a traceback.

The extras are made missing in this process (sys.modules[name] = None: find_spec answers None, an import
fails); tests/test_install.py checks the same in a fresh virtual environment that has only the core.
"""

from __future__ import annotations

import importlib.util
import re
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest

from acroboter.cli.console import main as console
from acroboter.process import extras
from acroboter.process.extras import CORE, EXTRAS, MissingExtraError, install_line, missing, require

REPO = Path(__file__).resolve().parent.parent
PYPROJECT = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]


def hide(monkeypatch, *extra_names: str) -> None:
    """Make the extras' packages missing, as if they were not installed."""
    for extra in extra_names:
        for module in EXTRAS[extra]:
            monkeypatch.setitem(sys.modules, module, None)


def _name(requirement: str) -> str:
    return re.split(r"[\[<>=!~; ]", requirement, maxsplit=1)[0].lower()


# --- the declared lists -----------------------------------------------------------------------------------


def test_the_core_and_the_extras_are_pyprojects():
    assert sorted(CORE.values()) == sorted(_name(r) for r in PYPROJECT["dependencies"])
    optional = PYPROJECT["optional-dependencies"]
    assert {*EXTRAS, "all", "test"} <= set(optional)  # others (the tools of a docs build) are no runtime extra
    assert optional["all"] == [f"acroboter[{','.join(EXTRAS)}]"]
    provides = {"mujoco": {"mujoco"}, "animation": {"imageio"}, "dask": {"dask"}}  # distribution names
    assert {extra: {_name(r) for r in optional[extra]} for extra in EXTRAS} == provides
    assert "mujoco" not in str(PYPROJECT["dependencies"]) and "imageio" not in str(PYPROJECT["dependencies"])


def test_make_setup_installs_every_extra():
    """`make run` installs what a run needs ([all]: every runtime extra), `make setup`/`make test` the
    test and docs tools on top ([all,test,...])."""
    installs = [set(e.split(",")) for e in re.findall(r"pip install --quiet -e '\.\[([\w,]+)\]'",
                                                       (REPO / "Makefile").read_text())]
    assert installs[0] == {"all"} and {"all", "test"} <= installs[-1], installs


def test_require_names_the_extra_the_package_and_the_pip_line(monkeypatch):
    hide(monkeypatch, "animation")
    assert missing("animation") == "imageio"
    monkeypatch.setitem(EXTRAS, "stdlib", ("json", "csv"))  # an extra that is surely there
    assert missing("stdlib") is None
    require("stdlib", "nothing")
    with pytest.raises(MissingExtraError) as caught:
        require("animation", "an MP4", "a GIF needs no extra")
    err = caught.value
    assert isinstance(err, ImportError) and err.name == "imageio" and err.extra == "animation"
    assert str(err).startswith("an MP4 needs the animation extra (imageio is not installed; a GIF needs no extra): "
                               "pip install 'acroboter[animation]'")
    assert str(err).endswith("(in this checkout: make setup)")  # the tests run in a checkout
    monkeypatch.setattr(extras, "checkout_root", lambda: None)  # installed: the pip line ends it
    with pytest.raises(MissingExtraError, match=r"pip install 'acroboter\[animation\]'$"):
        require("animation", "an MP4")
    with pytest.raises(ValueError, match="unknown extra 'mjuoco'"):
        require("mjuoco", "x")


def test_require_only_looks_imports_nothing(monkeypatch):
    """find_spec, not import: mujoco picks its GL backend when first imported, so a check must not import it."""
    monkeypatch.delitem(sys.modules, "imageio", raising=False)
    monkeypatch.delitem(sys.modules, "imageio_ffmpeg", raising=False)
    seen = []
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: seen.append(name) or real(name, *a))
    require("animation", "an MP4")
    assert seen == ["imageio", "imageio_ffmpeg"]
    assert "imageio" not in sys.modules and "imageio_ffmpeg" not in sys.modules


# --- every command: exit 2 with the pip line, before any work ---------------------------------------------

# (arguments, the extras made missing, the extra the line names, words of the line)
COMMANDS = [
    (["run", "--plant", "mujoco"], ["mujoco"], "mujoco", "--plant mujoco needs the mujoco extra"),
    (["run", "--view"], ["mujoco"], "mujoco", "--view (MuJoCo's viewer) needs the mujoco extra"),
    (["animate", "RESULTS"], ["animation"], "animation", "an MP4 needs the animation extra (imageio is not"),
    (["animate", "RESULTS", "--no-mp4", "--gif", "RESULTS/a.gif", "--renderer", "mujoco"], ["mujoco"], "mujoco",
     "--renderer mujoco needs the mujoco extra"),
    (["mjcf", "lab_crane", "-o", "OUT/crane.xml"], ["mujoco"], "mujoco", "acroboter mjcf (MuJoCo loads the XML"),
    (["sweep", "--spec", "lab_crane", "--out", "OUT"], ["dask"], "dask", "acroboter sweep needs the dask extra"),
    (["robustness", "--spec", "lab_crane", "--out", "OUT"], ["dask"], "dask",
     "acroboter robustness --workers 2 needs the dask extra (dask is not installed; --workers 0 runs in this "
     "process without it)"),
    (["robustness", "--scheduler", "tcp://127.0.0.1:1", "--out", "OUT"], ["dask"], "dask",
     "acroboter robustness --scheduler needs"),
    (["plant-fuzz", "--workers", "1", "--out", "OUT"], ["mujoco"], "mujoco", "acroboter plant-fuzz (MuJoCo is its"),
    pytest.param(["plant-fuzz", "--out", "OUT"], ["dask"], "dask",
                 "acroboter plant-fuzz --workers 2 needs the dask extra",
                 marks=pytest.mark.needs_mujoco),  # without mujoco too, its line comes first
]


@pytest.mark.parametrize("args, hidden, extra, words", COMMANDS,
                         ids=[" ".join(getattr(c, "values", c)[0][:4]) for c in COMMANDS])
def test_a_command_without_its_extra_exits_2_with_the_pip_line_before_any_work(args, hidden, extra, words, tmp_path,
                                                                               monkeypatch, capsys):
    hide(monkeypatch, *hidden)
    monkeypatch.chdir(tmp_path)
    # a model loaded would be compiled into this empty cache (and show in tmp_path below)
    monkeypatch.setenv("ACROBOTER_CACHE_DIR", str(tmp_path / "cache"))
    results = tmp_path / "results"
    results.mkdir()  # a results folder for `animate` (empty: reading it would fail, but it is never read)
    argv = [a.replace("RESULTS", str(results)).replace("OUT", str(tmp_path / "out")) for a in args]
    assert console(argv) == 2
    captured = capsys.readouterr()
    (line,) = captured.err.splitlines()  # one line, no traceback, no progress
    assert line.startswith(f"error: {words}"), line
    assert f": {install_line(extra)} (in this checkout: make setup)" in line
    assert captured.out == ""
    assert sorted(p.name for p in tmp_path.iterdir()) == ["results"] and not any(results.iterdir())


def test_the_commands_that_need_no_extra_check_none(monkeypatch, tmp_path):
    """Options that need only the core parse without any extra: the own plant, a GIF drawn with matplotlib
    (--renderer auto falls back to it), a robustness study in this process, plant-fuzz's options aside."""
    from acroboter.cli import animate, robustness, run_args, sweep

    hide(monkeypatch, *EXTRAS)
    assert run_args.parse_args(["--spec", "lab_crane", "--out", str(tmp_path / "r")]).plant == "own"
    gif = animate.parse_args([str(tmp_path), "--no-mp4", "--gif", str(tmp_path / "a.gif")])
    assert gif.renderer == "auto" and gif.no_mp4
    assert robustness.parse_args(["--workers", "0", "--out", str(tmp_path / "rob")]).workers == 0
    with pytest.raises(MissingExtraError):
        sweep.parse_args(["--out", str(tmp_path / "sweep")])
    assert not (tmp_path / "sweep").exists()


def test_auto_renderer_without_mujoco_draws_with_matplotlib_and_says_why(monkeypatch, caplog):
    from acroboter.cli import animate

    hide(monkeypatch, "mujoco")
    with caplog.at_level("INFO", logger="acroboter"):
        name, _ = animate.choose_renderer("auto", spec=None)
    assert name == "matplotlib"
    assert "mujoco is not installed (pip install 'acroboter[mujoco]')" in caplog.text


# --- the library: MissingExtraError, an ImportError with the line --------------------------------------------


@pytest.fixture(scope="module")
def lab_crane():
    from acroboter import Crane

    return Crane.from_example("lab_crane")


def test_the_library_raises_missing_extra_error_before_any_work(monkeypatch, lab_crane, tmp_path):
    from acroboter.report.animation.encode import write_complete, write_mp4
    from acroboter.sim.mujoco_plant import MujocoPlant
    from acroboter.studies.grid import require_dask

    hide(monkeypatch, *EXTRAS)
    line = r"pip install 'acroboter\[mujoco\]'"
    with pytest.raises(ImportError, match=r"plant='mujoco' needs the mujoco extra .*" + line):
        lab_crane.simulate("penalty", duration=0.1, plant="mujoco")
    with pytest.raises(MissingExtraError, match=line):
        lab_crane.simulate_open_loop(lambda t: np.zeros(len(lab_crane.inputs)), 0.1, plant="mujoco")
    with pytest.raises(MissingExtraError, match=r"the MuJoCo plant \(MujocoPlant\) needs the mujoco extra"):
        MujocoPlant(lab_crane.model, lab_crane.path)
    with pytest.raises(MissingExtraError, match=r"pip install 'acroboter\[dask\]'"):
        require_dask("a study")
    frames = iter([np.zeros((8, 8, 3), np.uint8)])
    with pytest.raises(MissingExtraError, match=r"an MP4 needs the animation extra .*acroboter\[animation\]"):
        write_complete(write_mp4, frames, tmp_path / "a.mp4", 25.0, 1, True)
    assert list(tmp_path.iterdir()) == []
    # what needs only the core runs: the own plant, and the MJCF as text
    run = lab_crane.simulate("penalty", duration=0.1, warm_up=0)
    assert run.time[-1] == pytest.approx(0.1) and run.summary()["max_position_error_mm"] < 1.0
    assert lab_crane.mjcf().rstrip().endswith("</mujoco>")


# --- a missing core dependency: one line ------------------------------------------------------------------


@pytest.mark.parametrize("module, requirement", [("scipy", "scipy>=1.11"), ("PIL", "pillow>=8"),
                                                 ("casadi", "casadi==3.8.2")])
def test_a_missing_core_dependency_is_one_line(module, requirement, monkeypatch, capsys, tmp_path):
    monkeypatch.setitem(sys.modules, module, None)
    monkeypatch.chdir(tmp_path)
    assert console(["run", "--duration", "1"]) == 3
    captured = capsys.readouterr()
    assert captured.err.splitlines() == [
        f"acroboter: the core dependency {CORE[module]} is not installed (or does not import): "
        f"pip install '{requirement}' (in this checkout: make setup)"]
    assert list(tmp_path.iterdir()) == []


def test_a_core_dependency_that_fails_to_import_mid_command_is_one_line(monkeypatch, capsys, tmp_path):
    """Found (find_spec) but broken: the import inside the command fails, the boundary gives the one line."""
    from acroboter.api import crane

    def broken(*a, **k):
        raise ModuleNotFoundError("No module named 'scipy.linalg'", name="scipy.linalg")

    monkeypatch.setattr(crane.Crane, "from_toml", broken)
    monkeypatch.chdir(tmp_path)
    assert console(["run", "--duration", "1", "--out", "out"]) == 3
    err = capsys.readouterr().err
    assert err.splitlines() == ["error: the core dependency scipy is not installed (or does not import): "
                                "pip install 'scipy>=1.11' (in this checkout: make setup)"]
    assert not (tmp_path / "out").exists()


def test_another_broken_package_is_one_line_and_a_bug_stays_a_bug(monkeypatch, capsys):
    from acroboter.cli.entry import core_import_problem, guarded

    assert "kiwisolver does not import" in core_import_problem(ImportError("boom", name="kiwisolver"))
    assert core_import_problem(ImportError("no acroboter.x", name="acroboter.x")) is None  # ours: a bug
    assert core_import_problem(MissingExtraError("dask", "dask", "x")) is None  # exit 2, not 3

    @guarded
    def command(argv=None) -> int:
        raise ImportError("cannot import name 'x'", name="kiwisolver")

    assert command() == 3
    assert capsys.readouterr().err.count("\n") == 1
