"""Every command line behind the one error boundary (acroboter.cli.entry): bad options and an unwritable
--out exit 2 with one message and no traceback, before any work."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
UNWRITABLE = "/proc/acroboter-out"

CASES = [
    ("acroboter.run", ["--kp", "nan"], "argument --kp: expected 0 < kp <= 1e4 (1/s), found nan"),
    ("acroboter.run", ["--mu", "-1"], "argument --mu: expected 0 < mu <= 1000, found -1"),
    ("acroboter.run", ["--iterations", "0"], "expected a whole number 1 <= iterations <= 1000, found 0"),
    ("acroboter.bench", ["--repeats", "0"], "expected a whole number 1 <= repeats <= 100, found 0"),
    ("acroboter.bench", ["--casadi-states", "nan"], "expected a whole number 1 <= casadi_states <= 100000, found nan"),
    ("acroboter.bench", ["--method", "iterative-100000000"], "1 <= N <= 1000"),
    ("acroboter.bench", ["--out", UNWRITABLE], "cannot write results into --out"),
    ("acroboter.study", ["--duration", "9000"], "expected 0 < duration <= 7200 (s), found 9000"),
    ("acroboter.study", ["--duration", "nan"], "expected 0 < duration <= 7200 (s), found nan"),
    ("acroboter.study", ["--out", UNWRITABLE], "cannot write results into --out"),
    ("acroboter.study", ["--duration", "0.001"], "is no control step"),
    pytest.param("acroboter.sweep", ["--duration", "0.001", "--out", "/tmp/acroboter-sweep-zero"], "is 0 control steps",
                 marks=pytest.mark.needs_dask),  # checked after the extra (without it: its line, exit 2)
    ("acroboter.sweep", ["--tolerance", "nan"], "expected 1 < tolerance <= 1e6, found nan"),
    ("acroboter.sweep", ["--duration", "nan"], "expected 0 < duration <= 1e6 (s), found nan"),
    ("acroboter.sweep", ["--connect-timeout", "nan"], "expected 0 < connect_timeout <= 3600 (s), found nan"),
    ("acroboter.sweep", ["--workers", "0"], "expected a whole number 1 <= workers <= 64, found 0"),
    ("acroboter.sweep", ["--iterations", "100000000"], "expected a whole number 1 <= iterations <= 1000"),
    pytest.param("acroboter.sweep", ["--out", UNWRITABLE], "cannot write results into --out",
                 marks=pytest.mark.needs_dask),
    ("acroboter", ["generate", "--out", UNWRITABLE], "cannot write into --out"),
    ("acroboter", ["export-step", "--out", UNWRITABLE], "cannot write into --out"),
    ("acroboter", ["export-step", "--kp", "nan"], "argument --kp: expected 0 < kp <= 1e4 (1/s), found nan"),
    ("acroboter", ["export-step", "--kappa", "-1"], "argument --kappa: expected 0 <= kappa <= 1, found -1"),
    ("acroboter", ["export-step", "--method", "iterative-1001"], "1 <= N <= 1000"),
]


@pytest.mark.parametrize("module, args, words", CASES,
                         ids=[f"{m} {' '.join(a)}" for m, a, _ in (getattr(c, "values", c) for c in CASES)])
def test_bad_options_exit_2_before_any_work(module, args, words, tmp_path):
    cache = tmp_path / "cache"  # empty: a model loaded before the refusal would be compiled into it
    proc = subprocess.run([sys.executable, "-m", module, *args], capture_output=True, text=True, cwd=REPO,
                          timeout=300, env={**os.environ, "ACROBOTER_CACHE_DIR": str(cache)})
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert words in proc.stderr, proc.stderr
    assert "Traceback" not in proc.stderr
    assert not cache.exists() or not any(cache.rglob("*"))  # refused before any model was loaded


def test_an_unexpected_error_is_one_line_and_exit_3(monkeypatch, capsys):
    """A bug no error class names still meets the boundary: a message, exit 3, no traceback."""
    from acroboter.cli.entry import guarded

    @guarded
    def broken(argv=None) -> int:
        raise ZeroDivisionError("a bug")

    monkeypatch.delenv("ACROBOTER_TRACEBACK", raising=False)
    assert broken() == 3
    err = capsys.readouterr().err
    assert "internal error (ZeroDivisionError: a bug)" in err and "Traceback" not in err


def test_the_boundary_maps_the_project_errors_to_their_codes(capsys):
    from acroboter.cli.entry import guarded
    from acroboter.control.controllers import SingularSystemError
    from acroboter.sim.statics import EquilibriumError

    for error, code in ((EquilibriumError("no static equilibrium found"), 2),
                        (SingularSystemError("MLM's system is singular"), 3), (KeyboardInterrupt(), 130)):
        @guarded
        def failing(argv=None, error=error) -> int:
            raise error

        assert failing() == code
        assert "Traceback" not in capsys.readouterr().err


def test_bench_refuses_a_scenario_too_short_to_time(tmp_path):
    """The path's numbers are read at run time: the default crane's spec with a fast path needs no
    regeneration, and bench says why it cannot time 0.3 s of it."""
    text = (REPO / "model_spec" / "acroboter.toml").read_text()
    assert "mean_speed = 0.04" in text
    spec = tmp_path / "acroboter.toml"
    spec.write_text(text.replace("mean_speed = 0.04", "mean_speed = 8.0"))
    proc = subprocess.run([sys.executable, "-m", "acroboter.bench", "--spec", str(spec), "--out", str(tmp_path)],
                          capture_output=True, text=True, cwd=REPO, timeout=120)
    assert proc.returncode == 2 and "needs at least 101" in proc.stderr and "Traceback" not in proc.stderr
