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
