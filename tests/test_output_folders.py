"""The one output-folder contract (acroboter.cli.outputs, docs/run.md), the same cases for every command that
writes files (issue 24 item 1): a user's files named like results survive, a narrower re-run leaves nothing of
the wider one (export-step, mjcf and animate: each spec's, method's or video's file is its own, and stays), an
empty or unusable --out is refused before any work, a failed or interrupted run leaves the folder as it was
(and no folder it made), a killed run's staging folder goes, and a command never writes into a folder another
one is writing into (exit 3, naming it). generate --out keeps whole generated folders (its own staging and
swap): the same promises, by its own cases at the end.

The commands run in this process (their `main`, behind the error boundary) with cheap arguments."""

from __future__ import annotations

import atexit
import importlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

from acroboter.cli import outputs
from acroboter.cli.outputs import MANIFEST, STAGING_PREFIX
from acroboter.sim.plant import SimulationError

REPO = Path(__file__).resolve().parent.parent

RUN_FIGURES = {"path_3d.png", "tracking_errors.png", "servo_errors.png", "inputs.png", "control_step_time.png"}
STUDY = {f"{s}/{n}" for s in ("redundant", "noncollocated") for n in ("table.md", "summary.json", "position_error.png")}
SWEEP = ["--alphas", "1e3", "--omegas", "10", "--iterations", "1", "--duration", "0.2", "--workers", "1", "-q"]
ROBUST = ["--samples", "1", "--workers", "0", "--duration", "0.2", "--methods", "penalty", "-q"]
ANIMATE = ["--fps", "2", "--size", "160x120", "--renderer", "matplotlib", "-q"]  # one frame of a 0.2 s run
# bench on the default and four-cable cranes with a 2.5 s path (its own, 55 s, took 70-170 s per call here)
BENCH = ["--spec", "{short}", "--limits-spec", "{short_4cable}", "--repeats", "1", "--casadi-states", "1",
         "--mc-samples", "0"]
SHORT = {"{short}": "acroboter", "{short_4cable}": "acroboter_4cable"}

# command: (module, wide arguments, what they write, narrower arguments, what those write)
COMMANDS = {
    "run": ("run", ["--duration", "0.2", "--method", "mlm,penalty", "-q"],
            {"mlm.csv", "penalty.csv", "summary.json"} | RUN_FIGURES,
            ["--duration", "0.2", "--method", "penalty", "--no-plots", "-q"], {"penalty.csv", "summary.json"}),
    "bench": ("bench", [*BENCH, "--methods", "penalty,mlm"], {"bench.json"}, [*BENCH, "--methods", "penalty"],
              {"bench.json"}),
    "study": ("study", ["all", "--duration", "0.1"], STUDY,
              ["redundant", "--duration", "0.1"], {n for n in STUDY if n.startswith("redundant/")}),
    "sweep": ("sweep", SWEEP, {"sweep.csv", "sweep_condition.png", "sweep_constraints.png",
                               "sweep_tracking_error.png"}, [*SWEEP, "--no-plots"], {"sweep.csv"}),
    "robustness": ("robustness", ROBUST, {"robustness.csv", "samples.csv", "summary.json", "robustness_cdf.png",
                                          "robustness_success.png", "robustness_worst.png"},
                   [*ROBUST, "--no-plots"], {"robustness.csv", "samples.csv", "summary.json"}),
    "plant-fuzz": ("plant_fuzz", ["--cases", "1", "--workers", "1", "--spec", "acroboter", "-q"],
                   {"plant_fuzz.csv", "report.md"},
                   ["--cases", "1", "--workers", "1", "--spec", "acroboter", "-q"], {"plant_fuzz.csv", "report.md"}),
    "export-step": ("generate:export_step_main", ["--spec", "lab_crane", "--method", "mlm"],
                    {"lab_crane_mlm_step.c", "lab_crane_mlm_step.h"}, ["--spec", "lab_crane", "--method", "penalty"],
                    {"lab_crane_penalty_step.c", "lab_crane_penalty_step.h"}),
    "plan": ("plan", ["--spec", "{lift}", "--margin", "20%", "-q"], {"trajectory.csv", "summary.json", "plan.png"},
             ["--spec", "{lift}", "--margin", "20%", "--no-plots", "-q"], {"trajectory.csv", "summary.json"}),
    "mjcf": ("mjcf", ["acroboter", "--pose", "spec", "-q"], {"acroboter.xml"},
             ["lab_crane", "--pose", "spec", "-q"], {"lab_crane.xml"}),
    "animate": ("animate", ["{run}", "--method", "mlm", *ANIMATE], {"animation_mlm.mp4"},
                ["{run}", "--method", "penalty", *ANIMATE], {"animation_penalty.mp4"}),
}
# One file per spec, video or study: a run of another one keeps the earlier ones (ResultsFolder accumulate); an
# export-step replaces the earlier one's files (issue 36: other gains' files were listed as current beside it)
ACCUMULATE = {"mjcf", "animate", "study"}
# The option as the messages name it; whether a missing --out is made; whether an existing file is an output
OPTION = {"mjcf": "-o"}
MADE = set(COMMANDS) - {"mjcf", "animate"}  # mjcf and animate write into an existing folder or name a file
FILE_IS_OUTPUT = {"mjcf"}  # -o FILE writes that file
NEEDS = {"sweep": [pytest.mark.needs_dask], "plant-fuzz": [pytest.mark.needs_mujoco],  # the extras (conftest.py)
         "mjcf": [pytest.mark.needs_mujoco], "animate": [pytest.mark.needs_animation]}
