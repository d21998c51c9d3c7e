"""The penalty-number sweep (acroboter.sweep) on a real dask.distributed cluster on 127.0.0.1.

A tiny grid — α ∈ {1e3, 1e7}, Ω = 10, penalty and iterative-3, plus the MLM reference, 1 s of the path —
through the function API (a LocalCluster owned by the test, used both directly and as a --scheduler
address) and through the CLI (its own one-worker LocalCluster). Clusters are always closed by context
managers. The task function also runs in-process for the failure statuses and the no-compile rule,
and the CLI without dask installed (an optional extra) for its one-line error.
"""

from __future__ import annotations

import csv
import math
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from acroboter.cli import sweep as sw
from acroboter.process.extras import MissingExtraError
from acroboter.studies import grid
from acroboter.studies import penalty_grid as pg
from acroboter.studies import run_verdicts as judging

REPO = Path(__file__).resolve().parent.parent
SPEC = REPO / "model_spec" / "acroboter.toml"
ALPHAS, OMEGAS, ITERATIONS, DURATION = [1e3, 1e7], [10.0], [1, 3], 1.0
N_RUNS = 1 + len(ALPHAS) * len(OMEGAS) * len(ITERATIONS)
# dask is an optional extra (acroboter[dask]): the tests that start a cluster need it.
needs_dask = pytest.mark.needs_dask
# Python code that makes dask and distributed unimportable, as if they were not installed.
WITHOUT_DASK = "import sys; sys.modules['dask'] = None; sys.modules['distributed'] = None; "


def run_cli(*args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "acroboter.sweep", *args], capture_output=True, text=True,
                          cwd=REPO, timeout=timeout)


def check_rows(rows: list[dict]) -> None:
    """The tiny grid's rows: all finished, MLM once, the default α = 1e7 tracks like MLM."""
    assert len(rows) == N_RUNS
    assert all(set(r) >= set(pg.COLUMNS) for r in rows)
    assert [r["status"] for r in rows] == ["ok"] * N_RUNS, [r["status"] for r in rows]
    mlm = [r for r in rows if r["method"] == "mlm"]
    assert len(mlm) == 1 and mlm[0]["alpha_geometric"] is None and mlm[0]["iterations"] is None
    ref = mlm[0]["max_position_error_mm"]
    assert 0 < ref < 0.5
    assert math.isnan(mlm[0]["cond_penalty_matrix"])  # MLM has no penalty matrix
    by_key = {(r["method"], r["alpha_geometric"]): r for r in rows if r["method"] != "mlm"}
    assert set(by_key) == {(m, a) for m in ("penalty", "iterative-3") for a in ALPHAS}
    for method in ("penalty", "iterative-3"):
        r = by_key[(method, 1e7)]
        assert r["alpha_servo"] == 1e7 and r["omega"] == 10.0
        assert r["max_position_error_mm"] < 2 * ref  # the paper: Penalty and MLM almost overlap
        assert r["max_yaw_error_deg"] < 0.01 and r["max_constraint_violation"] < 1e-9
        assert r["min_winch_tension_N"] > 0 and r["median_control_step_us"] > 0
        assert 1e8 < r["cond_penalty_matrix"] < 1e11  # grows like α: ~1.4e2·α on this crane
    # α = 1e3 is too soft for the plain penalty method: its commanded q̈ misses the servo-constraints.
    soft, stiff = by_key[("penalty", 1e3)], by_key[("penalty", 1e7)]
    assert soft["max_position_error_mm"] > 10 * stiff["max_position_error_mm"]
    assert soft["max_servo_accel_residual"] > 1e3 * stiff["max_servo_accel_residual"]


