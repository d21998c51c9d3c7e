"""The one error boundary of every command line, and the option types they share.

Every CLI's `main` is wrapped by `guarded`: the project's error classes become one line on stderr
and the documented exit code, never a traceback:

    2    bad input: a spec, an option, stale or tampered generated code, an unwritable --out, an option
         whose optional extra is not installed (the line names the `pip install` that fixes it)
    3    cannot run: the computation failed (a singular system, a failed build, a plant that
         found no consistent state, an I/O error while writing), or another command is writing into
         the output folder
    130  interrupted (Ctrl-C, at any phase, within a second): nothing half-written is left that looks
         complete, no staging folder is left behind

A helper library's warning (numpy's, Dask's) or log line never reaches the terminal: -v shows it as a
debug line (acroboter.process.quiet).

A core dependency that does not import is one line naming it and its `pip install` (exit 3). An error no
class names (a bug) is reported the same way, as "internal error", with exit 3; set ACROBOTER_TRACEBACK=1 to
see its traceback. The option types put every number in its range (acroboter.model.ranges) before any work,
in one message form: `argument --kp: expected 0 < kp <= 1e4 (1/s), found 1e+308`.
"""

from __future__ import annotations

import argparse
import functools
import logging
import os
import sys
import tempfile
import traceback
from collections.abc import Callable
from pathlib import Path

from ..model.ranges import Range
from ..runtime.progress import (
    progress_disabled as progress_disabled,  # every command's --quiet (shared with the animation)
)

log = logging.getLogger(__name__)

EXIT_BAD_INPUT = 2
EXIT_CANNOT_RUN = 3
EXIT_INTERRUPTED = 130


def _bad_input_errors() -> tuple[type[BaseException], ...]:
    from ..model.physical import PlantParameterError
    from ..model.spec import SpecError
    from ..process.extras import MissingExtraError
    from ..runtime.compiled import StaleModelError  # imported late: `--help` stays instant
    from ..sim.statics import EquilibriumError
    from .outputs import OutputFolderError

    return SpecError, StaleModelError, EquilibriumError, PlantParameterError, MissingExtraError, OutputFolderError


def _cannot_run_errors() -> tuple[type[BaseException], ...]:
    from ..control.controllers import SingularSystemError
    from ..control.distribution import DistributionError
    from ..control.recovery import RecoveryError
    from ..runtime.compile_library import BuildError
    from ..sim.plant import SimulationError
    from .outputs import OutputFolderBusy

    return (BuildError, SingularSystemError, DistributionError, SimulationError, RecoveryError, OutputFolderBusy,
            OSError)


def guarded(main: Callable[..., int]) -> Callable[..., int]:
    """Run a CLI main with the error boundary above (argparse's own exit 2 passes through)."""

    @functools.wraps(main)
    def wrapper(*args, **kwargs) -> int:
        from ..process.interrupts import exit_status, remembered_interrupt
        from ..process.quiet import contained

        interrupt = None
        try:
            # a helper library's warning or log line: -v only (acroboter.process.quiet); Ctrl-C at once, or as soon
            # as CasADi returns (acroboter.process.interrupts: inside it, it would be swallowed)
            with contained(), remembered_interrupt() as interrupt:
                return main(*args, **kwargs)
        except KeyboardInterrupt as err:  # Ctrl-C, or SIGTERM, SIGHUP handled as it: 130, 143, 129
            print("interrupted", file=sys.stderr)
            return exit_status(err)
        except Exception as err:  # noqa: BLE001 - the boundary: every error becomes a message and a code
            if interrupt is not None and interrupt.received:  # a Ctrl-C that a library turned into an error of its own
                log.debug("after Ctrl-C: %s: %s", type(err).__name__, err)
                print("interrupted", file=sys.stderr)
                return 128 + interrupt.signum
            if (line := core_import_problem(err)) is not None:
                print(f"error: {line}", file=sys.stderr)
                return EXIT_CANNOT_RUN
            if isinstance(err, _bad_input_errors()):
                print(f"error: {err}", file=sys.stderr)
                return EXIT_BAD_INPUT
            if isinstance(err, _cannot_run_errors()):
                print(f"error: {_described(err)}", file=sys.stderr)
                return EXIT_CANNOT_RUN
            if os.environ.get("ACROBOTER_TRACEBACK"):
                traceback.print_exc()
            print(f"internal error ({type(err).__name__}: {err}); this is a bug, please report it "
                  "(ACROBOTER_TRACEBACK=1 shows where)", file=sys.stderr)
            return EXIT_CANNOT_RUN

    return wrapper