EVERY = [pytest.param(c, marks=NEEDS.get(c, [])) for c in COMMANDS]
# A user's own files named like some command's results (the list and more)
LOOKALIKES = ["mlm.csv", "penalty.csv", "iterative-3.csv", "inputs.png", "summary.json", "sweep.csv", "report.md",
              "bench.json", "robustness.csv", "samples.csv", "plant_fuzz.csv", "animation_x.gif",
              "animation_penalty.mp4", "sweep_condition.png", "redundant/table.md", "noncollocated/notes.txt",
              ".hidden", "lab_crane.xml", "lab_crane_mlm_step.c", "animation_mlm.mp4"]
_RUN: list[Path] = []
_LIFT: list = []
_SHORT: dict[str, Path] = {}


def short_spec(name: str) -> Path:
    """The example `name` with its path one 10 cm edge (2.5 s: more than the 101 control instants bench needs),
    written once."""
    if not _SHORT:
        from acroboter.model.spec_edits import with_path

        folder = Path(tempfile.mkdtemp(prefix="acroboter-short-"))
        atexit.register(shutil.rmtree, folder, True)
        for example in ("acroboter", "acroboter_4cable"):
            text = (REPO / "model_spec" / f"{example}.toml").read_text()
            short = with_path(text, [[0.0, 0.0, 0.0], [0.1, 0.0, 0.0]])
            assert short != text
            (folder / f"{example}.toml").write_text(short)
            _SHORT[example] = folder / f"{example}.toml"
    return _SHORT[name]


def lift_plan():
    """A spec whose path is one short vertical lift with winch limits, and its plan, made once: the folder tests
    replace Crane.plan by this answer (the planner itself: tests/test_planning.py)."""
    if not _LIFT:
        from conftest import write_lift_spec

        import acroboter

        folder = Path(tempfile.mkdtemp(prefix="acroboter-plan-source-"))
        atexit.register(shutil.rmtree, folder, True)
        spec = write_lift_spec(folder)
        _LIFT.extend([spec, acroboter.Crane.from_toml(spec).plan(margin=0.2, intervals=8)])
    return _LIFT


@pytest.fixture(autouse=True)
def _planned(request, monkeypatch):
    """For `plan`: the lift's plan, computed once, stands in for the optimisation in every folder test."""
    callspec = getattr(request.node, "callspec", None)
    if callspec is not None and callspec.params.get("command") == "plan":
        spec, plan = lift_plan()
        monkeypatch.setattr("acroboter.api.crane.Crane.plan", lambda self, **kwargs: plan)
    if callspec is not None and callspec.params.get("command") == "animate":
        animated_run()  # made before a test patches publish away, whatever order the tests run in