@needs_dask
def test_function_api_on_a_local_cluster(tmp_path):
    from distributed import Client, LocalCluster

    cases = pg.make_grid(ALPHAS, OMEGAS, ITERATIONS)
    assert len(cases) == N_RUNS and cases[0].method == "mlm"
    with (
        LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1", dashboard_address=None)
        as cluster,
        Client(cluster) as client,
    ):
        rows = pg.run_sweep(client, SPEC, cases, DURATION)
        check_rows(rows)
        assert {r["worker"] for r in rows} <= set(client.scheduler_info()["workers"])
        # The same cluster as a --scheduler address: the whole study with its files.
        result = sw.sweep(SPEC, alphas=ALPHAS, omegas=OMEGAS, iterations=ITERATIONS, duration=DURATION,
                          scheduler=cluster.scheduler_address, out=tmp_path)
    assert result.workers == 2
    check_rows(result.rows)
    names = {p.name for p in tmp_path.iterdir()}
    assert {"sweep.csv", "sweep_tracking_error.png", "sweep_constraints.png", "sweep_condition.png"} <= names
    for png in tmp_path.glob("*.png"):
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    check_rows(pg.read_csv(tmp_path / "sweep.csv"))
    text = "\n".join(judging.findings(result.rows))
    assert "iterative-3 (Ω = 10): good for 1e+03 <= α <= 1e+07" in text
    assert "penalty (Ω = 10): good for 1e+07" in text and "soft penalty" in text


@needs_dask
def test_cli_on_a_one_worker_cluster(tmp_path):
    proc = run_cli("--alphas", "1e3,1e7", "--omegas", "10", "--iterations", "1,3", "--duration", str(DURATION),
                   "--workers", "1", "--no-plots", "--quiet", "--out", str(tmp_path))
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stderr
    with (tmp_path / "sweep.csv").open() as f:
        reader = csv.reader(f)
        header = next(reader)
        body = list(reader)
    assert header == pg.COLUMNS
    assert len(body) == N_RUNS
    check_rows(pg.read_csv(tmp_path / "sweep.csv"))
    assert not list(tmp_path.glob("*.png"))
    assert f"{N_RUNS} runs of 1 s" in proc.stdout and "on 1 worker(s)" in proc.stdout
    assert "mlm (no penalty numbers)" in proc.stdout and "good for" in proc.stdout


@needs_dask
def test_unreachable_scheduler_is_a_clear_error():
    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    proc = run_cli("--scheduler", f"tcp://127.0.0.1:{port}", "--connect-timeout", "2", "--no-plots", timeout=300)
    assert proc.returncode == 2
    assert "cannot connect to the Dask scheduler" in proc.stderr and f"127.0.0.1:{port}" in proc.stderr
    assert "Traceback" not in proc.stderr


def test_help_and_bad_options():
    proc = run_cli("--help", timeout=300)
    assert proc.returncode == 0
    for option in ("--spec", "--alphas", "--alpha-mode", "--omegas", "--iterations", "--duration", "--out",
                   "--scheduler", "--workers", "--no-plots"):
        assert option in proc.stdout
    for args, words in ((["--alphas", "1e3:abc"], "--alphas"),
                        (["--iterations", "0"], "expected a whole number 1 <= iterations <= 1000, found 0"),
                        (["--workers", "0"], "--workers"), (["--duration", "-1"], "--duration")):
        proc = run_cli(*args, timeout=300)
        assert proc.returncode == 2 and words in proc.stderr and "Traceback" not in proc.stderr


def test_grid_values_and_modes():
    assert grid.parse_values("1e3:1e12") == [10.0**k for k in range(3, 13)]
    assert grid.parse_values("1:100:2") == pytest.approx([1, 10**0.5, 10, 10**1.5, 100])
    assert grid.parse_values("5, 10,20,10") == [5.0, 10.0, 20.0]
    for bad in ("", "a", "0:10", "10:1", "-1", "1:10:0.5"):
        with pytest.raises(ValueError):
            grid.parse_values(bad)
    assert pg.parse_iterations("1,3,5") == [1, 3, 5]
    pairs = pg.make_grid([1e3, 1e6], [10.0], [1], "grid")
    assert {(c.alpha_geometric, c.alpha_servo) for c in pairs[1:]} == {(a, b) for a in (1e3, 1e6) for b in (1e3, 1e6)}
    servo = pg.make_grid([1e3, 1e6], [10.0], [1, 5], "servo", fixed_geometric=7.0)
    assert [(c.method, c.alpha_geometric, c.alpha_servo) for c in servo[1:]] == [
        ("penalty", 7.0, 1e3), ("penalty", 7.0, 1e6), ("iterative-5", 7.0, 1e3), ("iterative-5", 7.0, 1e6)]


