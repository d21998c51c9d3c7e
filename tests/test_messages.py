"""Issue 36: messages name the real cause. An --out that cannot hold a folder says why (the root, a kernel file
system, a dangling link) instead of "No such file or directory" or "File exists"; nothing is created there."""

from __future__ import annotations

import pytest


@pytest.mark.parametrize(("out", "why"), [("/", "it is the file system's root"),
                                          ("/proc/acroboter-x", "/proc is the kernel's"),
                                          ("/sys/x/y", "/sys is the kernel's")])
def test_a_system_path_is_refused_naming_why(out, why, capsys):
    from acroboter.cli.run import main

    assert main(["--duration", "0.1", "--method", "mlm", "--out", out, "-q"]) == 2
    err = capsys.readouterr().err
    assert f"--out {out}: {why}" in err and "No such file" not in err, err


def test_a_dangling_link_is_refused_naming_its_target(tmp_path, capsys):
    from acroboter.cli.run import main

    link = tmp_path / "results"
    link.symlink_to(tmp_path / "gone")
    assert main(["--duration", "0.1", "--method", "mlm", "--out", str(link), "-q"]) == 2
    err = capsys.readouterr().err
    assert f"a symbolic link to {tmp_path / 'gone'}, which does not exist" in err and "File exists" not in err, err
    assert not (tmp_path / "gone").exists()


def test_a_bad_sensing_option_is_named_as_the_option_not_as_the_spec_file(tmp_path, capsys):
    """Issue 36: `--sensing-noise=bogus=0.1` was reported as an invalid model spec file."""
    from acroboter.cli.run import main

    assert main(["--sensing-noise=bogus=0.1", "--duration", "0.1", "--out", str(tmp_path / "out"), "-q"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: --sensing-noise bogus: expected one of the groups"), err
    assert "invalid model spec" not in err and not (tmp_path / "out").exists()


def test_a_spec_path_that_is_no_file_says_what_it_is(tmp_path):
    """Issue 36 (input files): /dev/zero was "nothing at this path"; an oversized file is refused unread."""
    from acroboter.model.spec import MAX_SPEC_BYTES, SpecError, load_spec

    with pytest.raises(SpecError, match="found a device or a pipe, not a file at this path"):
        load_spec("/dev/zero")
    big = tmp_path / "big.toml"
    with big.open("wb") as f:  # sparse: no disk, no time
        f.truncate(MAX_SPEC_BYTES + 1)
    with pytest.raises(SpecError, match="expected a TOML spec of at most 1 MB, found 1 MB"):
        load_spec(big)
    with pytest.raises(SpecError, match="found nothing at this path"):
        load_spec(tmp_path / "missing.toml")


@pytest.mark.parametrize("target", ["notes.txt", "lab_crane.toml", "/dev/null", "crane"])
def test_an_mjcf_target_that_is_no_xml_file_is_refused_at_parse_time(target, tmp_path, monkeypatch, capsys):
    """Issue 36 (MJCF paths): `mjcf -o lab_crane.toml` replaced the spec itself with XML, and `-o newdir/` wrote a
    file called newdir. -o takes *.xml, a folder (existing, or a name ending in /) or -; the rest is refused
    before the spec is read, and nothing is written."""
    from acroboter.cli.mjcf import main

    monkeypatch.chdir(tmp_path)
    (tmp_path / "lab_crane.toml").write_text("mine")
    with pytest.raises(SystemExit) as stop:
        main(["lab_crane", "-o", target, "--pose", "spec"])
    assert stop.value.code == 2
    assert "an MJCF file is named *.xml" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["lab_crane.toml"]
    assert (tmp_path / "lab_crane.toml").read_text() == "mine"


@pytest.mark.needs_mujoco
def test_an_mjcf_folder_is_named_by_a_trailing_slash_and_a_kernel_path_is_refused(tmp_path, monkeypatch, capsys):
    from acroboter.cli.mjcf import main

    monkeypatch.chdir(tmp_path)
    assert main(["lab_crane", "-o", "models/", "--pose", "spec", "-q"]) == 0
    assert (tmp_path / "models" / "lab_crane.xml").read_text().lstrip().startswith(("<mujoco", "<!--"))
    assert main(["lab_crane", "-o", "/dev/acroboter-test.xml", "--pose", "spec", "-q"]) == 2
    assert "/dev is the kernel's file system" in capsys.readouterr().err
    from pathlib import Path

    assert not Path("/dev/acroboter-test.xml").exists()
