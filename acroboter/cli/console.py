"""`acroboter <command>`: one console script for every command line of the package.

    acroboter run          the paper's scenario (or any spec) under the controllers
    acroboter bench        control-step timings: compiled C against the casadi.Function path
    acroboter study        redundancy and non-collocation study over the example cranes
    acroboter sweep        penalty-number sweep on a Dask cluster
    acroboter robustness   Monte Carlo over plant parameters: every method, with and without ki, on Dask
    acroboter plan         the fastest timing of the path under the input limits with a margin (docs/planning.md)
    acroboter generate     write a spec's C (generated/ in a checkout)
    acroboter check        regenerate into a temporary folder and compare with generated/
    acroboter build        compile the example specs' libraries into the cache
    acroboter export-step  one method's complete control step as embedded C
    acroboter animate      a video (MP4, GIF) of one method's run from its results folder
    acroboter mjcf         a spec's MJCF model for MuJoCo
    acroboter plant-fuzz   generated open-loop experiments, the own plant against MuJoCo (docs/plant.md)
    acroboter examples     the example cranes (any of them is a --spec NAME), one line each

`acroboter <command> --help` lists each command's options. -q shows warnings and errors only (no
progress bars), -v adds debugging detail (cache paths, library paths). Exit codes: 0 done, 2 bad
input, 3 cannot run, 130 interrupted.

`pip install acroboter` is the core; MuJoCo (--plant mujoco, --view, mjcf, plant-fuzz), the MP4 encoder
and Dask (sweep, robustness, plant-fuzz) are extras: pip install 'acroboter[all]' installs them
(docs/extras.md). A command that needs a missing one says which, before any work (exit 2).
"""

from __future__ import annotations

import argparse
import logging
import signal
import sys
from importlib import import_module

# command -> (module, function, arguments put before the user's)
COMMANDS: dict[str, tuple[str, str, tuple[str, ...]]] = {
    "run": ("acroboter.cli.run", "main", ()),
    "bench": ("acroboter.cli.bench", "main", ()),
    "study": ("acroboter.cli.study", "main", ()),
    "sweep": ("acroboter.cli.sweep", "main", ()),
    "robustness": ("acroboter.cli.robustness", "main", ()),
    "plan": ("acroboter.cli.plan", "main", ()),
    "generate": ("acroboter.cli.generate", "main", ("generate",)),
    "check": ("acroboter.cli.generate", "main", ("check",)),
    "build": ("acroboter.cli.generate", "build_main", ()),
    "export-step": ("acroboter.cli.generate", "export_step_main", ()),
    "animate": ("acroboter.cli.animate", "main", ()),
    "mjcf": ("acroboter.cli.mjcf", "main", ()),
    "plant-fuzz": ("acroboter.cli.plant_fuzz", "main", ()),
    "examples": ("acroboter.cli.examples", "main", ()),
}


def version() -> str:
    from .. import __version__

    return __version__


class _CurrentStderr(logging.StreamHandler):
    """Writes to sys.stderr as it is at each message, not as it was when the handler was made: a command
    called in-process after another (tests, a notebook) may run with sys.stderr replaced, and a handler
    holding the earlier, closed stream prints logging's own traceback instead of the message."""

    def __init__(self) -> None:
        super().__init__(sys.stderr)

    @property
    def stream(self):
        return sys.stderr

    @stream.setter
    def stream(self, value) -> None:  # StreamHandler.__init__ and setStream assign it: sys.stderr it stays
        pass


def configure_logging(verbosity: int) -> None:
    """-q (verbosity -1): warnings only; default: progress and notes; -v: debugging detail."""
    level = {-1: logging.WARNING, 0: logging.INFO}.get(verbosity, logging.DEBUG)
    logger = logging.getLogger("acroboter")
    if not logger.handlers:
        handler = _CurrentStderr()
        handler.setFormatter(logging.Formatter("%(message)s"))
        logger.addHandler(handler)
        logger.propagate = False
    logger.setLevel(level)


def main(argv: list[str] | None = None) -> int:
    program = argv is None  # the `acroboter` program itself (not a caller in a process that goes on)
    argv = sys.argv[1:] if argv is None else list(argv)
    parser = argparse.ArgumentParser(prog="acroboter", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=f"acroboter {version()}",
                        help="print the package version and exit")
    noise = parser.add_mutually_exclusive_group()
    noise.add_argument("-q", "--quiet", action="store_const", const=-1, dest="verbosity", default=0,
                       help="warnings and errors only, no progress bars")
    noise.add_argument("-v", "--verbose", action="store_const", const=1, dest="verbosity",
                       help="debugging detail (cache and library paths)")
    parser.add_argument("command", choices=sorted(COMMANDS), metavar="COMMAND",
                        help=f"one of: {', '.join(COMMANDS)}")
    parser.add_argument("arguments", nargs=argparse.REMAINDER, help="the command's own options (see COMMAND --help)")
    if not argv:
        parser.print_help()
        return 0
    args = parser.parse_args(argv)
    arguments, verbosity = _noise_after_command(args.command, args.arguments, args.verbosity)
    configure_logging(verbosity)
    module, function, prefix = COMMANDS[args.command]
    # A broken install (a core dependency missing): one line, not a traceback from deep in an import.
    from ..process.extras import missing_core

    if (problem := missing_core()) is not None:
        print(f"acroboter: {problem}", file=sys.stderr)
        return 3
    try:
        command = getattr(import_module(module), function)
    except KeyboardInterrupt:  # while the command's modules load (numpy, scipy): before any work
        print("interrupted", file=sys.stderr)
        return 130
    except ImportError as err:  # found but does not import (a half-removed package, a missing library)
        from .entry import core_import_problem

        line = core_import_problem(err)
        if line is None:
            raise
        print(f"acroboter: {line}", file=sys.stderr)
        return 3
    code = command([*prefix, *arguments])
    if program:  # the command is done, its folder as its code says: a SIGTERM during the interpreter's shutdown (a
        # third of a second) exited 143, "folder as it was", over published results
        from ..process.interrupts import SIGNALS

        for signum in SIGNALS:
            signal.signal(signum, signal.SIG_IGN)
    return code


def forward(command: str):
    """main(argv=None) of `python -m acroboter.<command>`: the console with that command, so the module
    form gets the same -q/-v, core-dependency check and error boundary as `acroboter <command>`."""

    def forwarded(argv: list[str] | None = None) -> int:
        return main([command, *(sys.argv[1:] if argv is None else argv)])

    return forwarded


# The commands whose own options include -q/--quiet (no progress bars); -v is the console's alone.
QUIET_OPTION = {"run", "plan", "sweep", "robustness", "animate", "mjcf", "plant-fuzz"}


def _noise_after_command(command: str, arguments: list[str], verbosity: int) -> tuple[list[str], int]:
    """-v/-q given after the command (`acroboter run -v`) act as before it: -v is taken out of the
    command's arguments, -q too unless the command has a -q of its own (then both see it)."""
    kept = []
    for i, arg in enumerate(arguments):
        if arg == "--":  # the rest belongs to the command as it is
            kept += arguments[i:]
            break
        if arg in ("-v", "--verbose"):
            verbosity = 1
        elif arg in ("-q", "--quiet"):
            verbosity = -1
            if command in QUIET_OPTION:
                kept.append(arg)
        else:
            kept.append(arg)
    return kept, verbosity


if __name__ == "__main__":
    sys.exit(main())