def test_task_statuses_in_process():
    """Divergence at the smallest α the range allows (1: the penalty enforces nothing) and a Cholesky failure at the
    largest are statuses, not exceptions."""
    text = SPEC.read_text()
    diverged = pg.run_case(text, str(SPEC), pg.Case("penalty", 1.0, 1.0, 10.0, 1), 0.6)
    assert diverged["status"].startswith("diverged at t = 0.3"), diverged["status"]
    assert diverged["max_position_error_mm"] is None and diverged["cond_penalty_matrix"] > 0
    broken = pg.run_case(text, str(SPEC), pg.Case("iterative-3", 1e16, 1e16, 10.0, 3), 0.2)
    assert broken["status"].startswith("error: ") and "not positive definite" in broken["status"]
    assert broken["cond_penalty_matrix"] > 1e16  # beyond 1/eps: why the factorization fails


def test_task_never_compiles(monkeypatch, tmp_path):
    """A worker whose cache has no library for the spec says so; it neither generates nor compiles."""
    monkeypatch.setenv("ACROBOTER_CACHE_DIR", str(tmp_path))
    text = SPEC.read_text() + "\n# a variant: not in the worker's model cache\n"
    with pytest.raises(grid.MissingLibraryError, match="never compile"):
        pg.run_case(text, str(SPEC), pg.Case("mlm"), 0.1)
    assert not (tmp_path / "lib").exists() and not (tmp_path / "generated").exists()


def test_cases_run_in_process_in_order():
    """Without a client the same runner runs here: results in case order, a failure through on_error."""
    assert grid.run_cases(lambda c: 1 / c, [1, 0, 4], on_error=lambda c, err: type(err).__name__) == [
        1.0, "ZeroDivisionError", 0.25]
    with pytest.raises(ZeroDivisionError):
        grid.run_cases(lambda c: 1 / c, [0])
    rows = pg.run_sweep(None, SPEC, pg.make_grid([1e7], [10.0], [3]), 0.2)
    assert [(r["method"], r["status"], r["worker"]) for r in rows] == [("mlm", "ok", "local"),
                                                                       ("iterative-3", "ok", "local")]


def test_import_and_help_need_no_dask():
    """Importing the sweep loads no dask; with dask unimportable, `acroboter sweep --help` still works."""
    code = "import sys, acroboter.sweep; print(sorted({'dask', 'distributed'} & set(sys.modules)))"
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO, timeout=300)
    assert proc.returncode == 0 and proc.stdout.strip() == "[]", proc.stdout + proc.stderr
    code = WITHOUT_DASK + "from acroboter.cli.console import main; sys.exit(main(['sweep', '--help']))"
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert "--scheduler" in proc.stdout and "Traceback" not in proc.stderr


def test_a_sweep_without_dask_says_what_to_install(monkeypatch, capsys, tmp_path):
    """No dask: one line naming the cause and the fix, exit 2 (a missing extra), before any work: not even
    --out is made."""
    monkeypatch.setitem(sys.modules, "dask", None)  # as if not installed: find_spec finds nothing
    monkeypatch.setitem(sys.modules, "distributed", None)
    assert sw.main(["--out", str(tmp_path / "out"), "--quiet"]) == 2
    captured = capsys.readouterr()
    assert captured.err.splitlines() == [
        "error: acroboter sweep needs the dask extra (dask is not installed): pip install 'acroboter[dask]' "
        "(in this checkout: make setup)"]
    assert captured.out == "" and not (tmp_path / "out").exists()
    with pytest.raises(MissingExtraError, match="acroboter\\[dask\\]"):  # the function API alike (an ImportError)
        sw.sweep(SPEC, out=tmp_path / "api")
    assert not (tmp_path / "api").exists()
