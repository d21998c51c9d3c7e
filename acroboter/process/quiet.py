"""What the helper libraries say on their own, kept off a user's terminal (docs/errors.md).

numpy warns with a source path and a line of our code ("RuntimeWarning: overflow encountered in matmul"), Dask
with its own ("UserWarning: Port 8787 is already in use"); Dask, tornado and asyncio log tracebacks of
connections closed while a cluster shuts down, imageio-ffmpeg that no frame was written. None of it is the
package's word to a user. Where such a condition means something (numbers that are no longer finite, a
singular system), the place it happens checks it and says so in the package's own error; the warnings left
say nothing to a user: `contained()` (every command's error boundary, acroboter.cli.entry) turns them into
debug lines (`-v` shows each with where it came from) and keeps the helper libraries' loggers at CRITICAL
unless -v.
"""

from __future__ import annotations

import contextlib
import logging
import warnings
from collections.abc import Iterator

HELPER_LOGGERS = ("distributed", "tornado", "asyncio", "imageio", "imageio_ffmpeg")
log = logging.getLogger("acroboter")


def _as_debug(message, category, filename, lineno, file=None, line=None) -> None:
    log.debug("%s (%s:%s): %s", category.__name__, filename, lineno, message)


@contextlib.contextmanager
def contained() -> Iterator[None]:
    """Python warnings become debug lines of the package's logger, the helper libraries' loggers stay quiet
    (both as they were after the block)."""
    loggers = [logging.getLogger(name) for name in HELPER_LOGGERS]
    levels = [logger.level for logger in loggers]
    with warnings.catch_warnings():
        warnings.simplefilter("default")
        warnings.showwarning = _as_debug
        if not log.isEnabledFor(logging.DEBUG):
            for logger in loggers:
                logger.setLevel(logging.CRITICAL)
        try:
            yield
        finally:
            for logger, level in zip(loggers, levels, strict=True):
                logger.setLevel(level)
