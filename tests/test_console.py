"""The console script `acroboter <command>`: version, verbosity, and help text on every option."""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import pytest

import acroboter
from acroboter.cli.console import COMMANDS, main


def _acroboter(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "acroboter", *args], capture_output=True, text=True, cwd=cwd,
                          timeout=300)


def test_version():
    proc = _acroboter("--version")
    assert proc.returncode == 0 and proc.stdout.strip() == f"acroboter {acroboter.__version__}"


def test_an_unknown_command_is_bad_input():
    proc = _acroboter("simulate")
    assert proc.returncode == 2 and "invalid choice: 'simulate'" in proc.stderr


def test_quiet_and_verbose(tmp_path):
    args = ["run", "--method", "penalty", "--duration", "0.2", "--no-plots", "--out", str(tmp_path)]
    quiet = _acroboter("-q", *args)
    assert quiet.returncode == 0 and quiet.stderr == ""  # no progress bar, no notes
    verbose = _acroboter("-v", *args)
    assert verbose.returncode == 0 and "model 'acroboter': generated C in" in verbose.stderr


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_every_option_has_help_text(command, monkeypatch, capsys):
    """Each command's parser, built by its own main: no option without a help string."""
    missing = []
    original = argparse._ActionsContainer.add_argument

    def add_argument(self, *names, **kwargs):
        action = original(self, *names, **kwargs)
        if not isinstance(action, argparse._HelpAction | argparse._VersionAction) and not action.help:
            missing.append(action.dest)
        return action

    monkeypatch.setattr(argparse._ActionsContainer, "add_argument", add_argument)
    with pytest.raises(SystemExit) as info:
        main([command, "--help"])
    assert info.value.code == 0
    assert "usage:" in capsys.readouterr().out
    assert not missing, f"acroboter {command}: options without help: {missing}"


# --- examples by name, -v/-q after the command (issue 21 item 4) ----------------------------------------


def test_an_example_s_name_is_a_spec(tmp_path):
    from acroboter.cli.entry import spec_file
    from acroboter.process.locations import example_spec

    assert spec_file("lab_crane") == example_spec("lab_crane")
    assert spec_file("model_spec/lab_crane.toml") == Path("model_spec/lab_crane.toml")  # a path stays a path
    with pytest.raises(argparse.ArgumentTypeError, match="did you mean lab_crane"):
        spec_file("lab_crnae")


def test_examples_lists_every_example_and_run_takes_a_name(tmp_path):
    from acroboter.process.locations import example_names

    listing = subprocess.run([sys.executable, "-m", "acroboter", "examples"], capture_output=True, text=True,
                             timeout=120)
    assert listing.returncode == 0, listing.stderr
    assert [line.split()[0] for line in listing.stdout.splitlines()] == example_names()
    assert main(["run", "--spec", "lab_crane", "--duration", "0.04", "--no-plots", "-v",
                 "--out", str(tmp_path / "out")]) == 0
    assert json.loads((tmp_path / "out" / "summary.json").read_text())["spec"] == "lab_crane"


def test_verbosity_after_the_command_acts_as_before_it():
    from acroboter.cli.console import _noise_after_command

    assert _noise_after_command("bench", ["-v", "--spec", "x"], 0) == (["--spec", "x"], 1)
    assert _noise_after_command("bench", ["-q"], 0) == ([], -1)  # bench has no -q of its own
    assert _noise_after_command("run", ["-q", "--", "-v"], 0) == (["-q", "--", "-v"], -1)  # run has