def _described(err: Exception) -> str:
    """An error's message; a full disk or a quota says where and what to do ("[Errno 28] No space left on device"
    said neither)."""
    import errno

    if isinstance(err, OSError) and err.errno in (errno.ENOSPC, errno.EDQUOT):
        where = f" writing {err.filename}" if err.filename else ""
        return (f"{err.strerror}{where}: free some space on that file system, or give another --out (the output "
                "folder is as it was)")
    return str(err)


def core_import_problem(err: BaseException) -> str | None:
    """The one line for an installed package that does not import (a broken install: a core dependency
    missing, or one of theirs), None for any other error (also an ImportError of the package itself: a bug)."""
    from ..process.extras import MissingExtraError, core_line, is_core

    if not isinstance(err, ImportError) or isinstance(err, MissingExtraError) or not err.name:
        return None
    top = err.name.split(".")[0]
    if is_core(top):
        return core_line(top)
    if top == "acroboter":
        return None
    return (f"the installed package {top} does not import ({err}): a broken install, "
            "pip install --force-reinstall acroboter repairs it")


# --- option types (argparse `type=`): every number of every command in its Range ------------------------------


def ranged(range_: Range, template: str = "{}") -> Callable[[str], float | int]:
    """The type of a number option: a number in `range_` (acroboter.model.ranges), else argparse's exit 2 with
    'argument --kp: expected 0 < kp <= 1e4 (1/s), found 1e+308', before any work."""

    def parse(text: str) -> float | int:
        try:
            return range_.parse(text)
        except ValueError as err:
            raise argparse.ArgumentTypeError(str(err)) from None

    return carrying(parse, range_.name, (range_,), template)


def add_parameter_options(parser: argparse.ArgumentParser, parameters, note: dict[str, str] | None = None) -> None:
    """One option per controller parameter (acroboter.model.controller_parameters.ControllerParameter), derived
    from its declaration: --alpha-geometric, dest alpha_geometric, its range or choices, default None (the spec's
    value), the declared help (with a command's `note` on a name appended)."""
    for item in parameters:
        extra = f"; {note[item.name]}" if note and item.name in note else ""
        kind = {"type": ranged(item.range)} if item.range is not None else {"choices": item.choices}
        parser.add_argument(item.flag, dest=item.name, default=None, help=item.option_help() + extra, **kind)


def as_option_text(err: Exception) -> str:
    """A library argument's error in the words of the option that gave it: 'kd: expected …' as '--kd: expected …'
    (a GainError names the parameter, a RangeError its argument)."""
    name, sep, rest = str(err).partition(": ")
    return f"--{name.replace('_', '-')}: {rest}" if sep and name.isidentifier() else str(err)


def ranged_list(range_: Range) -> Callable[[str], list]:
    """Comma-separated numbers, each in `range_` (repeats dropped, order kept)."""

    def parse(text: str) -> list:
        items = [item.strip() for item in str(text).split(",")]
        if not all(items):  # `1,,2` or a trailing comma: a number left out, or a typo
            raise argparse.ArgumentTypeError(f"expected comma-separated numbers, each {range_.text()}, found an "
                                             f"empty item in '{text}'")
        try:
            return list(dict.fromkeys(range_.parse(item) for item in items))
        except ValueError as err:
            raise argparse.ArgumentTypeError(str(err)) from None

    return carrying(parse, range_.name, (range_,), "{}")


