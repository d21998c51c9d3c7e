"""Issue 36: what an adversarial pass with bad inputs found (2026-12-06, about 190 inputs across every command),
kept as regression cases. Each was an internal error, a wrong exit code, a memory blow-up or a lost file."""

from __future__ import annotations

import json
import os
import re
from pathlib import Path

import pytest
from conftest import REPO

from acroboter.cli.outputs import MANIFEST, STAGING_PREFIX, unfit_folder

HEADER = "t_s,x_m,y_m,z_m,vx_m_s,vy_m_s,vz_m_s,ax_m_s2,ay_m_s2,az_m_s2\n"


@pytest.mark.parametrize(("rows", "why"), [
    ("0,0,0,0.35,0,0,0,0,0,0\n1000000,0,0,0.35,0,0,0,0,0,0\n", "more than the 360,000 a run may have"),
    ("0,0,0,0.35,0,0,0,0,0,0\n100,0,0,0.35,0,0,0,0,0,0\n", "never moves: nothing to retime"),
])
def test_plan_refuses_a_trajectory_it_cannot_retime_before_any_work(rows, why, tmp_path, capsys):
    """A 163-byte file ending at t = 1e6 s passed every check and took `plan` to 10 GB (sampled at 100 Hz, no
    cap), deaf to SIGTERM for ten minutes; one that never moves ended in "the limits do not bound this motion"."""
    from acroboter.cli.plan import main

    (tmp_path / "t.csv").write_text(HEADER + rows)
    assert main(["--trajectory", str(tmp_path / "t.csv"), "--no-plots", "--no-certificate", "-q",
                 "--out", str(tmp_path / "out")]) == 2
    assert why in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_trajectory_files_a_spreadsheet_writes_and_rows_the_csv_module_refuses(tmp_path):
    from acroboter.control.path import TrajectoryError
    from acroboter.control.trajectory_file import read_trajectory_csv

    bom = tmp_path / "bom.csv"  # Excel's "CSV UTF-8": "line 1: no column t_s" although it is there
    bom.write_text(HEADER + "0,0,0,0,0,0,0,0,0,0\n1,0,0,0,0,0,0,0,0,0\n", encoding="utf-8-sig")
    assert read_trajectory_csv(bom).times.tolist() == [0.0, 1.0]
    wide = tmp_path / "wide.csv"  # a field over the csv module's limit was an internal error
    wide.write_text(HEADER + "0," + "1" * 200_000 + ",0,0,0,0,0,0,0,0\n")
    with pytest.raises(TrajectoryError, match=r"wide\.csv, line 2: not a CSV row"):
        read_trajectory_csv(wide)
    twice = tmp_path / "twice.csv"  # a column named twice: the first was used, silently
    twice.write_text("t_s," + HEADER + "0,0,0,0,0,0,0,0,0,0,0\n")
    with pytest.raises(TrajectoryError, match="line 1: column t_s named twice"):
        read_trajectory_csv(twice)


def test_a_spec_nested_too_deep_or_with_a_byte_order_mark(tmp_path):
    from acroboter.model.spec import SpecError, load_spec

    text = (REPO / "model_spec" / "lab_crane.toml").read_text()
    deep = tmp_path / "deep.toml"  # 500 levels: RecursionError inside tomllib, "internal error", exit 3
    deep.write_text(text + "\n[extra]\nx = " + "[" * 500 + "]" * 500 + "\n")
    with pytest.raises(SpecError, match="nested too deep"):
        load_spec(deep)
    bom = tmp_path / "bom.toml"  # "Invalid statement (at line 1, column 1)"
    bom.write_text(text, encoding="utf-8-sig")
    assert load_spec(bom).name == "lab_crane"


def test_a_damaged_manifest_or_a_linked_subfolder_never_costs_a_file(tmp_path, capsys):
    """A manifest nested thousands deep was an internal error that left a staging folder; a manifest path through a
    folder that is a link (`sub -> ../victim`) removed a file outside --out."""
    from acroboter.cli.run import main

    out = tmp_path / "out"
    out.mkdir()
    (out / MANIFEST).write_text("[" * 100_000 + "]" * 100_000)
    assert main(["--duration", "0.1", "--method", "mlm", "--no-plots", "-q", "--out", str(out)]) == 0
    assert not [p for p in out.iterdir() if p.name.startswith(STAGING_PREFIX)]
    victim = tmp_path / "victim"
    victim.mkdir()
    (victim / "mlm.csv").write_text("mine")
    linked = tmp_path / "linked"
    linked.mkdir()
    (linked / "sub").symlink_to(victim)
    (linked / MANIFEST).write_text(json.dumps({"format": 1, "commands": {"run": {"files": ["sub/mlm.csv"],
                                                                                 "folders": ["sub"]}}}))
    assert main(["--duration", "0.1", "--method", "mlm", "--no-plots", "-q", "--out", str(linked)]) == 0
    assert (victim / "mlm.csv").read_text() == "mine"


def test_dev_shm_is_a_folder_for_results_and_proc_is_not():
    assert unfit_folder(Path("/dev/shm/acroboter-results")) is None
    assert "kernel's file system" in unfit_folder(Path("/dev/acroboter-results"))


@pytest.fixture(scope="module")
def run_folder(tmp_path_factory):
    from acroboter.cli.run import main

    out = tmp_path_factory.mktemp("run") / "out"
    assert main(["--duration", "0.1", "--method", "mlm", "--no-plots", "-q", "--out", str(out)]) == 0
    return out


def copy_of(folder: Path, tmp_path: Path) -> Path:
    import shutil

    return Path(shutil.copytree(folder, tmp_path / "copy"))


