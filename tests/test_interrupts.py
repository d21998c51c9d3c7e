"""Ctrl-C at any phase of a command (issue 24 item 4): exit 130 with "interrupted", no traceback, no staging folder
left, the output folder as it was, and never "does not compile"; SIGINT sent to the process group (as a terminal
sends it: the compilers and the Dask cluster get it too) and to the process alone.

Each command runs in a session of its own (`python -c`: the console's main, with one function of the phase wrapped
to touch a marker file when the phase starts); the signal goes once the marker is there (and, for the compile,
once a cc1 runs). Phases that are short by nature (reading the spec, writing the figures) are made long by doing
their real work over and over until the signal lands in it. How long the command took to exit is printed
(`pytest -s`), never asserted: the limits below (20 s) only keep a hung command from hanging the suite.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
SPEC_DIR = REPO / "model_spec"
EXIT_LIMIT_S = 20.0  # after the signal (a limit, not a measurement)
START_LIMIT_S = 300.0  # until the phase starts, on a loaded machine

PRELUDE = """
import importlib, pathlib, sys
marker = pathlib.Path({marker!r})
module = importlib.import_module({module!r})
owner = getattr(module, {owner!r}) if {owner!r} else module
real = getattr(owner, {name!r})

def wrapped(*args, **kwargs):
    marker.touch()
    if {repeat!r}:  # a short phase: its real work over and over, until Ctrl-C lands in it
        while True:
            real(*args, **kwargs)
    return real(*args, **kwargs)

setattr(owner, {name!r}, wrapped)
{extra}
from acroboter.cli.console import main
sys.exit(main({argv!r}))
"""


def session_processes(sid: int) -> dict[int, str]:
    """pid -> command name of every process in the session `sid` (Linux /proc)."""
    found = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
        except OSError:
            continue
        name = stat[stat.index("(") + 1: stat.rindex(")")]
        fields = stat[stat.rindex(")") + 2:].split()
        if int(fields[3]) == sid:  # state, ppid, pgrp, session
            found[int(entry.name)] = name
    return found


def children_running(pid: int, pattern: str) -> list[int]:
    """The processes whose parent is `pid` and whose command line contains `pattern`."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
            cmdline = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:
            continue
        if int(stat[stat.rindex(")") + 2:].split()[1]) == pid and pattern in cmdline:
            found.append(int(entry.name))
    return found


def interrupt(tmp_path: Path, argv: list[str], hook: tuple[str, str, str], *, group: bool, repeat: bool = False,
              wait_for: str | None = None, env: dict | None = None, extra: str = "",
              sent_at: list[float] | None = None, signum: int = signal.SIGINT) -> tuple[int, str, float, list[int]]:
    """Run `acroboter ARGV` with `hook` (module, class or '', function) marked, `signum` (SIGINT) once the phase
    started; (exit code, stderr, seconds from the signal to the exit, the pids of any Dask cluster it had started)."""
    marker = tmp_path / "phase-started"
    marker.unlink(missing_ok=True)  # an earlier call's: the phase of this one has not started
    module, owner, name = hook
    script = PRELUDE.format(marker=str(marker), module=module, owner=owner, name=name, repeat=repeat, argv=argv,
                            extra=extra)
    proc = subprocess.Popen([sys.executable, "-c", script], cwd=tmp_path, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True,
                            env={**os.environ, **(env or {})})
    try:
        deadline = time.monotonic() + START_LIMIT_S
        while not marker.exists() or (wait_for and not any(name.startswith(wait_for) for name in
                                                            session_processes(proc.pid).values())):
            assert proc.poll() is None, f"ended before the phase: {proc.communicate()}"
            assert time.monotonic() < deadline, "the phase never started"
            time.sleep(0.05)
        time.sleep(0.2)  # inside the phase
        clusters = children_running(proc.pid, "acroboter.studies.cluster")
        sent = time.monotonic()
        if sent_at is not None:
            sent_at.append(time.time())
        if group:
            os.killpg(proc.pid, signum)  # what a terminal's Ctrl-C (a closed terminal's SIGHUP) does
        else:
            proc.send_signal(signum)  # what `kill` and `timeout` do
        _, err = proc.communicate(timeout=EXIT_LIMIT_S)
        latency = time.monotonic() - sent
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.communicate()
    print(f"\n{argv[0]} ({name}) {signal.Signals(signum).name} to the {'group' if group else 'process'}: exit "
          f"{proc.returncode} "
          f"{latency:.2f} s after the signal")
    deadline = time.monotonic() + 10
    while session_processes(proc.pid) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not session_processes(proc.pid), "processes of the command outlived it (compilers?)"
    return proc.returncode, err, latency, clusters


