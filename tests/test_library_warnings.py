"""No helper library's words on a user's terminal (issue 24 item 4): numpy's RuntimeWarnings with their source
paths, Dask's UserWarnings and its logged CommClosedError tracebacks stay off stderr, on a successful run and on
a reported failure; -v shows a warning as a debug line. The places where such a warning meant something say it
in the package's words instead (the input distribution: terms that are not finite; the sensing: test_sensing).

A command runs in a subprocess with one function wrapped to emit, each time it is called, a numpy overflow
warning, a library's UserWarning and an error logged by Dask's logger, then do its real work."""

from __future__ import annotations

import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parent.parent

NOISY = """
import importlib, logging, sys, warnings
import numpy as np
module = importlib.import_module({module!r})
real = getattr(module, {name!r})

def noisy(*args, **kwargs):
    np.float64(1e308) * np.float64(10.0)  # RuntimeWarning: overflow encountered in scalar multiply
    warnings.warn("Port 8787 is already in use.", UserWarning)
    logging.getLogger("distributed.comm.tcp").error("Traceback (most recent call last):\\n  CommClosedError: in <TCP>")
    return real(*args, **kwargs)

setattr(module, {name!r}, noisy)
from acroboter.cli.console import main
sys.exit(main({argv!r}))
"""
LEAKS = ("Warning", "Traceback", "CommClosedError", ".py:", "overflow", "Port 8787")


def run_noisy(tmp_path, argv, hook=("acroboter.api.crane", "simulate")):
    script = NOISY.format(module=hook[0], name=hook[1], argv=argv)
    return subprocess.run([sys.executable, "-c", script], cwd=tmp_path, capture_output=True, text=True, timeout=600)


def test_a_successful_run_shows_no_library_warning(tmp_path):
    proc = run_noisy(tmp_path, ["run", "--duration", "0.2", "--method", "mlm,penalty", "--no-plots",
                                "--out", str(tmp_path / "out")])
    assert proc.returncode == 0, proc.stderr
    assert not [w for w in LEAKS if w in proc.stderr], proc.stderr
    verbose = run_noisy(tmp_path, ["-v", "run", "--duration", "0.2", "--method", "mlm", "--no-plots",
                                   "--out", str(tmp_path / "out")])
    assert verbose.returncode == 0, verbose.stderr
    assert "RuntimeWarning (" in verbose.stderr and "overflow" in verbose.stderr  # -v: a debug line, with its place


def test_a_reported_failure_shows_no_library_warning(tmp_path):
    """No method can run (MLM where the constraints are redundant: a singular system at its first step): the
    package's message, and nothing else."""
    proc = run_noisy(tmp_path, ["run", "--spec", "acroboter_redundant", "--duration", "0.2", "--method", "mlm",
                                "--out", str(tmp_path / "out")], hook=("acroboter.api.crane", "load_spec"))
    assert proc.returncode == 3 and "error: no method could run" in proc.stderr, proc.stderr
    assert not [w for w in LEAKS if w in proc.stderr], proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert all(line.startswith(("warning: ", "error: ")) for line in lines), lines


@pytest.mark.needs_dask
def test_a_successful_sweep_shows_only_its_own_lines(tmp_path):
    """Dask on two workers: what the cluster and its workers print is theirs (read by the command, -v shows it);
    on the terminal only the sweep's own line (and no 'Port 8787 is already in use' when another cluster has it)."""
    proc = run_noisy(tmp_path, ["sweep", "--alphas", "1e3,1e7", "--omegas", "10", "--iterations", "1",
                                "--duration", "0.2", "--workers", "2", "--no-plots", "-q",
                                "--out", str(tmp_path / "sweep")], hook=("distributed", "as_completed"))
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr.strip().splitlines() == ["sweep: 3 runs on a local cluster of 2 worker process(es) on 127.0.0.1"]


@pytest.mark.needs_dask
def test_the_local_clusters_output_is_not_the_terminals(monkeypatch):
    """The cluster process (and so its workers) write into a pipe the command reads, in a session of its own."""
    import os

    from acroboter.studies import cluster

    started = []

    class Recorded(subprocess.Popen):  # the process local_cluster starts, as it started it (no search of /proc)
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            started.append(self)

    monkeypatch.setattr(cluster.subprocess, "Popen", Recorded)
    with cluster.local_cluster(1) as address:
        assert address.startswith("tcp://127.0.0.1:")
        [proc] = started
        assert "acroboter.studies.cluster" in proc.args
        for fd in (1, 2):
            assert os.readlink(f"/proc/{proc.pid}/fd/{fd}").startswith("pipe:")
        assert os.getsid(proc.pid) == proc.pid != os.getsid(0)


def test_the_input_distributions_check_of_huge_terms_warns_nothing():
    """G and g of a controller gone wild (a gain of 1e300): the package's DistributionError, not numpy's overflow."""
    from acroboter.control.distribution import BoundedInputs, DistributionError

    inputs = BoundedInputs(np.zeros(3), np.full(3, 100.0), np.full(3, 10.0))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(DistributionError, match="not finite"):
            inputs.solve(np.eye(3), np.array([1e300, np.inf, 1.0]))
        with pytest.raises(DistributionError):  # large, finite: the QP's word, no overflow warning on the way in
            inputs.solve(np.eye(3), np.full(3, 1e200))
