"""The console script `acroboter <command>`: version, verbosity, and help text on every option."""

from __future__ import annotations

import argparse
import subprocess
import sys

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