def animated_run() -> Path:
    """A run's folder for animate (mlm and penalty, 0.2 s), made once."""
    if not _RUN:
        from acroboter.cli import run

        folder = Path(tempfile.mkdtemp(prefix="acroboter-animate-source-"))
        atexit.register(shutil.rmtree, folder, True)
        assert run.main(["--duration", "0.2", "--method", "mlm,penalty", "--no-plots", "-q",
                         "--out", str(folder / "run")]) == 0
        _RUN.append(folder / "run")
    return _RUN[0]


def call(command: str, args: list[str]) -> int:
    """The command's exit code, as `acroboter <command> ARGS` gives it (argparse's exit included)."""
    module, _, function = COMMANDS[command][0].partition(":")
    main = getattr(importlib.import_module(f"acroboter.cli.{module}"), function or "main")
    args = [str(animated_run()) if a == "{run}" else a for a in args]
    args = [str(lift_plan()[0]) if a == "{lift}" else a for a in args]
    args = [str(short_spec(SHORT[a])) if a in SHORT else a for a in args]
    try:
        return main(args)
    except SystemExit as stop:
        return stop.code


def files(folder: Path) -> dict[str, bytes]:
    """Every file under `folder` (relative path: content), the manifest and dot-files included."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def results(folder: Path) -> set[str]:
    return set(json.loads((folder / MANIFEST).read_text())["commands"][next(iter(
        json.loads((folder / MANIFEST).read_text())["commands"]))]["files"])


def put(folder: Path, names) -> dict[str, bytes]:
    for name in names:
        (folder / name).parent.mkdir(parents=True, exist_ok=True)
        (folder / name).write_bytes(f"the user's own {name}".encode())
    return files(folder)


@pytest.mark.parametrize("command", EVERY)
def test_user_files_survive_and_a_narrower_rerun_leaves_nothing_of_the_wider_one(command, tmp_path, capsys):
    _, wide, wrote, narrow, narrower = COMMANDS[command]
    out = tmp_path / "out"
    out.mkdir()
    mine = put(out, [n for n in LOOKALIKES if n not in wrote | narrower])
    assert call(command, [*wide, "--out", str(out)]) == 0, capsys.readouterr().err
    assert {k: v for k, v in files(out).items() if k in mine} == mine  # untouched
    assert set(files(out)) == set(mine) | wrote | {MANIFEST}
    assert results(out) == wrote  # the manifest lists exactly this run's files
    assert call(command, [*narrow, "--out", str(out)]) == 0, capsys.readouterr().err
    if command in ACCUMULATE:  # another spec's, video's or study's files: both stay, both the command's
        assert set(files(out)) == set(mine) | wrote | narrower | {MANIFEST} and results(out) == wrote | narrower
    else:
        assert set(files(out)) == set(mine) | narrower | {MANIFEST}  # nothing of the wider run
    assert {k: v for k, v in files(out).items() if k in mine} == mine
    assert not [p for p in out.iterdir() if p.is_dir() and p.name not in {"redundant", "noncollocated"}]
    if command == "study":  # issue 36: `study redundant` keeps the study it did not redo, and the user's file
        assert (out / "noncollocated" / "table.md").exists() and (out / "noncollocated" / "notes.txt").exists()


@pytest.mark.parametrize("command", EVERY)
def test_a_users_file_under_a_results_name_is_refused_before_any_work(command, tmp_path, capsys, monkeypatch):
    _, _, _, narrow, narrower = COMMANDS[command]
    out = tmp_path / "out"
    out.mkdir()
    before = put(out, [sorted(narrower)[0]])
    monkeypatch.setattr(outputs.ResultsFolder, "publish", lambda self: pytest.fail("the work ran"))
    assert call(command, [*narrow, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert OPTION.get(command, "--out") in err and sorted(narrower)[0] in err and "Traceback" not in err
    assert files(out) == before


@pytest.mark.parametrize("command", EVERY)
@pytest.mark.parametrize("given", ["", "a file", "unwritable"])
def test_an_empty_or_unusable_out_is_refused_before_any_work(command, given, tmp_path, capsys, monkeypatch):
    _, _, _, narrow, _ = COMMANDS[command]
    if given == "a file" and command in FILE_IS_OUTPUT:
        pytest.skip(f"{command} -o FILE writes that file")
    monkeypatch.chdir(tmp_path)
    target = ""
    if given == "a file":
        target = str(tmp_path / "results.txt")
        Path(target).write_text("mine")
    elif given == "unwritable":
        target = "/proc/acroboter-out"  # no folder can be made there, not even by root
    before = files(tmp_path)
    monkeypatch.setattr(outputs.ResultsFolder, "publish", lambda self: pytest.fail("the work ran"))
    assert call(command, [*narrow, "--out", target]) == 2
    err = capsys.readouterr().err
    assert OPTION.get(command, "--out") in err and "Traceback" not in err
    assert files(tmp_path) == before and [p.name for p in tmp_path.iterdir()] == list(before)


@pytest.mark.parametrize("command", EVERY)
@pytest.mark.parametrize("failure, code", [(OSError(28, "No space left on device"), 3), (KeyboardInterrupt(), 130),
                                           (SimulationError("the loop diverged"), 3)])
def test_a_failed_or_interrupted_run_leaves_the_folder_as_it_was(command, failure, code, tmp_path, capsys,
                                                                monkeypatch):
    """The work done and staged, it fails (a full disk, a computation that cannot run: exit 3) or is interrupted
    just before the swap: the earlier results and the user's files are as they were byte for byte, no staging
    folder is left, and a fresh --out is not made (issue 36: exit 3 keeps the last good results, every command)."""
    _, _, _, narrow, narrower = COMMANDS[command]
    out = tmp_path / "out"
    out.mkdir()
    assert call(command, [*narrow, "--out", str(out)]) == 0, capsys.readouterr().err
    before = put(out, ["notes.txt"])
    staged = []

    def fail(self):
        staged.extend(p.name for p in self.staging.rglob("*"))
        raise failure

    monkeypatch.setattr(outputs.ResultsFolder, "publish", fail)
    assert call(command, [*narrow, "--out", str(out)]) == code
    assert "Traceback" not in capsys.readouterr().err
    assert staged  # it failed with its results staged
    assert files(out) == before and not [p for p in out.iterdir() if p.name.startswith(STAGING_PREFIX)]
    if code == 3 and command in MADE:  # once a command (the work is its cost): a fresh --out is not left behind
        fresh = tmp_path / "fresh" / "deeper"
        assert call(command, [*narrow, "--out", str(fresh)]) == code
        assert not (tmp_path / "fresh").exists()


@pytest.mark.parametrize("command", EVERY)
def test_a_killed_runs_staging_folder_is_cleaned_at_the_next_start(command, tmp_path, capsys):
    _, _, _, narrow, narrower = COMMANDS[command]
    out = tmp_path / "out"
    out.mkdir()
    gone = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    stale = out / f"{STAGING_PREFIX}{command}-{int(gone.stdout)}-abc123"
    live = out / f"{STAGING_PREFIX}{command}-{os.getppid()}-def456"  # a running process's: kept
    for folder in (stale, live):
        (folder / "sub").mkdir(parents=True)  # (out exists: mjcf and animate write into an existing folder)
        (folder / "sub" / "summary.json").write_text("half written")
    assert call(command, [*narrow, "--out", str(out)]) == 0, capsys.readouterr().err
    assert not stale.exists() and live.exists()
    assert results(out) == narrower


HOLD = """
import sys, time
from pathlib import Path
from acroboter.cli.outputs import folder_lock
with folder_lock(Path(sys.argv[1])):
    print("held", flush=True)
    time.sleep(300)
