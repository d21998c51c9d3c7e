"""Hold Ctrl-C back while a few file operations that belong together run (a dependency-free helper
for the code generator's swap and the run's publishing of its results)."""

from __future__ import annotations

import contextlib
import signal
import threading


@contextlib.contextmanager
def deferred_interrupt():
    """SIGINT during the block is remembered and raised as KeyboardInterrupt right after it."""
    if threading.current_thread() is not threading.main_thread():
        yield  # signals reach the main thread only
        return
    caught = []
    previous = signal.signal(signal.SIGINT, lambda signum, frame: caught.append(signum))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
    if caught:
        raise KeyboardInterrupt


class _Remembered:
    def __init__(self):
        self.caught = False

    def check(self) -> None:
        """Raise the remembered Ctrl-C now (at a point where stopping leaves nothing half-done)."""
        if self.caught:
            raise KeyboardInterrupt


@contextlib.contextmanager
def remembered_interrupt():
    """SIGINT during the block is remembered, raised at the next `check()` and at the end.

    For work inside CasADi: its SWIG layer swallows a KeyboardInterrupt raised in the middle of a
    symbolic operation, so the code generator checks between steps instead (before it replaces any
    file)."""
    state = _Remembered()
    if threading.current_thread() is not threading.main_thread():
        yield state
        return

    def remember(signum, frame):
        state.caught = True

    previous = signal.signal(signal.SIGINT, remember)
    try:
        yield state
    finally:
        signal.signal(signal.SIGINT, previous)
    state.check()
