"""End to end: `python -m acroboter.run` writes what docs/run.md promises; bad input exits cleanly."""

from __future__ import annotations

import csv
import json
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
METHOD_FIELDS = {
    "max_position_error_mm", "rms_position_error_mm", "max_yaw_error_deg", "max_tilt_deg",
    "max_constraint_violation", "min_winch_tension_N", "max_abs_input", "control_step_us", "sim_wall_s",
}


def run_cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "acroboter.run", *args], capture_output=True, text=True,
                          cwd=REPO, timeout=600)


@pytest.fixture(scope="module")
def short_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("results")
    proc = run_cli("--duration", "1.0", "--out", str(out), "--method", "mlm,penalty", "--method", "iterative",
                   "--iterations", "3", "--quiet")
    return proc, out


def test_short_run_writes_every_file(short_run):
    proc, out = short_run
    assert proc.returncode == 0, proc.stderr
    names = {p.name for p in out.iterdir()}
    assert {"summary.json", "mlm.csv", "penalty.csv", "iterative-3.csv"} <= names
    assert {"path_3d.png", "servo_errors.png", "inputs.png", "control_step_time.png"} <= names
    for png in out.glob("*.png"):
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "mlm" in proc.stdout and "MATLAB" in proc.stdout


def test_summary_json_fields(short_run):
    _, out = short_run
    doc = json.loads((out / "summary.json").read_text())
    assert doc["spec"] == "acroboter"
    prov = doc["provenance"]  # enough to repeat the run
    spec_bytes = (REPO / "model_spec" / "acroboter.toml").read_bytes()
    import hashlib

    assert prov["spec_sha256"] == hashlib.sha256(spec_bytes).hexdigest()
    assert prov["gains"]["alpha_servo"] == 1e7 and prov["gains"]["recovery"] == "projected"
    assert prov["methods"] == ["mlm", "penalty", "iterative-3"] and prov["duration_s"] == 1.0
    assert prov["casadi_version"] == "3.8.2" and prov["command_line"][:3] == ["python", "-m", "acroboter.run"]
    assert "--iterations" in prov["command_line"] and prov["date"].startswith("20")
    assert set(doc["methods"]) == {"mlm", "penalty", "iterative-3"}
    for method, fields in doc["methods"].items():
        assert METHOD_FIELDS <= set(fields), method
        assert set(fields["control_step_us"]) == {"median", "mean", "p99"}
        assert fields["max_position_error_mm"] < 0.05  # measured 0.0282..0.0284 mm (2026-12-02); 1.8x (was 5.3)
        assert fields["min_winch_tension_N"] > 0
        assert len(fields["max_abs_input"]) == 6


def test_csv_columns_and_rows(short_run):
    _, out = short_run
    with (out / "mlm.csv").open() as f:
        rows = list(csv.reader(f))
    header = rows[0]
    expected = ["t_s", "x_m", "y_m", "z_m", "yaw_deg", "x_d_m", "y_d_m", "z_d_m", "yaw_d_deg", "position_error_mm",
                "yaw_error_deg", "tilt_deg"]
    expected += [f"servo_SU_position_{axis}_mm" for axis in "xyz"]
    expected += ["servo_SU_yaw_via_u", "servo_SU_level_w_x", "servo_SU_level_w_y"]
    expected += ["tension_1_N", "tension_2_N", "tension_3_N", "yaw_torque_Nm", "thrust_u_N", "thrust_v_N"]
    cables = ("main", "L1", "L2", "L3")
    for c in cables:
        expected += [f"cable_{c}_tension_N", f"cable_{c}_slack", f"cable_{c}_gap_m"]
    expected += ["energy_residual_J", "saturated"]
    expected += [f"anchor_climbing_unit_{axis}_m" for axis in "xyz"]
    expected += [f"q_{body}.{vec}_{axis}{'_m' if vec == 'r' else ''}" for body in ("CC", "SU") for vec in "ruvw"
                 for axis in "xyz"]
    expected += [f"q_{c}.length_m" for c in ("L1", "L2", "L3")]
    assert header == expected
    assert len(rows) == 1 + 51  # 1 s at 50 Hz, both ends
    first = dict(zip(header, map(float, rows[1]), strict=True))
    assert first["t_s"] == 0.0
    assert first["z_m"] == pytest.approx(0.35, abs=1e-9)  # p0 of the design
    assert first["tension_1_N"] == pytest.approx(26.75, abs=0.01)
    assert first["cable_L1_tension_N"] == pytest.approx(26.75, abs=0.01)  # the plant's cable pulls with tension_1
    assert all(first[f"cable_{c}_slack"] == 0 for c in cables) and first["saturated"] == 0
    assert (first["anchor_climbing_unit_x_m"], first["anchor_climbing_unit_z_m"]) == (0.0, 3.0)  # the spec's start
    assert first["q_SU.r_z_m"] == first["z_m"]  # the tracked point is the SU's centre


