"""The Monte Carlo robustness study (acroboter.robustness): a tiny study (3 samples, 1 s of the path)
in this process and on a real dask.distributed LocalCluster on 127.0.0.1, the same rows either way;
reproducibility from the seed (the whole CSV, and any one sample drawn alone); a sample re-run from
its recorded `acroboter run` line gives the same figures; bad input exits 2."""

from __future__ import annotations

import csv
import json
import math
import os
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from acroboter.cli import robustness as rb
from acroboter.studies import robustness_grid as rg

REPO = Path(__file__).resolve().parent.parent
SPEC = REPO / "model_spec" / "acroboter.toml"
SAMPLES, DURATION, SEED = 3, 1.0, 7
N_ROWS = SAMPLES * len(rg.DEFAULT_METHODS) * 2
needs_dask = pytest.mark.needs_dask  # skipped without the extra (tests/conftest.py)


def run_cli(*args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "acroboter", "robustness", *args], capture_output=True, text=True,
                          cwd=REPO, timeout=timeout)


def read_csv(path: Path, timing: bool = True) -> list[dict]:
    with path.open(newline="") as f:
        rows = list(csv.DictReader(f))
    if not timing:
        for row in rows:
            for key in rg.TIMING_COLUMNS:
                row.pop(key)
    return rows


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    out = tmp_path_factory.mktemp("robustness")
    result = rb.robustness(SPEC, samples=SAMPLES, seed=SEED, duration=DURATION, workers=0, out=out)
    return result, out


def test_in_process_study(study):
    result, out = study
    assert result.workers == 0 and result.ki == 18.375  # docs/integral_action.md's choice for kp = kd = 5
    rows = result.rows
    assert len(rows) == N_ROWS
    assert [(r["sample"], r["method"], r["ki"]) for r in rows] == [
        (i, m, ki) for i in range(SAMPLES) for m in rg.DEFAULT_METHODS for ki in (0.0, 18.375)]
    assert all(r["status"] == "ok" and not r["diverged"] for r in rows), [r["status"] for r in rows]
    for r in rows:
        assert r["max_position_error_mm"] >= r["rms_position_error_mm"] > 0
        assert r["max_yaw_error_deg"] >= 0 and r["time_saturated_s"] == 0.0
        assert r["worker"] == "local"
        assert r["max_position_error_settled_mm"] is None  # 1 s: never past SETTLE_S
    # The controllers keep the model: the plant's parameters move the error. The defaults: masses ±10 %,
    # inertias ±20 %, points ±5 mm, the main cable ±2 mm.
    nominal = {k: v for k, v in __import__("acroboter").Crane.from_toml(SPEC).plant_parameters().items()}
    for s in result.samples:
        assert abs(s.params["SU.mass"] / nominal["SU.mass"] - 1) <= 0.1
        assert abs(s.params["CC.inertia.zz"] / nominal["CC.inertia.zz"] - 1) <= 0.2
        assert abs(s.params["SU.points.b1.z"] - nominal["SU.points.b1.z"]) <= 0.005
        assert abs(s.params["main.length"] - nominal["main.length"]) <= 0.002
        assert "gravity.z" not in s.params and "SU.damping.translational" not in s.params
        assert s.tracked_mass_error == pytest.approx(s.params["SU.mass"] / 8.0 - 1)
    names = {p.name for p in result.files}
    assert names == {"robustness.csv", "samples.csv", "summary.json", "robustness_cdf.png",
                     "robustness_success.png", "robustness_worst.png"}
    summary = json.loads((out / "summary.json").read_text())
    prov = summary["provenance"]
    assert prov["seed"] == SEED and prov["samples"] == SAMPLES and prov["duration_s"] == DURATION
    assert prov["ranges"]["mass"] == {"low": -0.1, "high": 0.1, "unit": "fraction",
                                      "what": rg.GROUPS["mass"][0]}
    assert prov["versions"]["numpy"] and prov["ki"] == [0.0, 18.375]
    assert len(summary["per_method"]) == 10 and summary["worst_sample"]["command"].startswith("acroboter run")
    assert len(read_csv(out / "robustness.csv")) == N_ROWS


@needs_dask
def test_on_a_local_dask_cluster_gives_the_same_rows(study, tmp_path):
    _, out = study
    p = run_cli("--spec", str(SPEC), "--samples", str(SAMPLES), "--seed", str(SEED), "--duration", str(DURATION),
                "--workers", "2", "--no-plots", "-q", "--out", str(tmp_path))
    assert p.returncode == 0, p.stderr
    assert "success" in p.stdout and "integral action" in p.stdout
    rows = read_csv(tmp_path / "robustness.csv")
    assert all(r["worker"].startswith("tcp://127.0.0.1") for r in rows)
    assert read_csv(tmp_path / "robustness.csv", timing=False) == read_csv(out / "robustness.csv", timing=False)
    assert (tmp_path / "samples.csv").read_text() == (out / "samples.csv").read_text()
    assert not (tmp_path / "robustness_cdf.png").exists()  # --no-plots


