"""Whether a progress bar shows: one rule for the commands and the animation's encoders."""

from __future__ import annotations


def progress_disabled(quiet: bool = False) -> bool | None:
    """tqdm's `disable`: off with --quiet or `acroboter -q` (the 'acroboter' logger set above INFO, as the
    commands do), else tqdm's own choice (None: off when stderr is not a terminal). The library leaves that
    logger's level unset: its compiles show their bar too (a logging configuration at WARNING does not hide it)."""
    import logging

    level = logging.getLogger("acroboter").level  # its own level: NOTSET unless a command or the user set one
    if quiet or level > logging.INFO:
        return True
    return None


def announce(text: str) -> None:
    """One line on stderr where no bar can show (stderr not a terminal: a notebook, a log) and progress is not
    switched off: long work on a first use is never silent."""
    import sys

    if progress_disabled() is None and not (hasattr(sys.stderr, "isatty") and sys.stderr.isatty()):
        print(f"acroboter: {text}", file=sys.stderr, flush=True)