def test_animate_refuses_a_records_file_no_run_writes(run_folder, tmp_path):
    """A 3 GB sparse mlm.csv took 15.8 GB to load; a summary that is a list was an internal error; a NaN pose was
    drawn as if recorded."""
    from acroboter.report.animation.scene import MAX_CSV_BYTES, AnimationInputError, load

    folder = copy_of(run_folder, tmp_path)
    csv = folder / "mlm.csv"
    good = csv.read_text()
    os.truncate(csv, MAX_CSV_BYTES + 1)
    with pytest.raises(AnimationInputError, match="not a run's record"):
        load(folder, "mlm")
    lines = good.splitlines()
    lines[3] = re.sub(r"[^,]+", "nan", lines[3])
    csv.write_text("\n".join(lines) + "\n")
    with pytest.raises(AnimationInputError, match=r"mlm\.csv, line 4: .* is nan"):
        load(folder, "mlm")
    (folder / "summary.json").write_text("[1, 2, 3]")
    with pytest.raises(AnimationInputError, match="not a run's summary"):
        load(folder, "mlm")


@pytest.mark.needs_mujoco
def test_mjcf_never_writes_over_its_spec_through_a_link_or_by_name(tmp_path, monkeypatch, capsys):
    from acroboter.cli.mjcf import main

    monkeypatch.chdir(tmp_path)
    spec = tmp_path / "crane.toml"
    spec.write_text((REPO / "model_spec" / "lab_crane.toml").read_text())
    before = spec.read_bytes()
    (tmp_path / "link.xml").symlink_to(spec)
    assert main([str(spec), "--pose", "spec", "-o", "link.xml", "-q"]) == 2
    assert "it is the spec being read" in capsys.readouterr().err
    named = tmp_path / "s.xml"
    named.write_bytes(before)
    assert main([str(named), "--pose", "spec", "-o", str(named), "-q"]) == 2
    assert named.read_bytes() == before and spec.read_bytes() == before
    (tmp_path / "other.xml").symlink_to(tmp_path / "elsewhere.toml")  # a link to another file: replaced, not followed
    (tmp_path / "elsewhere.toml").write_text("mine")
    assert main(["lab_crane", "--pose", "spec", "-o", "other.xml", "-q"]) == 0
    assert not (tmp_path / "other.xml").is_symlink() and (tmp_path / "elsewhere.toml").read_text() == "mine"


@pytest.mark.parametrize(("given", "why"), [("missing", "nothing at this path"), ("a file", "a file at this path"),
                                            ("/usr", "no generated code in it"), ("/proc", "kernel's file system")])
def test_check_out_must_be_a_folder_of_generated_code(given, why, tmp_path, capsys):
    """`check --out missing` and `--out afile` said "generated/ is stale" (exit 1) with 150 "missing" lines;
    `--out /usr` walked the whole tree (122,345 lines)."""
    from acroboter.cli.generate import main

    target = {"missing": str(tmp_path / "missing"), "a file": str(REPO / "README.md")}.get(given, given)
    with pytest.raises(SystemExit) as stop:
        main(["check", "--out", target])
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert f"--out {target}: " in err and why in err


def test_generate_takes_a_spec_after_its_options_and_an_examples_name(tmp_path, capsys):
    """`generate --out DIR --no-compile-check SPEC` was "unrecognized arguments: SPEC"; `generate lab_crane` was
    "found nothing at this path"."""
    from acroboter.cli.generate import main

    assert main(["generate", "--out", str(tmp_path / "gen"), "--no-compile-check", "lab_crane"]) == 0
    assert (tmp_path / "gen" / "lab_crane" / "manifest.json").is_file()


@pytest.mark.parametrize("argv", [["run", "--method", "mlm,,", "--duration", "0.1"], ["sweep", "--alphas", "1,,2"],
                                  ["run", "--iterations", "3,", "--duration", "0.1"]])
def test_an_empty_item_in_a_list_option_is_refused(argv, tmp_path, capsys):
    """`--alphas 1,,2` and `--method mlm,,` were taken silently (a value left out, or a typo)."""
    from acroboter.cli.console import main

    try:
        code = main([*argv, "--out", str(tmp_path / "out")])
    except SystemExit as stop:
        code = stop.code
    assert code == 2 and "empty item" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_a_full_disk_says_where_and_what_to_do(tmp_path, capsys, monkeypatch):
    """"error: [Errno 28] No space left on device" named neither the file nor the fix."""
    import errno

    from acroboter.cli import outputs
    from acroboter.cli.run import main

    def full(self):
        raise OSError(errno.ENOSPC, "No space left on device", str(self.out / "summary.json"))

    monkeypatch.setattr(outputs.ResultsFolder, "publish", full)
    assert main(["--duration", "0.1", "--method", "mlm", "--no-plots", "-q", "--out", str(tmp_path / "out")]) == 3
    err = capsys.readouterr().err
    assert f"No space left on device writing {tmp_path / 'out' / 'summary.json'}: free some space" in err


@pytest.mark.needs_mujoco
def test_a_mujoco_step_that_does_not_divide_is_named_by_its_option(tmp_path, capsys):
    from acroboter.cli.run import main

    assert main(["--plant", "mujoco", "--mujoco-timestep", "0.0003", "--duration", "0.1", "--method", "mlm", "-q",
                 "--no-plots", "--out", str(tmp_path / "out")]) == 2
    assert "--mujoco-timestep: 0.0003 s must divide" in capsys.readouterr().err


def test_bench_limits_spec_takes_an_examples_name(capsys):
    """`bench --limits-spec lab_crane` read a file called lab_crane; it takes examples' names as --spec does."""
    from acroboter.cli.bench import main

    with pytest.raises(SystemExit) as stop:
        main(["--limits-spec", "lab_cran"])
    assert stop.value.code == 2 and "did you mean lab_crane?" in capsys.readouterr().err