def test_same_seed_same_csv_and_any_sample_alone(study, tmp_path):
    _, out = study
    again = rb.robustness(SPEC, samples=SAMPLES, seed=SEED, duration=DURATION, workers=0, out=tmp_path,
                          plots=False)
    assert read_csv(tmp_path / "robustness.csv", timing=False) == read_csv(out / "robustness.csv", timing=False)
    spec = __import__("acroboter").load_spec(SPEC)
    alone = rg.draw_sample(spec, SEED, 2, rg.default_ranges())
    assert alone == again.samples[2]  # sample i needs only (seed, i)
    other = rg.draw_sample(spec, SEED + 1, 2, rg.default_ranges())
    assert other.params != alone.params
    # A zero range leaves its group at the spec's values and the others' draws where they were.
    narrow = rg.draw_sample(spec, SEED, 2, {**rg.default_ranges(), "point": (0.0, 0.0)})
    assert not any(".points." in n for n in narrow.params)
    assert {n: v for n, v in alone.params.items() if ".points." not in n} == narrow.params


def test_a_sample_rerun_from_its_recorded_command(study, tmp_path):
    result, out = study
    with (out / "samples.csv").open(newline="") as f:
        recorded = list(csv.DictReader(f))
    assert [int(r["sample"]) for r in recorded] == list(range(SAMPLES))
    line = recorded[1]["command_ki"]
    assert "--ki 18.375" in line and "--plant-param SU.mass=" in line
    args = shlex.split(line)
    assert args[:2] == ["acroboter", "run"]
    p = subprocess.run([sys.executable, "-m", "acroboter", *args[1:], "--method", "penalty", "--out", str(tmp_path),
                        "--no-plots", "-q"], capture_output=True, text=True, cwd=REPO, timeout=300)
    assert p.returncode == 0, p.stderr
    rerun = json.loads((tmp_path / "summary.json").read_text())["methods"]["penalty"]
    row = next(r for r in result.rows if r["sample"] == 1 and r["method"] == "penalty" and r["ki"] > 0)
    assert rerun["max_position_error_mm"] == row["max_position_error_mm"]  # bit for bit
    assert rerun["max_yaw_error_deg"] == row["max_yaw_error_deg"]


@pytest.mark.parametrize("args, message", [
    (["--samples", "0"], "--samples"),
    (["--mass-range", "-0.1"], "half-width must be ≥ 0"),
    (["--point-range=5:-5"], "LO ≤ HI"),
    (["--inertia-range=-1:0.2"], "expected -0.9 <= inertia_range <= 9 (fraction), found -1"),
    (["--length-range", "abc"], "expected H (±H) or LO:HI with -1000 <= length_range <= 1000 (mm)"),
    (["--length-range", "1e9"], "expected -1000 <= length_range <= 1000 (mm), found 1e+09"),
    (["--ki", "300"], "2·kd·kp²"),
    (["--ki", "0"], "--ki"),
    (["--methods", "mlm,bogus"], "unknown method"),
    (["--sensing-noise", "positions=-1"], "--sensing-noise"),
])
def test_bad_input_exits_2(args, message, tmp_path):
    p = run_cli(*args, "--samples" if "--samples" not in args else "--seed", "1", "--duration", "0.1",
                "--workers", "0", "--no-plots", "--out", str(tmp_path))
    assert p.returncode == 2, (p.returncode, p.stderr)
    assert message in p.stderr and "Traceback" not in p.stderr


def test_ranges_and_recommended_ki():
    assert rg.parse_range("0.1", "mass") == (-0.1, 0.1)
    assert rg.parse_range("-0.05:0.1", "mass") == (-0.05, 0.1)
    assert rg.parse_range("0", "point") == (0.0, 0.0)
    assert rg.recommended_ki(5.0, 5.0) == pytest.approx(18.375)
    # Stable (Routh–Hurwitz: ki < 2 kd kp²) for other gains too.
    for kp, kd in ((5.0, 8.0), (8.0, 5.0), (2.0, 2.0)):
        ki = rg.recommended_ki(kp, kd)
        assert 0 < ki < 2 * kd * kp * kp
    with pytest.raises(ValueError, match="samples"):
        rb.robustness(SPEC, samples=0, workers=0)
    assert math.isfinite(rg.POSITION_BOUND_MM)