"""


def holding(folder: Path) -> subprocess.Popen:
    """Another process writing into `folder` (holding its lock, as a running command does)."""
    proc = subprocess.Popen([sys.executable, "-c", HOLD, str(folder)], stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline() == "held\n"
    return proc


@pytest.mark.parametrize("command", EVERY)
def test_a_second_command_into_a_folder_in_use_is_refused_naming_the_other(command, tmp_path, capsys, monkeypatch):
    """Two commands into one folder at once: the second exits 3 before any work, naming the first's process, and
    the folder is as the first left it."""
    _, _, _, narrow, _ = COMMANDS[command]
    out = tmp_path / "out"
    before = put(out, ["notes.txt"])
    other = holding(out)
    try:
        monkeypatch.setattr(outputs.ResultsFolder, "publish", lambda self: pytest.fail("the work ran"))
        assert call(command, [*narrow, "--out", str(out)]) == 3
    finally:
        other.kill()
        other.wait()
    err = capsys.readouterr().err
    assert f"process {other.pid}" in err and "another acroboter command is writing into it" in err, err
    assert OPTION.get(command, "--out") in err and "Traceback" not in err
    assert files(out) == before and not [p for p in out.iterdir() if p.name.startswith(STAGING_PREFIX)]


def test_two_real_runs_into_one_folder(tmp_path):
    """A run in progress (a long one) and a second into its folder: refused (exit 3, naming the first); the first
    finishes, or is interrupted, unharmed."""
    out = tmp_path / "out"
    first = subprocess.Popen([sys.executable, "-m", "acroboter", "run", "--method", "iterative", "--iterations",
                              "300", "--duration", "30", "--no-plots", "-q", "--out", str(out)],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 300
    while not (out.exists() and any(p.name.startswith(STAGING_PREFIX) for p in out.iterdir())):
        assert first.poll() is None and time.monotonic() < deadline, first.communicate()
        time.sleep(0.1)
    second = subprocess.run([sys.executable, "-m", "acroboter", "run", "--duration", "0.2", "--no-plots", "-q",
                             "--out", str(out)], capture_output=True, text=True, timeout=300)
    first.send_signal(subprocess.signal.SIGINT)
    _, err = first.communicate(timeout=120)
    assert second.returncode == 3 and f"process {first.pid}" in second.stderr, second.stderr
    assert first.returncode in (0, 130), err  # interrupted, or (a fast machine) done first
    left = list(out.iterdir()) if out.exists() else []  # (interrupted, the first removes the folder it made)
    assert not [p for p in left if p.name.startswith(STAGING_PREFIX)]
    assert not (out / "summary.json").exists() or "iterative-300" in json.loads((out / "summary.json").read_text())[
        "methods"]  # never the second's


def test_generate_never_replaces_a_folder_that_is_not_generated_code(tmp_path, capsys):
    """generate --out DIR writes DIR/<crane>/ whole: a folder of that name that is not a crane's generated code is
    the user's and refused before any work (exit 2); a killed generate's staging goes at the next start."""
    from acroboter.cli import generate

    out = tmp_path / "out"
    before = put(out, ["lab_crane/notes.txt"])
    spec = str(REPO / "model_spec" / "lab_crane.toml")
    assert generate.main(["generate", spec, "--out", str(out), "--no-compile-check"]) == 2
    err = capsys.readouterr().err
    assert "--out" in err and "lab_crane" in err and "not the generated code" in err and "Traceback" not in err
    assert files(out) == before
    shutil.rmtree(out / "lab_crane")
    gone = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    stale = [out / ".lab_crane.new-abcd1234", out / f".lab_crane.old-{int(gone.stdout)}"]
    live = out / f".lab_crane.old-{os.getpid()}"
    for folder in (*stale, live):
        (folder / "lab_crane_phi.c").parent.mkdir(parents=True)
        (folder / "lab_crane_phi.c").write_text("/* half */")
    assert generate.main(["generate", spec, "--out", str(out), "--no-compile-check"]) == 0
    assert not any(p.exists() for p in stale) and live.exists()
    assert json.loads((out / "lab_crane" / "manifest.json").read_text())["spec"] == "lab_crane"
    assert generate.main(["generate", spec, "--out", str(out), "--no-compile-check"]) == 0  # its own: replaced


def test_generate_into_a_folder_in_use_is_refused(tmp_path, capsys):
    from acroboter.cli import generate

    out = tmp_path / "out"
    out.mkdir()
    other = holding(out)
    try:
        code = generate.main(["generate", str(REPO / "model_spec" / "lab_crane.toml"), "--out", str(out)])
    finally:
        other.kill()
        other.wait()
    err = capsys.readouterr().err
    assert code == 3 and f"process {other.pid}" in err and "Traceback" not in err, err
    assert list(out.iterdir()) == []


def test_a_run_replaces_the_videos_animate_recorded_in_its_folder_and_no_other(tmp_path, capsys):
    """animate's GIF in a run folder is in the manifest (animate's entry): a second animate replaces it, the
    next run into the folder removes it (it shows the earlier run); a user's GIF of the same name is refused."""
    from acroboter.cli import animate, run

    out = tmp_path / "out"
    assert run.main(["--duration", "0.2", "--method", "penalty", "--no-plots", "-q", "--out", str(out)]) == 0
    gif = ["--no-mp4", "--gif", str(out), "--gif-fps", "2", "--renderer", "matplotlib", "-q"]
    assert animate.main([str(out), *gif]) == 0, capsys.readouterr().err
    assert (out / "animation_penalty.gif").exists()
    assert animate.main([str(out), *gif]) == 0, capsys.readouterr().err  # its own file: replaced
    mine = put(out, ["animation_mlm.gif"])
    assert run.main(["--duration", "0.2", "--method", "penalty", "--no-plots", "-q", "--out", str(out)]) == 0
    assert not (out / "animation_penalty.gif").exists() and (out / "animation_mlm.gif").exists()
    capsys.readouterr()
    (out / "animation_penalty.gif").write_bytes(b"mine")
    before = files(out)
    assert animate.main([str(out), *gif]) == 2
    assert "--gif" in capsys.readouterr().err and files(out) == before
    assert mine["animation_mlm.gif"] == before["animation_mlm.gif"]


