"""Ctrl-C, promptly and safely (a dependency-free helper for the code generator, the compiler and the output
folders; docs/errors.md).

- `deferred_interrupt`: held back while a few file operations that belong together run (the code generator's
  swap, a command's publishing of its results), raised right after them.
- `remembered_interrupt`: for work that calls CasADi. Its SWIG layer swallows a KeyboardInterrupt raised inside
  one of its calls (the call then goes on as if nothing happened), so inside CasADi a Ctrl-C is remembered and
  raised as soon as CasADi returns to our code; anywhere else in the block (our own code between CasADi calls, a
  compiler being waited for) it is raised at once. Raised while a finalizer or a weakref callback runs (matplotlib's
  transforms clean up that way during garbage collection), Python cannot propagate it and prints "Exception
  ignored in"; the block's hook for such exceptions remembers it instead, and it is raised at the next
  `check()`, before any `deferred_interrupt` block (publishing a command's results), or at the block's end.
"""

from __future__ import annotations

import contextlib
import signal
import sys
import threading

# the remembered_interrupt blocks open now (innermost last): deferred_interrupt raises a Ctrl-C they remember
_ACTIVE: list[_Remembered] = []
# What stops a command as Ctrl-C does: SIGINT, and SIGTERM (`kill`, `timeout`) and SIGHUP (a closed terminal), which
# by default would end the process at once, leaving a staging folder or a partial file behind.
SIGNALS = tuple(s for s in (signal.SIGINT, getattr(signal, "SIGTERM", None), getattr(signal, "SIGHUP", None))
                if s is not None)


class Interrupted(KeyboardInterrupt):
    """Ctrl-C, or SIGTERM or SIGHUP stopping a command as Ctrl-C does; `status` is the shell's 128 + the signal's
    number (130, 143, 129)."""

    def __init__(self, signum: int = signal.SIGINT):
        super().__init__()
        self.signum = int(signum)

    @property
    def status(self) -> int:
        return 128 + self.signum


def exit_status(err: BaseException) -> int:
    """The exit status of a command stopped by `err` (a KeyboardInterrupt): 128 + its signal, 130 for Ctrl-C."""
    return getattr(err, "status", 128 + int(signal.SIGINT))


def _install(handler) -> dict:
    return {signum: signal.signal(signum, handler) for signum in SIGNALS}


def _restore(previous: dict) -> None:
    for signum, handler in previous.items():
        signal.signal(signum, handler)


@contextlib.contextmanager
def deferred_interrupt():
    """SIGINT (SIGTERM, SIGHUP) during the block is remembered and raised as Interrupted (a KeyboardInterrupt) right
    after it. A Ctrl-C that an open remembered_interrupt block still holds is raised before the block starts."""
    if threading.current_thread() is not threading.main_thread():
        yield  # signals reach the main thread only
        return
    for state in _ACTIVE:
        state.check()
    caught = []
    previous = _install(lambda signum, frame: caught.append(signum))
    try:
        yield
    finally:
        _restore(previous)
    if caught:
        raise Interrupted(caught[0])


class _Remembered:
    def __init__(self):
        self.caught = False
        # set at any SIGINT in the block, and kept: a C extension that gets the KeyboardInterrupt from a Python call
        # it makes may turn it into an error of its own (matplotlib's Agg: "Invalid bounding box"), which is then
        # still a Ctrl-C (acroboter.cli.entry.guarded)
        self.received = False
        self.signum = int(signal.SIGINT)  # the signal received (SIGTERM and SIGHUP stop a command as Ctrl-C does)

    def check(self) -> None:
        """Raise the remembered Ctrl-C now (at a point where stopping leaves nothing half-done)."""
        if self.caught:
            self.caught = False
            raise Interrupted(self.signum)


def interrupt_pending() -> bool:
    """Whether a signal waits in an open remembered_interrupt block: a long CasADi call's Python callback (IPOPT's
    iteration callback) polls this and raises, which ends the solve at once; the signal itself is raised as CasADi
    returns."""
    return any(state.caught for state in _ACTIVE)


def inside_casadi(frame) -> bool:
    """Whether the Python stack at `frame` runs inside a CasADi call (a frame of its SWIG module on it)."""
    while frame is not None:
        if frame.f_globals.get("__name__", "").startswith("casadi"):
            return True
        frame = frame.f_back
    return False


@contextlib.contextmanager
def remembered_interrupt():
    """SIGINT during the block: KeyboardInterrupt at once outside CasADi, as soon as CasADi returns to our code
    inside it (a profile hook, set only then, sees the return), at the latest at `check()` or the block's end."""
    state = _Remembered()
    if threading.current_thread() is not threading.main_thread():
        yield state
        return
    profile = sys.getprofile()

    def on_return(frame, event, arg):
        if not inside_casadi(frame.f_back if event == "return" else frame):
            sys.setprofile(profile)
            state.caught = False
            raise Interrupted(state.signum)

    def on_interrupt(signum, frame):
        state.received, state.signum = True, int(signum)
        if inside_casadi(frame):  # raised here it would be swallowed: raised once CasADi has returned
            state.caught = True
            sys.setprofile(on_return)
            return
        state.caught = False
        raise Interrupted(signum)

    def on_unraisable(unraisable):
        if isinstance(unraisable.exc_value, KeyboardInterrupt):  # ours, where Python could not propagate it
            state.caught, state.signum = True, getattr(unraisable.exc_value, "signum", state.signum)
            return
        previous_hook(unraisable)

    previous = _install(on_interrupt)
    previous_hook, sys.unraisablehook = sys.unraisablehook, on_unraisable
    _ACTIVE.append(state)
    try:
        yield state
    finally:
        _ACTIVE.remove(state)
        _restore(previous)
        sys.unraisablehook = previous_hook
        sys.setprofile(profile)
    state.check()
