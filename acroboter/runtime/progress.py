"""Whether a progress bar shows: one rule for the commands and the animation's encoders."""

from __future__ import annotations


def progress_disabled(quiet: bool = False) -> bool | None:
    """tqdm's `disable`: off with --quiet or `acroboter -q`, else tqdm's own choice (None: off when
    stderr is not a terminal)."""
    import logging

    if quiet or logging.getLogger("acroboter").getEffectiveLevel() > logging.INFO:
        return True
    return None