def test_generate_of_a_bad_spec_leaves_no_new_folder(tmp_path, capsys):
    from acroboter.cli import generate

    bad = tmp_path / "bad.toml"
    bad.write_text("name = 'bad'\n[model\n")
    code = generate.main(["generate", str(bad), "--out", str(tmp_path / "new"), "--no-compile-check"])
    assert code == 2 and "Traceback" not in capsys.readouterr().err
    assert not (tmp_path / "new").exists()


@pytest.mark.parametrize("argv", [["mjcf", "-o", ""], ["animate", "results", "--out", ""],
                                  ["generate", "--out", ""], ["export-step", "--out", ""]])
def test_an_empty_output_name_is_refused_by_every_command(argv, tmp_path):
    proc = subprocess.run([sys.executable, "-m", "acroboter", *argv], capture_output=True, text=True,
                          cwd=tmp_path, timeout=120)
    assert proc.returncode == 2 and "an empty name" in proc.stderr and "Traceback" not in proc.stderr
    assert list(tmp_path.iterdir()) == []


def test_a_manifest_path_outside_the_folder_is_never_removed(tmp_path):
    """A manifest edited to name files outside its folder (or garbage) removes nothing outside it."""
    outside = tmp_path / "precious.txt"
    outside.write_text("keep")
    out = tmp_path / "out"
    out.mkdir()
    (out / MANIFEST).write_text(json.dumps({"format": 1, "commands": {"bench": {
        "files": ["../precious.txt", str(outside)], "folders": [".."]}}}))
    with outputs.results_folder(out, "bench") as folder:
        (folder.staging / "bench.json").write_text("{}")
        folder.publish()
    assert outside.read_text() == "keep" and results(out) == {"bench.json"}
    (out / MANIFEST).write_text("not json")
    with outputs.results_folder(out, "bench") as folder:  # unreadable: nothing is ours, and bench.json is refused
        pass
    with pytest.raises(outputs.OutputFolderError, match="bench.json"):
        with outputs.results_folder(out, "bench", expected=["bench.json"]):
            pass