def named_number(range_: Range | None, example: str, form: str = "NAME=VALUE") -> Callable[[str], tuple]:
    """'NAME=NUMBER' (e.g. --sensing-noise positions=0.0002) as (name, number), the number in `range_`; with
    `range_` None the number's range is the one of the spec field NAME stands for, checked with the spec
    (--plant-param SU.mass=8.8: acroboter.model.physical). `form` is how the option's help writes it."""

    def parse(text: str) -> tuple[str, float | int]:
        name, sep, value = str(text).partition("=")
        within = f" with {range_.text()}" if range_ is not None else ""
        if not sep or not name.strip():
            raise argparse.ArgumentTypeError(f"expected {form} such as {example}{within}, found '{text}'")
        if range_ is None:
            try:
                return name.strip(), float(value)
            except ValueError:
                raise argparse.ArgumentTypeError(f"expected {form} such as {example}, found '{text}'") from None
        try:
            return name.strip(), range_.parse(value)
        except ValueError as err:
            raise argparse.ArgumentTypeError(f"{name.strip()}: {err}") from None

    head = example.partition("=")[0]
    return carrying(parse, range_.name if range_ else form, (range_,) if range_ else (), head + "={}")


def carrying(parse: Callable, name: str, ranges: tuple[Range, ...], template: str) -> Callable:
    """A type that carries its ranges and how one number is written in the option (`template`): the docs' table
    and tests/test_number_ranges.py read them; a numeric option without them is a test failure."""
    parse.__name__ = name
    parse.ranges = ranges
    parse.template = template
    return parse


def spec_file(text: str) -> Path:
    """A spec option: a TOML file's path, or the name of a shipped example (`acroboter examples`), so
    that `--spec lab_crane` works from any folder; a name that is neither says so and suggests the
    nearest example."""
    import difflib

    from ..process.locations import example_names, example_spec

    path = Path(text)
    if path.suffix == ".toml" or (path.exists() and not path.is_dir()) or os.sep in text:  # (a folder is no spec:
        return path  # `--spec acroboter` in the checkout, beside the package's folder, is the example)
    names = example_names()
    if text in names:
        return example_spec(text)
    near = difflib.get_close_matches(text, names, n=1)
    raise argparse.ArgumentTypeError(
        f"'{text}' is neither a spec file nor an example's name" + (f" (did you mean {near[0]}?)" if near else "")
        + f"; the examples: {', '.join(names)} (`acroboter examples`)")


def check_out_folder(parser: argparse.ArgumentParser, out: Path, option: str = "--out") -> None:
    """--out must be creatable and writable: found before any work, not after it (parser.error: exit 2).
    A folder made for the check is removed again (the command makes it when it writes)."""
    from .outputs import missing_folders, remove_if_empty, unfit_folder

    if (problem := unfit_folder(out)) is not None:  # /proc said "No such file or directory"
        parser.error(f"cannot write into {option} {out}: {problem}")
    made = missing_folders(out)
    try:
        out.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=out):
            pass
    except OSError as err:
        parser.error(f"cannot write into {option} {out}: {err.strerror or err}")
    finally:
        remove_if_empty(made)


def folder_write_problem(folder: Path) -> str | None:
    """Why no file can be written into `folder` (None: one can), found without creating anything."""
    if not folder.exists():
        return f"the folder {folder} does not exist"
    if not folder.is_dir():
        return f"{folder} is not a folder"
    try:
        with tempfile.TemporaryFile(dir=folder):
            pass
    except OSError as err:
        return f"cannot write into the folder {folder}: {err.strerror or err}"
    return None


def file_write_problem(path: Path) -> str | None:
    """Why the file `path` (through a link: its target) cannot be written or replaced (None: it can)."""
    from .outputs import kernel_folder

    target = path.resolve() if path.is_symlink() else path
    if target.exists() and not target.is_file():
        return f"{path} is not a regular file"
    if (system := kernel_folder(target.parent)) is not None:  # /dev/x.xml "worked" as root, into a passing tmpfs
        return f"{system} is the kernel's file system, which holds no file of results"
    return folder_write_problem(target.parent)