def test_help_lists_the_options():
    proc = run_cli("--help")
    assert proc.returncode == 0
    for option in ("--spec", "--method", "--iterations", "--recovery", "--duration", "--out", "--no-plots"):
        assert option in proc.stdout


@pytest.mark.parametrize("args, words", [
    (["--method", "newton", "--duration", "0.1"], "unknown method"),
    (["--duration", "-1"], "argument --duration: expected 0 < duration <= 1e6 (s), found -1"),
    (["--recovery", "magic"], "invalid choice"),
    (["--iterations", "two"], "expected a whole number 1 <= iterations <= 1000, found 'two'"),
    (["--spec", "no/such/spec.toml"], "no/such/spec.toml"),
    (["--kp", "nan"], "argument --kp: expected 0 < kp <= 1e4 (1/s), found nan"),
    (["--alpha-servo", "inf"], "argument --alpha-servo: expected 1 <= alpha_servo <= 1e16, found inf"),
    (["--kappa", "2"], "argument --kappa: expected 0 <= kappa <= 1, found 2"),
    (["--duration", "0.001"], "--duration 0.001 s is 0 control steps"),
    (["--out", "README.md"], "is a file, not a folder"),
])
def test_bad_input_is_a_clear_error(args, words, tmp_path):
    proc = run_cli("--out", str(tmp_path), *args, "--quiet")
    assert proc.returncode == 2
    assert words in proc.stderr
    assert "Traceback" not in proc.stderr


def test_bad_spec_is_a_clear_error(tmp_path):
    spec = (REPO / "model_spec" / "acroboter.toml").read_text().replace("mass = 8.0", "mass = -8.0")
    bad = tmp_path / "bad.toml"
    bad.write_text(spec)
    proc = run_cli("--spec", str(bad), "--out", str(tmp_path / "out"), "--duration", "0.1")
    assert proc.returncode == 2
    assert "bodies[1].mass" in proc.stderr and "found -8" in proc.stderr
    assert "Traceback" not in proc.stderr


@pytest.mark.parametrize("module, args, words", [
    ("acroboter.bench", ["--methods", "foo"], "unknown method 'foo'"),
    ("acroboter.bench", ["--repeats", "0"], "expected a whole number 1 <= repeats <= 100, found 0"),
    ("acroboter.study", ["--duration", "-1"], "expected 0 < duration <= 7200 (s), found -1"),
    ("acroboter.sweep", ["--alphas", "abc"], "alphas"),
])
def test_other_clis_reject_bad_options_cleanly(module, args, words, tmp_path):
    proc = subprocess.run([sys.executable, "-m", module, *args, "--out", str(tmp_path)], capture_output=True,
                          text=True, cwd=REPO, timeout=120)
    assert proc.returncode == 2
    assert words in proc.stderr and "Traceback" not in proc.stderr