def staging_left(*folders: Path) -> list[str]:
    """Staging folders (ours, the code generator's, the compiler's) anywhere under `folders`."""
    pattern = re.compile(r"\.acroboter-staging-.*|\..+\.new-.*|\..+\.old-\d+|\..+\.partial\..*")
    return [str(p) for f in folders if f.exists() for p in f.rglob(".*") if pattern.fullmatch(p.name)]


def assert_interrupted(code: int, err: str, signum: int = signal.SIGINT) -> None:
    assert code == 128 + signum, err  # 130 Ctrl-C, 143 SIGTERM, 129 SIGHUP
    assert "interrupted" in err and "Traceback" not in err, err
    assert "does not compile" not in err and "Warning" not in err, err


GROUP = pytest.mark.parametrize("group", [True, False], ids=["group", "process"])


@GROUP
def test_while_the_spec_is_read(tmp_path, group):
    out = tmp_path / "out"
    code, err, _, _ = interrupt(tmp_path, ["run", "--duration", "0.2", "--out", str(out), "-q"],
                                ("acroboter.api.crane", "", "load_spec"), group=group, repeat=True)
    assert_interrupted(code, err)
    assert not out.exists() and not staging_left(tmp_path)


@GROUP
def test_while_casadi_generates_the_code(tmp_path, group):
    """Inside CasADi (which swallows a KeyboardInterrupt raised in its calls): raised as soon as it returns, and
    the generated folder's previous files stay (a spec of one's own, generated into a fresh cache on first use)."""
    spec = tmp_path / "mine.toml"
    spec.write_text((SPEC_DIR / "lab_crane.toml").read_text().replace("mass = 2.0", "mass = 2.1"))
    cache, out = tmp_path / "cache", tmp_path / "out"
    code, err, _, _ = interrupt(tmp_path, ["run", "--spec", str(spec), "--duration", "0.2", "--out", str(out), "-q"],
                                ("acroboter.codegen.emit_c", "GenerationContext", "register_all"), group=group,
                                env={"ACROBOTER_CACHE_DIR": str(cache)})
    assert_interrupted(code, err)
    assert not out.exists() and not staging_left(tmp_path)
    assert not list((cache / "generated").glob("*/*")), "a half-generated crane in the cache"


@GROUP
def test_while_the_generated_c_compiles(tmp_path, group):
    """generate's compile check: SIGINT to the group kills the compilers too (that was 'does not compile', exit 3);
    to the process alone it stops them (that took 7-28 s)."""
    out, tmp, ends, sent = tmp_path / "generated", tmp_path / "tmp", tmp_path / "compiles.log", []
    tmp.mkdir()
    log_ends = COMPILE_ENDS.format(log=str(ends))
    code, err, _, _ = interrupt(tmp_path, ["generate", str(SPEC_DIR / "lab_crane.toml"), "--out", str(out)],
                                ("acroboter.runtime.compile_library", "", "build"), group=group, wait_for="cc1",
                                env={"TMPDIR": str(tmp)}, extra=log_ends, sent_at=sent)
    assert_interrupted(code, err)
    assert not out.exists() and not staging_left(tmp_path)
    assert list(tmp.iterdir()) == []  # the compile check's folder went too (and gcc's own temporary files)
    # stopped, not waited for: no compiler that was still running when the signal went finished its file
    finished = [line.split() for line in ends.read_text().splitlines()]
    assert not [(t, c) for t, c in finished if float(t) > sent[0] and int(c) == 0], finished


COMPILE_ENDS = """
import time
from acroboter.runtime import compile_library as _build
_run = _build._Compilers.run

def _logged(self, command):
    code, err = _run(self, command)
    with open({log!r}, "a") as f:
        f.write(f"{{time.time()}} {{code}}\\n")
    return code, err

_build._Compilers.run = _logged
"""


@GROUP
def test_while_the_closed_loop_runs(tmp_path, group):
    out = tmp_path / "out"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    code, err, _, _ = interrupt(tmp_path, ["run", "--duration", "30", "--method", "iterative", "--iterations", "300",
                                           "--out", str(out), "-q"],
                                ("acroboter.api.crane", "", "simulate"), group=group)
    assert_interrupted(code, err)
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt"] and not staging_left(tmp_path)


OTHER_SIGNALS = pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGHUP], ids=["SIGTERM", "SIGHUP"])


