"""Compile progress is visible by default (issue 35 item 7): the library leaves the 'acroboter' logger's level unset,
so a first use's compile shows its bar on a terminal and one line elsewhere; `-q` (the logger above INFO) hides
both."""

from __future__ import annotations

import io
import logging
import subprocess
import sys

from acroboter.runtime import progress


def test_the_library_shows_progress_whatever_the_root_logger(monkeypatch):
    logger = logging.getLogger("acroboter")
    monkeypatch.setattr(logger, "level", logging.NOTSET)
    monkeypatch.setattr(logging.getLogger(), "level", logging.WARNING)  # a user's basicConfig at WARNING
    assert progress.progress_disabled() is None  # tqdm's choice: a bar on a terminal
    monkeypatch.setattr(logger, "level", logging.WARNING)  # `acroboter -q`, or the user hushing acroboter
    assert progress.progress_disabled() is True
    assert progress.progress_disabled(quiet=True) is True


def test_where_no_bar_can_show_one_line_says_what_takes_the_time(monkeypatch):
    logger = logging.getLogger("acroboter")
    monkeypatch.setattr(logger, "level", logging.NOTSET)
    err = io.StringIO()  # not a terminal
    monkeypatch.setattr(sys, "stderr", err)
    progress.announce("compiling acroboter (9 files, once)")
    assert err.getvalue() == "acroboter: compiling acroboter (9 files, once)\n"
    monkeypatch.setattr(logger, "level", logging.WARNING)
    progress.announce("hushed")
    assert "hushed" not in err.getvalue()


def test_a_first_compile_in_a_fresh_process_says_so(tmp_path):
    """A library call on an empty cache, stderr a pipe: the compile's line is there (the smallest example crane)."""
    code = "import acroboter; acroboter.Crane.from_example('lab_crane')"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=900,
                          env={**__import__("os").environ, "ACROBOTER_CACHE_DIR": str(tmp_path / "cache")})
    assert done.returncode == 0, done.stderr[-2000:]
    assert "acroboter: compiling lab_crane (" in done.stderr, done.stderr