def test_measurement_noise_and_delay_reach_every_run(tmp_path):
    p = run_cli("--spec", str(SPEC), "--samples", "1", "--duration", "0.5", "--methods", "mlm", "--workers", "0",
                "--sensing-noise", "positions=0.0002", "--sensing-delay", "1", "--sensing-seed", "3", "--no-plots",
                "-q", "--out", str(tmp_path))
    assert p.returncode == 0, p.stderr
    rows = read_csv(tmp_path / "robustness.csv")
    assert [r["status"] for r in rows] == ["ok", "ok"]
    with (tmp_path / "samples.csv").open(newline="") as f:
        line = next(csv.DictReader(f))["command"]
    assert "--sensing-noise positions=0.0002 --sensing-delay 1 --sensing-seed 3" in line
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["provenance"]["sensing"] == {"noise": {"positions": 0.0002}, "delay_periods": 1, "seed": 3}
    # Perfect measurements give other figures: the options reached the runs.
    clean = rb.robustness(SPEC, samples=1, seed=rb.DEFAULT_SEED, duration=0.5, methods=("mlm",), workers=0)
    assert clean.rows[0]["max_position_error_mm"] != float(rows[0]["max_position_error_mm"])


@needs_dask
def test_the_fast_path_study_on_workers_gives_the_reference_figures(study, tmp_path):
    """--fast: the controllers' fast path in every run, built in the cache before the workers start (they only load
    it). Its figures are the reference study's within the fast path's agreement (docs/fast-path.md: 1e-9 relative
    in u; the summaries' maxima within 1e-7), and its re-run lines carry --fast."""
    result, out = study
    p = run_cli("--spec", str(SPEC), "--samples", str(SAMPLES), "--seed", str(SEED), "--duration", str(DURATION),
                "--workers", "2", "--fast", "--no-plots", "-q", "--out", str(tmp_path))
    assert p.returncode == 0, p.stderr
    fast, reference = read_csv(tmp_path / "robustness.csv"), read_csv(out / "robustness.csv")
    assert [(r["sample"], r["method"], r["ki"], r["status"]) for r in fast] == \
        [(r["sample"], r["method"], r["ki"], r["status"]) for r in reference]
    for f, r in zip(fast, reference, strict=True):
        for key in ("max_position_error_mm", "rms_position_error_mm", "max_yaw_error_deg"):
            assert float(f[key]) == pytest.approx(float(r[key]), rel=1e-7, abs=1e-12), (f["method"], key)
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["provenance"]["fast_path"] is True
    with (tmp_path / "samples.csv").open(newline="") as f:
        assert " --fast " in next(csv.DictReader(f))["command"]


SPY = r"""
import os, sys
from pathlib import Path
from acroboter.cli import robustness as rb
from acroboter.studies import robustness_grid as grid

built = []
run_sample = grid.run_sample
def spy(*args, **kwargs):  # what a task adds to the cache's libraries: nothing, the study built it before
    lib = Path(os.environ["ACROBOTER_CACHE_DIR"]) / "lib"
    before = {p.name for p in lib.iterdir()}
    rows = run_sample(*args, **kwargs)
    built.extend(sorted({p.name for p in lib.iterdir()} - before))
    return rows
rb.run_sample = spy
result = rb.robustness(Path(sys.argv[1]), samples=1, duration=0.3, methods=("penalty",), workers=0,
                       fast=sys.argv[2] == "fast", plots=False)
print("statuses", [r["status"] for r in result.rows])
print("built in tasks", built)
"""


@pytest.mark.parametrize("fast", ["fast", "reference"])
def test_the_tasks_compile_nothing(tmp_path, fast):
    """A study builds, before any task, what its runs load from the cache: the plant's substep loop, and with
    --fast the fast steps and the compiled estimator of the spec's own [sensing] section (here without --sensing-*
    options). The workers only load them, as they load the model's library (a remote worker may have no compiler)."""
    import shutil

    cache = tmp_path / "cache"
    (cache / "lib").mkdir(parents=True)
    for folder in (REPO / "build" / "cache" / "lib").glob("acroboter-*"):  # the model's library, already built
        shutil.copytree(folder, cache / "lib" / folder.name)
    spec = tmp_path / "acroboter.toml"
    sensing = (REPO / "docs" / "sensing.md").read_text().split("```toml\n", 1)[1].split("```", 1)[0]
    assert sensing.startswith("[sensing]")
    spec.write_text(SPEC.read_text() + "\n" + sensing)
    p = subprocess.run([sys.executable, "-c", SPY, str(spec), fast], capture_output=True, text=True, cwd=REPO,
                       timeout=600, env={**os.environ, "ACROBOTER_CACHE_DIR": str(cache)})
    assert p.returncode == 0, p.stderr
    assert "statuses ['ok', 'ok']" in p.stdout
    assert "built in tasks []" in p.stdout, p.stdout