@OTHER_SIGNALS
def test_sigterm_and_sighup_stop_a_run_as_ctrl_c_does(tmp_path, signum):
    """Issue 36: SIGTERM (what `kill` and `timeout` send) 3 s into a run left a new folder holding only a staging
    folder. Now it exits 143 (SIGHUP 129) and the folder is as it was, as for Ctrl-C."""
    out = tmp_path / "out"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    code, err, _, _ = interrupt(tmp_path, ["run", "--duration", "30", "--method", "iterative", "--iterations", "300",
                                           "--out", str(out), "-q"],
                                ("acroboter.api.crane", "", "simulate"), group=False, signum=signum)
    assert_interrupted(code, err, signum)
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt"] and not staging_left(tmp_path)
    fresh = tmp_path / "fresh"  # a folder the run created is removed again
    code, err, _, _ = interrupt(tmp_path, ["run", "--duration", "30", "--method", "penalty", "--out", str(fresh),
                                           "-q"], ("acroboter.api.crane", "", "simulate"), group=False, signum=signum)
    assert_interrupted(code, err, signum)
    assert not fresh.exists() and not staging_left(tmp_path)


@pytest.mark.needs_dask
@GROUP
def test_while_a_dask_study_runs(tmp_path, group):
    """The cluster runs in a session of its own: no worker prints a KeyboardInterrupt traceback, the command ends
    the cluster at once, and none of its processes outlives the command."""
    out = tmp_path / "sweep"
    code, err, _, clusters = interrupt(tmp_path, ["sweep", "--alphas", "1e3:1e9", "--omegas", "10,20", "--iterations",
                                                  "1,3", "--duration", "30", "--workers", "2", "--no-plots", "-q",
                                                  "--out", str(out)],
                                       ("distributed", "", "as_completed"), group=group)
    assert_interrupted(code, err)
    assert not out.exists() and not staging_left(tmp_path)
    assert clusters, "no local cluster process was seen"
    for pid in clusters:
        assert not Path(f"/proc/{pid}").exists() or "(Z)" in Path(f"/proc/{pid}/stat").read_text()


# Ctrl-C to the group or the process alone; SIGTERM (`kill`, `timeout`) and SIGHUP (a closed terminal) stop a command
# as Ctrl-C does (issue 36: SIGTERM left a staging folder, a time-out of animate a .partial.mp4)
SIGNAL_CASES = pytest.mark.parametrize(("group", "signum"), [(True, signal.SIGINT), (False, signal.SIGINT),
                                                              (False, signal.SIGTERM), (False, signal.SIGHUP)],
                                       ids=["group", "process", "SIGTERM", "SIGHUP"])


@SIGNAL_CASES
def test_while_the_figures_are_written(tmp_path, group, signum):
    """The CSVs are staged, the figures being drawn: the earlier results stay as they were."""
    out = tmp_path / "out"
    assert subprocess.run([sys.executable, "-m", "acroboter", "run", "--duration", "0.2", "--method", "mlm",
                           "--no-plots", "-q", "--out", str(out)], capture_output=True, timeout=300).returncode == 0
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    code, err, _, _ = interrupt(tmp_path, ["run", "--duration", "0.2", "--method", "penalty", "--out", str(out), "-q"],
                                ("acroboter.report.report", "", "write_figures"), group=group, repeat=True,
                                signum=signum)
    assert_interrupted(code, err, signum)
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before and not staging_left(tmp_path)


@pytest.mark.needs_animation
@pytest.mark.parametrize(("group", "signum"), [(True, signal.SIGINT), (False, signal.SIGINT),
                                              (False, signal.SIGTERM)], ids=["group", "process", "SIGTERM"])
def test_while_a_video_is_encoded(tmp_path, group, signum):
    """ffmpeg (in a process group of its own: imageio-ffmpeg's) is killed before its input closes: it prints no
    complaint about a half frame, and the run's folder is as it was."""
    out = tmp_path / "run"
    assert subprocess.run([sys.executable, "-m", "acroboter", "run", "--duration", "10", "--method", "penalty",
                           "--no-plots", "-q", "--out", str(out)], capture_output=True, timeout=300).returncode == 0
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    code, err, _, _ = interrupt(tmp_path, ["animate", str(out), "--renderer", "matplotlib", "-q"],
                                ("acroboter.cli.animate", "", "write_complete"), group=group, wait_for="ffmpeg",
                                signum=signum)
    assert_interrupted(code, err, signum)
    assert err.strip() == "interrupted", err
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before and not staging_left(tmp_path)


def test_an_interrupt_inside_casadi_is_not_swallowed(monkeypatch):
    """In this process, the error boundary's handler: SIGINT from another thread while CasADi builds the penalty
    terms stops the generation before it writes a file (with Python's own handler CasADi swallowed it at times,
    and the earlier handler held it until the files were written)."""
    import threading

    from acroboter.codegen import emit_c as codegen
    from acroboter.codegen import solver_terms as structured
    from acroboter.model.spec import load_spec
    from acroboter.process.interrupts import remembered_interrupt

    wrote = []
    real = structured.penalty_terms

    def penalty_terms(*args, **kwargs):  # the signal arrives while CasADi works
        threading.Timer(0.05, os.kill, (os.getpid(), signal.SIGINT)).start()
        return real(*args, **kwargs)

    monkeypatch.setattr(structured, "penalty_terms", penalty_terms)
    with pytest.raises(KeyboardInterrupt), remembered_interrupt():
        codegen.GenerationContext(load_spec(SPEC_DIR / "acroboter.toml")).register_all()
        time.sleep(5)  # were it swallowed, the timer's signal would still be raised here: not within register_all
        wrote.append("register_all returned")
    assert wrote == []


def test_an_interrupt_a_library_turned_into_its_own_error_is_an_interrupt(capsys):
    """A C extension that gets the KeyboardInterrupt from a Python call it makes may raise an error of its own
    instead (matplotlib's Agg: "ValueError: Invalid bounding box", seen when Ctrl-C hit `animate` mid-frame): after a
    SIGINT the command exits 130 with "interrupted", not an internal error. Without a SIGINT the error stays one."""
    from acroboter.cli.entry import EXIT_INTERRUPTED, guarded

    def drawing(interrupted: bool) -> int:
        if interrupted:
            try:
                os.kill(os.getpid(), signal.SIGINT)
                time.sleep(5)  # the handler raises here
            except KeyboardInterrupt:  # what the extension does with it
                raise ValueError("Invalid bounding box") from None
        raise ValueError("Invalid bounding box")

    assert guarded(drawing)(True) == EXIT_INTERRUPTED
    assert capsys.readouterr().err.strip() == "interrupted"
    assert guarded(drawing)(False) == 3
    assert "internal error (ValueError: Invalid bounding box)" in capsys.readouterr().err


def test_a_ctrl_c_that_a_weakref_callback_swallows_is_not_lost(capsys):
    """CI, 2026-12-03: a SIGINT landed while matplotlib's weakref callback ran during garbage collection; Python
    printed "Exception ignored in" and went on, and `animate` published its video and exited 0. Now the block
    remembers such a Ctrl-C: nothing is published after it (deferred_interrupt raises first) and nothing is printed."""
    import weakref

    from acroboter.process.interrupts import deferred_interrupt, remembered_interrupt

    class Node:
        pass

    published = []
    with pytest.raises(KeyboardInterrupt):
        with remembered_interrupt():
            node = Node()
            ref = weakref.ref(node, lambda _: signal.raise_signal(signal.SIGINT))  # the handler runs in there
            del node
            assert ref() is None
            with deferred_interrupt():
                published.append("results")
    assert published == []
    assert "Exception ignored" not in capsys.readouterr().err
    seen, hook = [], sys.unraisablehook
    sys.unraisablehook = lambda unraisable: seen.append(unraisable.exc_type)
    try:
        with remembered_interrupt() as state:  # an exception of another kind goes to the hook that was there
            node = Node()
            ref = weakref.ref(node, lambda _: 1 / 0)
            del node
    finally:
        sys.unraisablehook = hook
    assert not state.received and seen == [ZeroDivisionError]


def test_ctrl_c_stops_the_plans_solve_within_an_iteration(tmp_path):
    """Issue 34 item 5: Ctrl-C took 8-11 s to stop a plan, IPOPT going on to the end of its solve (no Python runs
    inside it). Its iteration callback now polls the signal and ends the solve: IPOPT's own status says it was
    stopped (User_Requested_Stop), not that it finished, and the command exits 130 with nothing written."""
    from conftest import write_lift_spec

    write_lift_spec(tmp_path)
    status = tmp_path / "ipopt-status"
    record = f"""
import casadi
_solve = casadi.Opti.solve
def _recorded(self, *args, **kwargs):
    try:
        return _solve(self, *args, **kwargs)
    finally:
        pathlib.Path({str(status)!r}).write_text(str(self.stats().get("return_status")))
casadi.Opti.solve = _recorded
"""
    out = tmp_path / "plan"
    code, err, _, _ = interrupt(tmp_path, ["plan", "--spec", str(tmp_path / "lift.toml"), "--intervals", "24",
                                           "--no-certificate", "--out", str(out), "-q"],
                                ("casadi", "Opti", "solve"), group=False, extra=record)
    assert_interrupted(code, err)
    assert status.read_text() == "User_Requested_Stop"
    assert not out.exists() and not staging_left(tmp_path)
